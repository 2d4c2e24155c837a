"""The controlled pendulum's physics: gymnasium's Pendulum-v1, in numpy and torch.

θ = 0 is upright, g = 10, m = l = 1, dt = 0.05, torque u ∈ [−2, 2]. One step:
θ̇ ← clip(θ̇ + (3g/(2l) sin θ + 3/(m l²) u) dt, −8, 8), then θ ← θ + θ̇ dt; so before the clip
Δθ̇ = 0.75 sin θ + 0.15 u (docs/design.md §6). The state's θ is kept in [−π, π).

    >>> theta, rate = step(np.pi, 0.0, 2.0)       # a push from hanging at rest
    >>> features(np.array([[0.0, 1.0]]))          # (cos θ, sin θ, θ̇): [[1., 0., 1.]]
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = [
    "DT",
    "LENGTH",
    "MASS",
    "MAX_SPEED",
    "MAX_TORQUE",
    "RATE_GAIN",
    "SIN_GAIN",
    "G",
    "feature_step",
    "features",
    "step",
    "wrap_angle",
]

G, MASS, LENGTH, DT = 10.0, 1.0, 1.0, 0.05
MAX_SPEED, MAX_TORQUE = 8.0, 2.0
SIN_GAIN = 3 * G / (2 * LENGTH) * DT  # 0.75: Δθ̇ per unit sin θ
RATE_GAIN = 3 / (MASS * LENGTH ** 2) * DT  # 0.15: Δθ̇ per unit torque


def wrap_angle(theta: np.ndarray | float) -> np.ndarray:
    """θ wrapped into [−π, π)."""
    return (np.asarray(theta) + np.pi) % (2 * np.pi) - np.pi


def step(theta: np.ndarray | float, rate: np.ndarray | float,
         torque: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """One step of Pendulum-v1 from (θ, θ̇) under ``torque`` (clipped into the box), batched
    over equal shapes; returns (θ wrapped into [−π, π), θ̇)."""
    u = np.clip(torque, -MAX_TORQUE, MAX_TORQUE)
    new_rate = np.clip(rate + SIN_GAIN * np.sin(theta) + RATE_GAIN * u, -MAX_SPEED, MAX_SPEED)
    return wrap_angle(theta + new_rate * DT), new_rate


def features(states: np.ndarray) -> np.ndarray:
    """States (..., 2) of (θ, θ̇) as (..., 3) features (cos θ, sin θ, θ̇)."""
    states = np.asarray(states)
    return np.stack([np.cos(states[..., 0]), np.sin(states[..., 0]), states[..., 1]], -1)


def feature_step(x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """The true step on features, batched for MPPI: x (K, 3) of (cos θ, sin θ, θ̇), u (K, 1)
    -> (K, 3). An oracle model: what a perfect learned model of the state would predict."""
    theta = torch.atan2(x[:, 1], x[:, 0])  # (K,)
    torque = u[:, 0].clamp(-MAX_TORQUE, MAX_TORQUE)
    rate = (x[:, 2] + SIN_GAIN * x[:, 1] + RATE_GAIN * torque).clamp(-MAX_SPEED, MAX_SPEED)
    theta = theta + rate * DT
    return torch.stack([theta.cos(), theta.sin(), rate], dim=1)
