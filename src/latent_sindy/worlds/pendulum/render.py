"""The controlled pendulum's camera: a bright rod on black, anti-aliased, from the pivot at
the image's centre; two consecutive frames stacked as channels, so the rate is visible.

The rod points up at θ = 0 and turns counter-clockwise as θ grows: its tip is at
(−sin θ, cos θ)·ROD (x right, y up). Since θ_t = θ_{t−1} + θ̇_t dt exactly (Pendulum-v1's
update), the previous frame of a state (θ, θ̇) is the rod at θ − θ̇ dt, and an observation
is a function of the state alone.

    >>> obs = observe(np.pi, 0.0)        # hanging at rest: (2, 48, 48) uint8, equal frames
    >>> rods(np.array([0.0, 1.0]), 32)   # (2, 32, 32) uint8
"""

from __future__ import annotations

import numpy as np

from latent_sindy.worlds.pendulum.physics import DT

__all__ = ["ROD", "observe", "rods"]

ROD = 0.8
"""Rod length as a fraction of the image's half-width."""
_THICKNESS = 1 / 16
"""Rod half-thickness as a fraction of the image's side (1.5 px at 48×48)."""


def rods(theta: np.ndarray, size: int = 48) -> np.ndarray:
    """Frames (..., size, size) uint8 of the rod at angles ``theta`` (...)."""
    theta = np.asarray(theta, np.float64)
    half = (size - 1) / 2
    px = np.arange(size) - half  # pixel centres, relative to the pivot
    x = px[None, :]  # (1, size): column offset, to the right
    y = -px[:, None]  # (size, 1): row offset, upwards
    tip = ROD * (size / 2)
    dx = (-np.sin(theta) * tip)[..., None, None]  # (..., 1, 1) the rod's vector
    dy = (np.cos(theta) * tip)[..., None, None]
    # distance from each pixel centre to the segment from the pivot to the tip
    s = np.clip((x * dx + y * dy) / (tip * tip), 0.0, 1.0)
    dist = np.hypot(x - s * dx, y - s * dy)
    # coverage of a pixel by a rod edge at distance d from its centre (a 1-pixel ramp)
    cover = np.clip(_THICKNESS * size + 0.5 - dist, 0.0, 1.0)
    return np.round(255 * cover).astype(np.uint8)


def observe(theta: np.ndarray | float, rate: np.ndarray | float, size: int = 48) -> np.ndarray:
    """The observation (..., 2, size, size) uint8 of states (θ, θ̇): the frame a step ago
    (the rod at θ − θ̇ dt) and the frame now."""
    theta, rate = np.asarray(theta, np.float64), np.asarray(rate, np.float64)
    return np.stack([rods(theta - rate * DT, size), rods(theta, size)], axis=-3)
