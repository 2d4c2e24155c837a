"""Training windows line up images with actions; normalisation uses training data only."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from latent_sindy.data.windows import Normalizer, WindowDataset
from latent_sindy.errors import UserError
from synthetic import make_trajectories


@pytest.mark.parametrize("window", [1, 2, 4])
def test_windows_count_and_alignment(window):
    data = make_trajectories(n=3, steps=4)
    norm = Normalizer.from_trajectories(data)
    ds = WindowDataset(data, window, norm)
    assert len(ds) == 3 * (4 - window + 1)
    x, u = ds[len(ds) - 1]  # last window of the last trajectory
    assert x.shape == (window + 1, 1, 32, 32) and u.shape == (window, 3)
    t0 = 4 - window
    assert torch.allclose(norm.denormalize(x), torch.as_tensor(
        data.images[2, t0:], dtype=torch.float32), atol=1e-3)
    assert torch.equal(u, torch.as_tensor(data.actions[2, t0:]))
    xs, us = ds.tensors()
    assert torch.equal(xs[len(ds) - 1], x) and torch.equal(us[len(ds) - 1], u)
    assert torch.equal(xs[1], ds[1][0]) and torch.equal(us[1], ds[1][1])


def test_normalised_training_images_have_zero_mean_unit_std():
    data = make_trajectories(n=6, steps=3)
    norm = Normalizer.from_trajectories(data)
    x = norm.normalize(data.split("train").images).double()
    assert x.mean().item() == pytest.approx(0.0, abs=1e-5)
    assert x.std(unbiased=False).item() == pytest.approx(1.0, abs=1e-4)
    assert Normalizer.from_dict(norm.to_dict()) == norm


def test_impossible_horizon_and_constant_images():
    data = make_trajectories(n=3, steps=4)
    norm = Normalizer.from_trajectories(data)
    with pytest.raises(UserError, match="window 5"):
        WindowDataset(data, 5, norm)
    with pytest.raises(UserError, match="window 0"):
        WindowDataset(data, 0, norm)
    data.images[:] = 200
    with pytest.raises(UserError, match="constant"):
        Normalizer.from_trajectories(data)
    assert np.all(data.images == 200)
