"""The controlled pendulum's success criteria, on one state and on a whole episode.

E2C, PCC and PC3 score a swing-up controller by the fraction of time the pendulum spends near
upright; a swing-up succeeds here when the pendulum stays within 10° of upright over the
last 20 of 100 steps.

    >>> upright(np.array([[0.1, 0.0], [3.0, 0.0]]))                    # [True, False]
    >>> upright_fraction(states), swing_up_success(states, last=20)     # states (T, 2)
"""

from __future__ import annotations

import math

import numpy as np

from latent_sindy.errors import UserError
from latent_sindy.worlds.pendulum.physics import wrap_angle

__all__ = ["UPRIGHT_DEG", "swing_up_success", "upright", "upright_fraction"]

UPRIGHT_DEG = 10.0
"""Within this many degrees of θ = 0 counts as upright."""


def upright(states: np.ndarray, tolerance_deg: float = UPRIGHT_DEG) -> np.ndarray:
    """Per state (..., 2) of (θ, θ̇): is θ within ``tolerance_deg`` of upright? (...) bool."""
    theta = np.asarray(states)[..., 0]
    return np.abs(wrap_angle(theta)) <= math.radians(tolerance_deg)


def upright_fraction(states: np.ndarray, tolerance_deg: float = UPRIGHT_DEG) -> float:
    """The fraction of the states (T, 2) of an episode that are upright."""
    states = np.asarray(states)
    if states.ndim != 2 or states.shape[1] != 2 or len(states) == 0:
        raise UserError(f"upright_fraction takes an episode's states (T, 2) of (θ, θ̇), got "
                        f"shape {states.shape}")
    return float(np.mean(upright(states, tolerance_deg)))


def swing_up_success(states: np.ndarray, last: int = 20,
                     tolerance_deg: float = UPRIGHT_DEG) -> bool:
    """Whether each of the ``last`` states of an episode (T, 2) is upright."""
    states = np.asarray(states)
    if states.ndim != 2 or states.shape[1] != 2 or len(states) < last or last < 1:
        raise UserError(f"swing_up_success needs an episode's states (T, 2) with T >= "
                        f"last = {last} >= 1, got shape {states.shape}")
    return bool(np.all(upright(states[-last:], tolerance_deg)))
