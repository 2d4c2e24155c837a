"""The estimator's contract with its user: every method refuses what does not fit the model
with one UserError naming the argument and the fix, and does what it says on what does.

save never writes into a folder that holds a run; predict, encode, simulate and the planner
take only frames of the model's shape and pixel type; fit takes only training settings; an
autonomous model (no actions) fits and simulates; resume refuses changed data context.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from latent_sindy import LatentSINDy, Restarts, SequenceData
from latent_sindy.errors import UserError
from latent_sindy.locks import exclusive
from latent_sindy.training.runs import RunDir

pytestmark = pytest.mark.usefixtures("one_torch_thread")

H = W = 8
SMALL = {"encoder": "mlp", "decoder": "mlp", "order": 1, "include_sine": False}


def _images(n: int = 6, steps: int = 3, channels: int = 1, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, (n, steps + 1, channels, H, W), dtype=np.uint8)


def _data(nu: int = 2, **kw) -> SequenceData:
    images = _images()
    if nu == 0:
        return SequenceData(images, **kw)
    actions = np.random.default_rng(1).uniform(-1, 1, (6, 3, nu)).astype(np.float32)
    return SequenceData(images, actions, [-1] * nu, [1] * nu, **kw)


@pytest.fixture(scope="module")
def fitted() -> tuple[SequenceData, LatentSINDy]:
    data = _data()
    return data, LatentSINDy(2, seed=0, **SMALL).fit(data, epochs=1)


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


# ------------------------------------------------------------------ save
@pytest.mark.parametrize("files", [("config.json", "checkpoint.pt"), ("metrics.csv",),
                                   ("config.json", "model.pt", "metrics.csv")])
def test_save_refuses_a_folder_that_holds_a_run_and_changes_nothing(fitted, tmp_path: Path,
                                                                    files) -> None:
    _, model = fitted
    run = tmp_path / "run"
    run.mkdir()
    for name in files:  # an interrupted or finished `latent-sindy train`
        (run / name).write_bytes(f"the run's own {name}".encode())
    before = _snapshot(run)
    with pytest.raises(UserError, match=rf"{files[0]}.*choose another folder"):
        model.save(run)
    assert _snapshot(run) == before


def test_save_refuses_a_folder_a_training_holds(fitted, tmp_path: Path) -> None:
    _, model = fitted
    run = tmp_path / "run"
    with exclusive(run, "run folder"), pytest.raises(UserError, match="is using this run"):
        model.save(run)
    assert not run.exists()


def test_save_writes_into_a_new_or_empty_folder_and_loads_back(fitted, tmp_path: Path) -> None:
    data, model = fitted
    (tmp_path / "empty").mkdir()
    for folder in (tmp_path / "new", tmp_path / "empty"):
        back = LatentSINDy.load(model.save(folder))
        x = data.images[0, 0]
        np.testing.assert_array_equal(back.encode(x), model.encode(x))
        assert not (tmp_path / f".{folder.name}.lock").exists()
    # a loaded model keeps its record, metrics and kept epoch: it saves elsewhere too
    assert back.kept_ == model.kept_ and len(back.metrics_) == len(model.metrics_) == 1
    LatentSINDy.load(back.save(tmp_path / "copy"))


def test_fit_into_a_run_folder_fills_kept_and_metrics(tmp_path: Path) -> None:
    model = LatentSINDy(2, seed=0, **SMALL).fit(_data(), epochs=2, out=tmp_path / "run")
    assert model.kept_["epoch"] in (1, 2) and model.kept_["selection"]
    assert [row["epoch"] for row in model.metrics_] == [1.0, 2.0]


# ------------------------------------------------------------------ images and actions
def test_images_of_another_pixel_type_are_refused_naming_the_conversion(fitted) -> None:
    data, model = fitted
    x = data.images[:, 0]
    with pytest.raises(UserError, match=r"uint8 pixels.*astype\(np.uint8\)"):
        model.encode(x / 255)
    with pytest.raises(UserError, match="images are float32"):
        model.predict(x.astype(np.float32) / 255, data.actions[:, 0])
    planner = model.planner()
    with pytest.raises(UserError, match="goal_image are float64"):
        planner.act(x[0], x[1] / 255)
    floats = data.replace(images=data.images.astype(np.float32) / 255)
    float_model = LatentSINDy(2, seed=0, **SMALL).fit(floats, epochs=1)
    with pytest.raises(UserError, match=r"float32 pixels.*/ 255"):
        float_model.encode(x)
    assert float_model.encode(floats.images[:, 0]).shape == (6, 2)


def test_a_goal_or_image_without_the_channel_axis_is_refused(fitted) -> None:
    data, model = fitted
    frame = data.images[0, 0]  # (1, H, W)
    planner = model.planner()
    with pytest.raises(UserError, match=r"goal_image of shape \(8, 8\).*\(1, 8, 8\)"):
        planner.act(frame, frame[0])
    with pytest.raises(UserError, match=r"image of shape \(8, 8\)"):
        planner.act(frame[0], frame)
    assert planner.act(frame, data.images[0, 1]).shape == (2,)
    with pytest.raises(UserError, match=r"images of shape \(8, 8\)"):
        model.encode(frame[0])


def test_misused_methods_name_the_argument(fitted) -> None:
    data, model = fitted
    x, u = data.images[:, 0], data.actions[:, 0]
    with pytest.raises(UserError, match=r"actions of shape \(3, 2\).*\(6, 2\)"):
        model.predict(x, u[:3])
    with pytest.raises(UserError, match=r"actions of shape \(3,\).*\(2,\)"):
        model.predict(x[0], np.zeros(3))
    with pytest.raises(UserError, match="NaN"):
        model.predict(x[0], np.array([np.nan, 0.0]))
    with pytest.raises(UserError, match=r"\(N, T, nu\) with N = 6"):
        model.simulate(x, data.actions[0])
    with pytest.raises(UserError, match=r"an image \(C, H, W\) or a batch"):
        model.simulate(x[0, 0], data.actions[0])
    with pytest.raises(UserError, match=r"\(T, 2\)"):
        model.simulate(x[0], data.actions[0, 0])
    with pytest.raises(UserError, match="bogus"):
        LatentSINDy(2, **SMALL).fit(data, bogus=3)
    with pytest.raises(UserError, match="LatentSINDy\\(seed="):
        LatentSINDy(2, **SMALL).fit(data, seed=3)
    with pytest.raises(UserError, match="out="):
        LatentSINDy(2, **SMALL).fit(data, resume=True)
    with pytest.raises(UserError, match=r"action_names \['a'\]: give a list of 2"):
        model.equations(action_names=["a"])
    assert "speed" in "\n".join(model.equations(action_names=["speed", "turn"]))


def test_simulate_rolls_out_a_model_with_actions(fitted) -> None:
    data, model = fitted
    z, images = model.simulate(data.images[0, 0], data.actions[0])
    assert z.shape == (4, 2) and images.shape == (4, 1, H, W)
    np.testing.assert_allclose(z[0], model.encode(data.images[0, 0]), rtol=1e-6)


# ------------------------------------------------------------------ autonomous systems
@pytest.mark.parametrize("dynamics", ["sindy", "linear", "mlp"])
def test_an_autonomous_discrete_time_model_fits_and_simulates(dynamics: str) -> None:
    data = _data(nu=0)
    small = {**SMALL} if dynamics == "sindy" else {"encoder": "mlp", "decoder": "mlp"}
    model = LatentSINDy(2, dynamics=dynamics, seed=0, **small).fit(data, epochs=1)
    z, images = model.simulate(data.images[0, 0], 5)
    assert z.shape == (6, 2) and images.shape == (6, 1, H, W)
    np.testing.assert_array_equal(model.simulate(data.images[0, 0], np.zeros((5, 0)))[0], z)
    assert model.predict(data.images[:, 0], np.zeros((6, 0))).shape == (6, 1, H, W)
    with pytest.raises(UserError, match="0 or more"):
        model.simulate(data.images[0, 0], -1)


def test_a_first_order_continuous_time_model_simulates(fitted) -> None:
    data = _data(nu=0, dt=0.1)
    model = LatentSINDy(1, time="continuous", encoder="mlp", decoder="mlp", order=1,
                        seed=0).fit(data, epochs=1, phases=[], restarts=Restarts(count=0))
    z, images = model.simulate(data.images[0, 0], 4)
    assert z.shape == (5, 1) and images.shape == (5, 1, H, W)
    assert np.all(np.isfinite(z))
    with pytest.raises(UserError, match="2 action"):
        fitted[1].simulate(data.images[0, 0], 4)


# ------------------------------------------------------------------ memory
def test_an_autoencoder_that_cannot_fit_in_memory_is_refused_before_anything(
        tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr("latent_sindy.atomic.available_memory", lambda: 2**30)
    images = np.random.default_rng(0).integers(0, 256, (3, 2, 1, 256, 256), dtype=np.uint8)
    data = SequenceData(images, np.zeros((3, 1, 1), np.float32), [-1], [1])
    with pytest.raises(UserError, match=r"encoder and fc decoder on 256x256 images.*GiB"):
        LatentSINDy(2, decoder="fc", **{k: SMALL[k] for k in ("order", "include_sine")}
                    ).fit(data, epochs=1)
    with pytest.raises(UserError, match="256x256 images"):
        LatentSINDy(2, decoder="fc").fit(data, epochs=1, out=tmp_path / "run")
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------ resume and the data
@pytest.mark.parametrize("change", ["dt", "box", "executed", "images_dot"])
def test_resume_refuses_a_changed_data_context(tmp_path: Path, change: str) -> None:
    data = _data(dt=0.1)
    run = tmp_path / "run"
    LatentSINDy(2, seed=0, **SMALL).fit(data, epochs=1, out=run)
    changed = {"dt": data.replace(dt=0.2),
               "box": data.replace(action_low=[-2, -2]),
               "executed": data.replace(executed=np.ones((6, 3), bool)),
               "images_dot": data.replace(images_dot=np.zeros(data.images.shape, np.float32)),
               }[change]
    before = _snapshot(run)
    named = {"dt": r"data\.dt \(run 0\.1, now 0\.2\)", "box": r"data\.action_low"}
    with pytest.raises(UserError, match="cannot resume .*" + named.get(change, "")):
        LatentSINDy(2, seed=0, **SMALL).fit(changed, epochs=2, out=run, resume=True)
    assert _snapshot(run) == before


# ------------------------------------------------------------------ edited run folders
@pytest.mark.parametrize(("edit", "needle"), [
    (lambda r: r.update(note="mine"), "unknown key 'note'"),
    (lambda r: r["description"].update(action_names=["a"]), "action_names has 1 name"),
    (lambda r: r["description"].update(pixel_dtype="int7"), "pixel_dtype 'int7'"),
])
def test_an_edited_run_record_is_refused(fitted, tmp_path: Path, edit, needle) -> None:
    run = fitted[1].save(tmp_path / "run")
    record = json.loads((run / RunDir.CONFIG).read_text())
    edit(record)
    (run / RunDir.CONFIG).write_text(json.dumps(record))
    with pytest.raises(UserError, match=needle):
        LatentSINDy.load(run)


def test_a_symbolic_link_loop_is_named_as_one(tmp_path: Path) -> None:
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    with pytest.raises(UserError, match="symbolic link"):
        LatentSINDy.load(loop)
