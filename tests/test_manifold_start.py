"""The continuous recipe's start: geodesic coordinates of frames, two latents turned apart."""

import numpy as np
import torch

from latent_sindy.models.manifold import farthest_points, geodesic_coordinates
from latent_sindy.training.manifold_start import choose_rotation


def blob_frames(theta: np.ndarray, size: int = 24, width: float = 0.02) -> torch.Tensor:
    """A blob on a circle at angles ``theta``: frames flattened (N, size²)."""
    axis = np.linspace(-1, 1, size)
    X, Y = np.meshgrid(axis, axis[::-1])
    px, py = 0.6 * np.sin(theta), -0.6 * np.cos(theta)
    f = np.exp(-((X[None] - px[:, None, None]) ** 2 + (Y[None] - py[:, None, None]) ** 2) / width)
    return torch.from_numpy(f.reshape(len(theta), -1))


def r2_affine(x: torch.Tensor, t: np.ndarray) -> float:
    a = np.stack([t, np.ones_like(t)], 1)
    x = x.numpy().ravel()
    res = x - a @ np.linalg.lstsq(a, x, rcond=None)[0]
    return 1 - res.var() / x.var()


def test_farthest_points_spread_over_the_points():
    x = torch.linspace(0, 1, 101).unsqueeze(1).double()
    idx = farthest_points(x, 3, first=0)
    assert sorted(idx.tolist()) == [0, 50, 100]


def test_geodesic_coordinate_of_a_blob_on_an_arc_is_its_angle_up_to_an_affine_map():
    # the arc nearly closes (up to 2.9 rad each side): the height reads it twice, the
    # geodesic coordinate once
    theta = np.random.default_rng(0).uniform(-2.9, 2.9, 3000)
    frames = blob_frames(theta)
    m = geodesic_coordinates(frames, 1, landmarks=300, seed=0)
    z = m.transform(frames)
    assert r2_affine(z, theta) > 0.999
    assert m.eigenvalues[1] < 0.01 * m.eigenvalues[0]  # one-dimensional
    height = frames @ torch.from_numpy(np.linspace(-1, 1, 24).repeat(24)[::-1].copy())
    assert r2_affine(height.unsqueeze(1), theta) < 0.5  # what a PCA latent may settle on


def test_choose_rotation_takes_two_independent_motions_apart():
    rng = np.random.default_rng(3)
    n = 4000
    th = rng.uniform(-2.5, 2.5, (n, 2))
    w = rng.uniform(-1.5, 1.5, (n, 2))
    acc = np.stack([-1.2 * np.sin(th[:, 0]), -2.5 * np.sin(th[:, 1]) - 0.3 * w[:, 1]], 1)
    turn = 0.6
    r = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    mix = lambda x: x @ r.T  # noqa: E731
    phase = torch.from_numpy(np.concatenate([mix(th), mix(w)], 1))
    phi = choose_rotation(phase, torch.from_numpy(mix(acc)))
    # turning back by φ undoes the mix up to a quarter turn (the latents' order and signs)
    back = (phi + turn) % (np.pi / 2)  # R(φ) R(turn) = 1
    assert min(back, np.pi / 2 - back) < 0.02
