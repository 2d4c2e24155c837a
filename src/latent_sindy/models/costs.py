"""Diagonal weights Q of a quadratic latent cost, from what the latent coordinates are.

A planner's latent cost is (z − z_goal)ᵀ Q (z − z_goal) with Q diagonal. Errors of different
kinds are put on one scale by saying what error costs 1: ``position_scale`` in a coordinate
that is a position, ``angle_scale`` (radians) in an angle θ held as a pair of features
(cos 2πθ/P, sin 2πθ/P) of period P, whose error e moves them 2 − 2 cos(2πe/P) apart, squared.
Other coordinates weigh 1. Which coordinates are which, and the scales, are the caller's:
the world knows its criteria, the observation its units.

    >>> cost_weights(4, positions=(0, 1), position_scale=0.02, circle=(2, 3),
    ...              period=math.pi / 2, angle_scale=math.radians(10))
    tensor([2500.0000, 2500.0000,    3.1171,    3.1171])
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

__all__ = ["cost_weights"]


def cost_weights(nz: int, positions: Sequence[int] = (), position_scale: float = 1.0,
                 circle: Sequence[int] | None = None, period: float = 2 * math.pi,
                 angle_scale: float = math.pi / 2) -> torch.Tensor:
    """Q (nz,): 1 / ``position_scale``² at the coordinates ``positions``; at the pair
    ``circle`` = (a, b) of an angle's (cos, sin) features (the angle's ``period``) the weight
    at which an angle error of ``angle_scale`` costs 1 (an error past half a period costs as
    much as half a period); 1 elsewhere."""
    if position_scale <= 0 or not 0 < angle_scale < math.inf or period <= 0:
        raise ValueError(f"cost scales must be > 0: position_scale {position_scale}, "
                         f"angle_scale {angle_scale}, period {period}")
    q = [1.0] * nz
    for i in positions:
        q[i] = 1.0 / position_scale**2
    if circle is not None:
        e = angle_scale * 2 * math.pi / period
        a = 1.0 / (2.0 - 2.0 * math.cos(min(e, math.pi)))
        for i in circle:
            q[i] = a
    return torch.tensor(q)
