"""Independently moving parts found from the pixels (latent_sindy.models.parts)."""

import numpy as np
import torch

from latent_sindy.models.parts import moving_parts


def blobs(angles: np.ndarray, pivots: list[float], size: int = 32, width: float = 0.01
          ) -> torch.Tensor:
    """Frames (n, F, size²) of one blob per column of ``angles`` (n, F, blobs), each on a
    circle of radius 0.35 about its pivot (x, 0)."""
    axis = np.linspace(-1, 1, size)
    X, Y = np.meshgrid(axis, axis[::-1])
    out = np.zeros((*angles.shape[:2], size, size))
    for b, px in enumerate(pivots):
        cx = px + 0.35 * np.sin(angles[..., b])
        cy = -0.35 * np.cos(angles[..., b])
        out += np.exp(-((X - cx[..., None, None]) ** 2 + (Y - cy[..., None, None]) ** 2) / width)
    return torch.from_numpy(out.reshape(*angles.shape[:2], -1))


def swings(rng: np.random.Generator, n: int, frames: int, blobs_: int) -> np.ndarray:
    t = np.linspace(0, 6, frames)
    amp = rng.uniform(0.5, 2.5, (n, 1, blobs_))
    phase = rng.uniform(0, 2 * np.pi, (n, 1, blobs_))
    rate = rng.uniform(0.8, 1.6, (1, 1, blobs_))
    return amp * np.sin(rate * t[None, :, None] + phase)


def test_two_independent_pendulums_are_two_parts_one_on_each_side():
    rng = np.random.default_rng(0)
    frames = blobs(swings(rng, 30, 80, 2), [-0.5, 0.5])
    parts = moving_parts(frames, 2)
    assert parts is not None and len(parts) == 2
    columns = sorted(float((p % 32).double().mean()) for p in parts)
    assert columns[0] < 14 and columns[1] > 18
    assert not set(parts[0].tolist()) & set(parts[1].tolist())


def test_one_pendulum_is_not_split_into_two_parts():
    rng = np.random.default_rng(1)
    assert moving_parts(blobs(swings(rng, 30, 80, 1), [0.0]), 2) is None


def test_the_pixels_a_part_lights_rarely_are_still_its_own():
    rng = np.random.default_rng(2)
    angles = swings(rng, 60, 80, 2)
    # the second pendulum swings wide in one sequence only: the pixels of its widest swings
    # vary faintly, yet they are its part's, not the other's and not left out
    angles[:, :, 1] *= 0.3
    angles[:1, :, 1] = 2.6 * np.sin(np.linspace(0, 6, 80))[None]
    frames = blobs(angles, [-0.5, 0.5])
    parts = moving_parts(frames, 2)
    assert parts is not None
    right = max(parts, key=lambda p: float((p % 32).double().mean()))
    left = min(parts, key=lambda p: float((p % 32).double().mean()))
    # the pixels only the wide swings light: near the blob's path beyond 60° from the bottom
    axis = np.linspace(-1, 1, 32)
    X, Y = np.meshgrid(axis, axis[::-1])
    wide = np.linspace(1.2, 2.5, 20)
    near = np.zeros(32 * 32, bool)
    for a in wide:
        d = (X - 0.5 - 0.35 * np.sin(a)) ** 2 + (Y + 0.35 * np.cos(a)) ** 2
        near |= (d < 0.003).ravel()
    wide_pixels = set(np.flatnonzero(near).tolist())
    assert len(wide_pixels) >= 10
    assert len(wide_pixels & set(right.tolist())) >= 0.9 * len(wide_pixels)
    assert not wide_pixels & set(left.tolist())
