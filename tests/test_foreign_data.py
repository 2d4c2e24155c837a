"""A user's own data set, written with h5py alone: RGB frames that are not square, a 2-D action,
no states, no split. It trains through the CLI and through LatentSINDy, prints its equations
with the given action names, predicts one step far better than "nothing moves", saves, loads
and plans toward a goal image."""

from __future__ import annotations

import subprocess
import sys

import h5py
import numpy as np
import pytest

from latent_sindy import LatentSINDy, SequenceData
from latent_sindy.control import MPPIConfig
from latent_sindy.data import read_sequences
from latent_sindy.training import TrainConfig

H, W = 20, 28
STEP = 0.25  # the blob moves by STEP * u per step


def render(p: np.ndarray) -> np.ndarray:
    """A blob at p = (px, py) in [-1, 1]² as an RGB uint8 frame (3, H, W), tinted per channel."""
    ys, xs = np.meshgrid(np.linspace(-1, 1, H), np.linspace(-1.3, 1.3, W), indexing="ij")
    blob = np.exp(-((xs - 1.3 * p[0]) ** 2 + (ys - p[1]) ** 2) / 0.08)
    return np.stack([255 * blob, 160 * blob + 40, 80 + 100 * blob]).astype(np.uint8)


def move(p: np.ndarray, u: np.ndarray) -> np.ndarray:
    return np.clip(p + STEP * u, -0.8, 0.8)


def write_foreign(path, n: int = 48, steps: int = 6, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    images = np.zeros((n, steps + 1, 3, H, W), np.uint8)
    actions = rng.uniform(-1, 1, (n, steps, 2)).astype(np.float32)
    for i in range(n):
        p = rng.uniform(-0.6, 0.6, 2)
        images[i, 0] = render(p)
        for t in range(steps):
            p = move(p, actions[i, t])
            images[i, t + 1] = render(p)
    with h5py.File(path, "w") as f:  # the documented layout, nothing of latent-sindy's
        f["images"] = images
        f["actions"] = actions
        f.attrs["action_low"] = [-1.0, -1.0]
        f.attrs["action_high"] = [1.0, 1.0]
        f.attrs["action_names"] = ["vx", "vy"]


@pytest.fixture(scope="module")
def foreign(tmp_path_factory):
    path = tmp_path_factory.mktemp("foreign") / "blob.h5"
    write_foreign(path)
    return path


@pytest.fixture(scope="module")
def fitted(foreign, one_torch_thread):
    data = read_sequences(foreign)
    model = LatentSINDy(latent_dim=2, order=1, include_sine=False, decoder="conv", seed=0,
                        settings=TrainConfig(lr=3e-3))
    return data, model.fit(data, epochs=60, batch_size=12)


def test_the_file_reads_as_sequence_data(foreign):
    data = read_sequences(foreign)
    assert data.frame_shape == (3, H, W) and data.nu == 2 and data.states is None
    assert data.action_names == ("vx", "vy") and data.world is None
    assert sum(data.split_counts().values()) == 48 and data.split_counts()["val"] >= 1


def test_fit_predicts_far_better_than_nothing_moves(fitted):
    data, model = fitted
    test = data.split("test")
    x, u = test.images[:, :-1].reshape(-1, 3, H, W), test.actions.reshape(-1, 2)
    truth = test.images[:, 1:].reshape(-1, 3, H, W).astype(np.float64)
    pred = model.predict(x, u)
    assert pred.shape == x.shape and pred.dtype == np.float32
    err = np.mean((pred - truth) ** 2)
    still = np.mean((x.astype(np.float64) - truth) ** 2)
    assert err < 0.5 * still, (err, still)
    assert model.score(data) > 0.3


def test_equations_name_the_given_actions(fitted, capsys):
    _, model = fitted
    model.print()
    text = capsys.readouterr().out
    assert "vx" in text and "vy" in text and "u0" not in text
    assert model.coefficients().shape[0] == 2
    assert "speed" in "\n".join(model.equations(action_names=["speed", "turn"]))


def test_save_load_and_plan_toward_a_goal(fitted, tmp_path):
    data, model = fitted
    run = model.save(tmp_path / "run")
    back = LatentSINDy.load(run)
    x = data.images[0, 0]
    np.testing.assert_array_equal(back.predict(x, np.zeros(2)), model.predict(x, np.zeros(2)))
    assert back.equations() == model.equations()

    planner = back.planner(MPPIConfig(samples=200, horizon=4, sigma=0.5), seed=0)
    start, goal = np.array([-0.5, -0.4]), np.array([0.5, 0.4])
    p, goal_image = start.copy(), render(goal)
    for _ in range(10):
        u = planner.act(render(p), goal_image)
        assert u.shape == (2,) and np.all(np.abs(u) <= 1 + 1e-6)
        p = move(p, u)
    assert np.linalg.norm(p - goal) < 0.5 * np.linalg.norm(start - goal)


@pytest.mark.slow  # about 20 s on 2 cores: four CLI processes (the same fit runs in-process)
def test_the_cli_trains_and_prints_on_the_same_file(foreign, tmp_path):
    cli = [sys.executable, "-m", "latent_sindy.cli"]
    run = tmp_path / "cli_run"
    info = subprocess.run([*cli, "info", str(foreign)], capture_output=True, text=True)
    assert info.returncode == 0, info.stderr
    assert "vx [-1, 1]" in info.stdout and "states: none" in info.stdout
    train = subprocess.run([*cli, "train", "sindy", "--order", "1", "--data", str(foreign),
                            "--out", str(run), "--epochs", "3", "--threads", "1",
                            "--no-progress", "image", "--latent-dim", "2"],
                           capture_output=True, text=True)
    assert train.returncode == 0, train.stderr
    eq = subprocess.run([*cli, "equations", str(run)], capture_output=True, text=True)
    assert eq.returncode == 0, eq.stderr
    assert "vx" in eq.stdout
    assert LatentSINDy.load(run).predict(read_sequences(foreign).images[0, 0],
                                         np.ones(2)).shape == (3, H, W)


def test_in_memory_data_without_a_split_is_split_by_seed():
    images = np.zeros((10, 3, 1, 5, 7), np.float32)
    a = SequenceData(images, np.zeros((10, 2, 1), np.float32), [-1], [1])
    b = SequenceData(images, np.zeros((10, 2, 1), np.float32), [-1], [1])
    np.testing.assert_array_equal(a.split_ids, b.split_ids)
    assert a.split_counts() == {"train": 8, "val": 1, "test": 1}
    with pytest.raises(ValueError, match="action box"):
        SequenceData(images, np.zeros((10, 2, 1), np.float32))
    with pytest.raises(ValueError, match=r"lie in \[0, 1\]"):
        SequenceData(images + 2, np.zeros((10, 2, 1), np.float32), [-1], [1])


def test_derivatives_and_executed_flags_round_trip_and_are_checked(tmp_path):
    import numpy as np
    import pytest

    from latent_sindy import SequenceData
    from latent_sindy.data.store import read_sequences, write_sequences
    from latent_sindy.errors import UserError

    rng = np.random.default_rng(0)
    images = rng.random((4, 6, 2, 5, 7)).astype(np.float32)  # two stacked frames per image
    dot = rng.normal(size=images.shape).astype(np.float32)
    executed = np.ones((4, 5), bool)
    executed[1, 2] = False
    data = SequenceData(images, None, images_dot=dot, images_ddot=-dot, executed=executed,
                        dt=0.02)
    write_sequences(tmp_path / "d.h5", data)
    back = read_sequences(tmp_path / "d.h5")
    np.testing.assert_array_equal(back.images_dot, dot)
    np.testing.assert_array_equal(back.images_ddot, -dot)
    np.testing.assert_array_equal(back.executed, executed)
    part = back.subset(np.array([1, 3]))
    assert part.executed.shape == (2, 5) and not part.executed[0, 2]
    assert part.images_dot.shape == (2, 6, 2, 5, 7)
    with pytest.raises(UserError, match="images_dot has shape"):
        SequenceData(images, None, images_dot=dot[:, :3])
    with pytest.raises(UserError, match="executed must be a bool array"):
        SequenceData(images, None, executed=np.ones((4, 6), bool))
