"""State-space reference models: the same trainer and MPPI on the block's true pose."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from latent_sindy.cli import main
from latent_sindy.data.collect import CollectionPlan, collect
from latent_sindy.data.windows import pose_features
from latent_sindy.training import RunDir, read_metrics

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_pose_features_equal_exactly_for_poses_the_camera_cannot_tell_apart() -> None:
    period = math.pi / 2
    poses = np.array([[0.5, 0.1, 0.3], [0.5, 0.1, 0.3 + period], [0.5, 0.1, 0.3 - 3 * period],
                      [0.5, 0.1, 0.3 + period / 2]])
    f = pose_features(poses, period)
    torch.testing.assert_close(f[1], f[0], atol=1e-6, rtol=0)
    torch.testing.assert_close(f[2], f[0], atol=1e-6, rtol=0)
    assert (f[3] - f[0]).abs().max() > 1  # a quarter period on: opposite features
    assert f.shape == (4, 4) and torch.allclose(f[:, 2] ** 2 + f[:, 3] ** 2, torch.ones(4))


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    return collect(tmp_path_factory.mktemp("d") / "d.h5",
                   CollectionPlan(trajectories=4, steps=3, val_fraction=0.25, test_fraction=0),
                   workers=1)


@pytest.mark.parametrize("kind", ["sindy", "linear", "mlp"])
def test_a_state_model_trains_on_poses_and_pushes(data: Path, tmp_path: Path, kind: str) -> None:
    out = tmp_path / kind
    assert main(["train", kind, "state", "--data", str(data), "--out", str(out), "--epochs", "30",
                 "--batch-size", "4", "--lr", "1e-2", "--no-progress"]) == 0
    rows = read_metrics(out)
    assert all(r["train/recon"] == 0 for r in rows)  # the state is observed exactly
    assert rows[-1]["train/pred_z"] < rows[0]["train/pred_z"]
    run = RunDir(out).load()
    assert run.model.config.encoder.latent_dim == 4 and run.normalizer.std == 1.0
    assert main(["control", str(out), "--task", "random", "--max-steps", "2", "--samples", "16",
                 "--horizon", "2", "--gif-episodes", "0", "--no-progress"]) == 0
    assert (out / "control-random-latent" / "results.json").exists()
