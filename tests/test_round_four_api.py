"""Round four of the Python API's contract (docs/robustness.md, "Round four: the Python
API"): what a hostile caller tried, and the one UserError naming the argument and the fix
that each now gets; where there is a right answer (a second-order model's one step, the
pixels fed back, the feature names), that it is given."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import h5py
import numpy as np
import pytest

from latent_sindy import LatentSINDy, SequenceData, cli
from latent_sindy.configs import from_json, to_json
from latent_sindy.errors import UserError
from latent_sindy.training import RunDir, TrainConfig, load_run
from latent_sindy.training.config import check_fit_settings
from latent_sindy.training.session import Phase

pytestmark = pytest.mark.usefixtures("one_torch_thread")


# ------------------------------------------------------------------ 2. old names
def _record_with(name: str) -> dict:
    record = json.loads(json.dumps(to_json(TrainConfig())))
    record[name] = 0.25
    return record


def _autoencoder(**kw):
    from latent_sindy.models.autoencoder import AutoencoderConfig
    return AutoencoderConfig(latent_dim=4, **kw)


def _moments_part():
    from latent_sindy.models.autoencoder_parts import ENCODER_PARTS
    return ENCODER_PARTS["moments"](order=2)


def _stlsq(**kw):
    from latent_sindy.sindy.optimizers import STLSQ
    return STLSQ(**kw)


def _centroid(**kw):
    from latent_sindy.worlds.pendulum.centroid_sindy import CentroidSindy
    return CentroidSindy(**kw)


def _pendulum_study(**kw):
    from latent_sindy.worlds.pendulum.study import StudyConfig
    return StudyConfig(**kw)


def _schedule(**kw):
    from latent_sindy.worlds.pendulum.video_schedules import SCHEDULES
    return dataclasses.replace(SCHEDULES["scalefree"], **kw)


def _spec(**kw):
    from latent_sindy.worlds.push.study.catalogue import model_specs
    from latent_sindy.worlds.push.study.scales import SCALES
    spec = next(s for s in model_specs(SCALES["tiny"]) if s.name == "sindy_moments")
    return dataclasses.replace(spec, **kw)


def _sweep(name: str):
    from latent_sindy.worlds.push.study.sweeps import parse_sweeps
    return parse_sweeps([f"{name}=0.1"])


def _model(**kw):
    from latent_sindy.models import ModelConfig
    return ModelConfig(**kw)


#: Each surface that took an old name, as a call giving it a setting ``name`` (the old one
#: alone, or beside its new one).
SURFACES = {
    "TrainConfig": (lambda n: TrainConfig(**{n: 0.25}), "threshold"),
    "TrainConfig, with the new name": (lambda n: TrainConfig(**{n: 0.25}, prune_below=0.5),
                                       "threshold"),
    "replace": (lambda n: dataclasses.replace(TrainConfig(), **{n: 0.1}),
                "sindy_init_threshold"),
    "Phase": (lambda n: Phase(3, "p", {n: 0}), "threshold_every"),
    "fit": (lambda n: check_fit_settings({n: 0.25}, None), "threshold"),
    "config.json": (lambda n: from_json(TrainConfig, _record_with(n), "config.json: train"),
                    "threshold"),
    "ModelConfig": (lambda n: _model(**{n: None}), "encoder"),
    "STLSQ": (lambda n: _stlsq(**{n: 0.1}), "threshold"),
    "CentroidSindy": (lambda n: _centroid(**{n: 0.1}), "threshold"),
    "pendulum study": (lambda n: _pendulum_study(**{n: 0.1}), "centroid_threshold"),
    "video schedule": (lambda n: _schedule(**{n: 0.2}), "threshold_every"),
    "push study model": (lambda n: _spec(**{n: 0.2}), "init_threshold"),
    "push study sweep": (lambda n: _sweep(n), "threshold"),
}


def _refusal(call, name: str) -> tuple[type, str]:
    """The error ``call(name)`` raises, its type and its words with the name (and the
    spelling suggestion a close name gets) taken out."""
    with pytest.raises((TypeError, UserError)) as e:
        call(name)
    words = re.sub(r" \(did you mean \w+\?\)", "", str(e.value)).replace(name, "NAME")
    return type(e.value), words


@pytest.mark.parametrize("surface", sorted(SURFACES))
def test_an_old_setting_name_is_refused_like_any_unknown_name(surface: str) -> None:
    """Before: the old name read as the new one, and beside it each surface picked a
    different winner. Now it is a name like any other the surface does not know."""
    call, old = SURFACES[surface]
    assert _refusal(call, old) == _refusal(call, "no_such_setting")


def test_an_autoencoder_part_named_by_a_string_is_refused() -> None:
    """``encoder="moments"`` named a kind; the kind is ``encoder_kind`` (the part, a config)."""
    with pytest.raises(UserError, match=r"encoder='moments' is none of the encoder's configs "
                                        r"\(.*MomentEncoderConfig.*\): give one, or its kind "
                                        r"as encoder_kind="):
        _autoencoder(encoder="moments")
    assert _autoencoder(encoder_kind="moments", moment_order=2).encoder == _moments_part()
    assert _autoencoder(encoder=_moments_part()).moment_order == 2
    with pytest.raises(UserError, match=r"encoder=.* and moment_order= both set"):
        _autoencoder(encoder=_moments_part(), moment_order=3)
    moments = _autoencoder(encoder_kind="moments", moment_order=2)
    assert dataclasses.replace(moments, moment_order=3).moment_order == 3


@pytest.mark.parametrize("old", ["--threshold", "--threshold-every", "--sindy-init-threshold"])
def test_the_cli_refuses_an_old_flag_like_any_unknown_flag(monkeypatch, capsys, old) -> None:
    """Before: the old flag set the new setting, and beside it the last one given won."""
    seen = []
    monkeypatch.setattr(cli.Train, "run", lambda self: seen.append(self.config))
    with pytest.raises(SystemExit) as e:
        cli.main(["train", old, "0.25"])
    err = capsys.readouterr().err
    with pytest.raises(SystemExit) as unknown:
        cli.main(["train", "--no-such-flag", "0.25"])
    assert e.value.code == unknown.value.code == 2 and not seen
    def headline(text: str) -> str:  # (tyro may add flags of similar names below it)
        return next(" ".join(line.strip("│ ").split()) for line in text.splitlines()
                    if "Unrecognized options:" in line)

    assert headline(err) == f"Unrecognized options: {old}, 0.25"
    assert headline(capsys.readouterr().err) == "Unrecognized options: --no-such-flag, 0.25"


# ------------------------------------------------------------------ 3. an edited action box
H = W = 8
SMALL = {"encoder": "mlp", "decoder": "mlp", "order": 1, "include_sine": False}


def _data(nu: int = 2, dtype=np.uint8, **kw) -> SequenceData:
    rng = np.random.default_rng(0)
    images = rng.integers(0, 256, (6, 4, 1, H, W), dtype=np.uint8)
    if dtype != np.uint8:
        images = (images / 255.0).astype(dtype)
    actions = np.random.default_rng(1).uniform(-1, 1, (6, 3, nu)).astype(np.float32)
    return SequenceData(images, actions, [-1] * nu, [1] * nu, **kw)


@pytest.fixture(scope="module")
def fitted() -> tuple[SequenceData, LatentSINDy]:
    data = _data(action_names=["vx", "vy"])
    return data, LatentSINDy(2, seed=0, **SMALL).fit(data, epochs=1)


def _edit_box(run: Path, low, high, also_data: bool = True) -> None:
    path = run / RunDir.CONFIG
    record = json.loads(path.read_text())
    record["description"].update(action_low=low, action_high=high)
    if also_data:  # the copy of the box the data's identity keeps, edited alike
        record["data"].update(action_low=low, action_high=high)
    path.write_text(json.dumps(record))


@pytest.mark.parametrize("also_data", [True, False])
def test_a_run_whose_action_box_was_edited_is_refused(fitted, tmp_path: Path,
                                                      also_data) -> None:
    """Before: it loaded, and the planner acted outside the trained box (±50)."""
    run = fitted[1].save(tmp_path / "run")
    _edit_box(run, [-50.0, -50.0], [50.0, 50.0], also_data)
    for load in (LatentSINDy.load, load_run):  # the estimator and every command
        with pytest.raises(UserError, match=r"config\.json: the action box .*-50.* not the one "
                                            r"the model was trained with .*-1\.0.*put that "
                                            r"box back"):
            load(run)


def test_a_trained_run_keeps_its_box_beside_the_weights(tmp_path: Path) -> None:
    data = _data()
    LatentSINDy(2, seed=0, **SMALL).fit(data, epochs=1, out=tmp_path / "run")
    _edit_box(tmp_path / "run", [-2.0, -1.0], [1.0, 1.0])
    with pytest.raises(UserError, match=r"kept in model\.pt"):
        load_run(tmp_path / "run")
    with pytest.raises(UserError, match=r"kept in checkpoint\.pt"):
        load_run(tmp_path / "run", checkpoint=True)


@pytest.mark.parametrize(("low", "high"), [([1.0, 1.0], [-1.0, -1.0]),
                                           ([-1.0, float("nan")], [1.0, 1.0]),
                                           ([-1.0, -1.0], [1.0, float("inf")])])
def test_an_inverted_or_not_finite_box_is_refused_at_load(fitted, tmp_path: Path, low,
                                                          high) -> None:
    """Before: an inverted box failed only inside planner()."""
    run = fitted[1].save(tmp_path / "run")
    _edit_box(run, low, high)
    with pytest.raises(UserError, match=r"config\.json: description action_low .* not a "
                                        r"finite box with action_low < action_high"):
        LatentSINDy.load(run)


def test_an_unedited_run_loads_and_plans_inside_its_box(fitted, tmp_path: Path) -> None:
    data, model = fitted
    back = LatentSINDy.load(model.save(tmp_path / "run"))
    u = back.planner(seed=0).act(data.images[0, 0], data.images[0, 1])
    assert np.all(np.abs(u) <= 1.0)


# ------------------------------------------------------------------ 5. the error contract
@pytest.mark.parametrize(("call", "needle"), [
    (lambda d: LatentSINDy(2, **SMALL).fit(d, epochs=1.5), r"epochs=1\.5: give an integer"),
    (lambda d: LatentSINDy(2, **SMALL).fit(d, epochs="2"), r"epochs='2': give an integer"),
    (lambda d: LatentSINDy(2, **SMALL).fit(d, epochs=True), r"epochs=True: give an integer"),
    (lambda d: LatentSINDy(2, **SMALL).fit(d, epochs=1, lr=True), r"lr=True: give a number"),
    (lambda d: LatentSINDy(2, **SMALL).fit(d, epochs=1, window=True), "window=True"),
    (lambda d: LatentSINDy(2, **SMALL).fit(d, epochs=1, batch_size=2.5), "batch_size=2.5"),
    (lambda d: LatentSINDy(2, seed=1.5, **SMALL), r"seed=1\.5: give an integer"),
    (lambda d: LatentSINDy(2, seed=True, **SMALL), "seed=True: give an integer"),
    (lambda d: LatentSINDy(True, **SMALL), "latent_dim=True: give an integer"),
    (lambda d: LatentSINDy(0, **SMALL), r"latent_dim=0 .*use 1 or more"),
    (lambda d: LatentSINDy(2, time="continuous", time_unit="fast"),
     r"time_unit='fast': give a positive number"),
    (lambda d: LatentSINDy(2, time="continuous", time_unit=True), "time_unit=True"),
    (lambda d: SequenceData(d.images, d.actions, [-1, -1], [1, 1], dt="0.1"),
     r"dt='0\.1': give the time between frames as a positive number"),
    (lambda d: SequenceData(d.images, d.actions, [-1, -1], [1, 1], dt=True), "dt=True"),
    (lambda d: TrainConfig(epochs=2.0), r"epochs=2\.0: give an integer"),
    (lambda d: LatentSINDy(2, **SMALL).fit(d, epochs=1, sindy_fit="later"),
     "--sindy-fit 'later': use joint or after"),  # (a string outside the choices: the flag)
    (lambda d: TrainConfig(device=5), "device=5: give one of 'auto', 'cpu', 'cuda'"),
    (lambda d: Phase(2, "p", {"prune_every": True}) and TrainConfig(prune_every=True),
     "prune_every=True"),
])
def test_wrong_types_are_refused_naming_the_argument(call, needle) -> None:
    """Before: TypeError or RuntimeError from inside torch or numpy, or (a bool) taken as 1."""
    with pytest.raises(UserError, match=needle):
        call(_data())


def test_numpy_numbers_are_numbers() -> None:
    cfg = TrainConfig(epochs=np.int64(3), lr=np.float32(0.5))
    assert (cfg.epochs, cfg.lr) == (3, 0.5) and type(cfg.epochs) is int
    assert json.dumps(to_json(cfg))  # (a record stays JSON)
    assert SequenceData(_data().images, dt=np.float64(0.1)).dt == 0.1


@pytest.mark.parametrize("method", ["predict", "encode", "simulate"])
def test_an_empty_batch_is_refused(fitted, method) -> None:
    """Before: RuntimeError: cannot reshape tensor of 0 elements."""
    data, model = fitted
    images, actions = data.images[:0, 0], data.actions[:0]
    call = {"predict": lambda: model.predict(images, actions[:, 0]),
            "encode": lambda: model.encode(images),
            "simulate": lambda: model.simulate(images, actions)}[method]
    with pytest.raises(UserError, match=r"\(0, 1, 8, 8\) hold no frame: give at least one"):
        call()


@pytest.mark.parametrize("path", ["", "  "])
def test_save_to_no_folder_is_refused(fitted, path) -> None:
    """Before: ValueError: PosixPath('.') has an empty name."""
    with pytest.raises(UserError, match=r"save\(.*\): give the folder"):
        fitted[1].save(path)


@pytest.mark.parametrize(("attr", "value", "needle"), [
    ("dt", "fast", r"attribute dt holds 'fast', not a number: set it to the time between"),
    ("dt", True, "attribute dt holds True"),
    ("seed", "zero", "attribute seed holds 'zero'"),
])
def test_a_data_file_attribute_that_is_no_number_is_named(tmp_path: Path, attr, value,
                                                          needle) -> None:
    """Before: "damaged (ValueError: could not convert string to float); re-collect it"."""
    from latent_sindy.data.store import read_sequences, write_sequences
    path = tmp_path / "data.h5"
    write_sequences(path, _data(dt=0.1))
    with h5py.File(path, "a") as f:
        f.attrs[attr] = value
    with pytest.raises(UserError, match=needle) as e:
        read_sequences(path)
    assert "damaged" not in str(e.value) and str(path) in str(e.value)


# ------------------------------------------------------------------ 6. second-order models
@pytest.fixture(scope="module")
def second_order() -> tuple[SequenceData, LatentSINDy]:
    from latent_sindy.worlds.pendulum.video import pendulum_video
    data = pendulum_video(n_train=4, n_val=1, n_test=1, steps=20, size=9, dt=0.05)
    model = LatentSINDy(1, time="continuous", derivative_order=2, order=2, seed=0,
                        settings=TrainConfig(epochs=2)).fit(data)
    return data, model


def test_a_second_order_model_says_what_to_pass(second_order) -> None:
    """Before: simulate said "use predict", and predict failed on the phase state's size."""
    data, model = second_order
    video, none = data.images, np.zeros((data.n, 0), np.float32)
    with pytest.raises(UserError, match=r"pass the frames one time step \(dt = 0\.05\) before"
                                        r".*predict\(images, actions, previous=frames_before\)"):
        model.predict(video[:, 1], none)
    with pytest.raises(UserError, match=r"simulate\(images, actions, previous=frames_before"):
        model.simulate(video[:, 1], 3)


def test_a_second_order_model_steps_from_two_frames(second_order) -> None:
    data, model = second_order
    video, none = data.images, np.zeros((data.n, 0), np.float32)
    nxt = model.predict(video[:, 1], none, previous=video[:, 0])
    assert nxt.shape == video[:, 2].shape and np.all((0 <= nxt) & (nxt <= 1))
    z, frames = model.simulate(video[:, 1], 4, previous=video[:, 0])
    assert z.shape == (data.n, 5, 1) and frames.shape == (data.n, 5, 1, 9, 9)
    np.testing.assert_allclose(z[:, 0], model.encode(video[:, 1]), rtol=1e-6)
    np.testing.assert_allclose(frames[:, 1], nxt, atol=1e-6)  # the same step both ways
    # the velocity comes from the earlier frame: another earlier frame, another step
    still = model.predict(video[:, 1], none, previous=video[:, 1])
    assert not np.allclose(still, nxt)
    one = model.predict(video[0, 1], np.zeros(0, np.float32), previous=video[0, 0])
    np.testing.assert_allclose(one, nxt[0], atol=1e-6)


def test_a_first_order_model_refuses_previous(fitted) -> None:
    data, model = fitted
    with pytest.raises(UserError, match=r"previous=...\) is for second-order"):
        model.predict(data.images[:, 1], data.actions[:, 1], previous=data.images[:, 0])


# ------------------------------------------------------------------ 9. the API's own parts
def test_predicted_uint8_frames_go_back_in_by_the_advice(fitted) -> None:
    """Before: the advice scaled predict's 0..255 floats by 255 again."""
    data, model = fitted
    out = model.predict(data.images[:, 0], data.actions[:, 0])
    assert out.dtype == np.float32 and out.max() > 1
    with pytest.raises(UserError, match=r"0\.\.255, as predict and simulate return them.*"
                                        r"np\.round\(images\)\.clip\(0, 255\)\."
                                        r"astype\(np\.uint8\)") as e:
        model.predict(out, data.actions[:, 1])
    assert "* 255" not in str(e.value)
    back = np.round(out).clip(0, 255).astype(np.uint8)
    np.testing.assert_array_equal(back.astype(np.float32), np.round(out))
    assert model.predict(back, data.actions[:, 1]).shape == out.shape
    with pytest.raises(UserError, match=r"np\.round\(images \* 255\)"):  # [0, 1] floats
        model.predict(out / 255, data.actions[:, 1])


def test_feature_names_use_the_action_names_of_the_equations(fitted) -> None:
    """Before: get_feature_names said u0, u1 where equations said vx, vy."""
    _, model = fitted
    names = model.get_feature_names()
    assert "vx" in names and "vy" in names and not {"u0", "u1"} & set(names)
    used = {t for line in model.equations(precision=12) for t in ("vx", "vy") if t in line}
    assert used <= set(names) and len(names) == model.coefficients().shape[1]


@pytest.mark.parametrize(("names", "needle"), [
    (["a", "a"], "'a' names more than one action"),
    (["z0", "b"], "'z0' is a name the equations already use"),
    (["a", "1"], "'1' is not a name"),
    ("ab", "action_names 'ab': give a list of 2"),
    (["u1", "u0"], "'u1' is a name the equations already use"),
    (["sin", "b"], "'sin' is a name the equations already use"),
    (["a", "b c"], "'b c' is not a name"),
])
def test_ambiguous_action_names_are_refused(fitted, names, needle) -> None:
    """Before: accepted, and the equations read ambiguously (z0 for an action and a latent)."""
    with pytest.raises(UserError, match=needle):
        _data(action_names=names)
    with pytest.raises(UserError, match=needle):
        fitted[1].equations(action_names=names)
    assert _data(action_names=["u0", "u1"]).action_names == ("u0", "u1")  # the defaults


def test_a_bare_u_or_z_names_an_action(fitted) -> None:
    """The equations write single variables (z0, u1), never a bare u or z: those are free."""
    assert _data(nu=1, action_names=["u"]).action_names == ("u",)
    assert _data(action_names=["z", "u"]).action_names == ("z", "u")
    lines = fitted[1].equations(precision=12, action_names=["u", "z"])
    assert not any(t in line for line in lines for t in ("u0", "u1"))


def test_second_derivatives_without_first_are_refused() -> None:
    """Before: SequenceData accepted images_ddot alone."""
    data = _data(dtype=np.float32)
    with pytest.raises(UserError, match="images_ddot without images_dot"):
        SequenceData(data.images, data.actions, [-1, -1], [1, 1],
                     images_ddot=np.zeros_like(data.images))
