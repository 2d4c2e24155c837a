"""How far the block is from its goal, and which success criteria that meets: the course's
(position within ``success_distance``) and the strict one (``strict_distance`` and
``strict_angle_deg``), orientation compared modulo the block's visible symmetry."""

from __future__ import annotations

import math

import numpy as np

from latent_sindy.worlds.push.config import PushEnvConfig

__all__ = ["goal_criteria", "wrap_angle"]


def wrap_angle(a: float, period: float = 2 * math.pi) -> float:
    """Map an angle to (-period/2, period/2] (default: (-pi, pi])."""
    return -((-a + period / 2) % period - period / 2)


def goal_criteria(cfg: PushEnvConfig, pose: np.ndarray, goal: np.ndarray) -> dict:
    """distance (m), angle_error (rad), is_success (course), is_success_strict."""
    dist = float(np.hypot(*(pose[:2] - goal[:2])))
    dth = wrap_angle(float(pose[2] - goal[2]), cfg.angle_period)
    angle_ok = cfg.success_angle_deg is None or abs(math.degrees(dth)) < cfg.success_angle_deg
    return {
        "distance": dist,
        "angle_error": dth,
        "is_success": bool(dist < cfg.success_distance and angle_ok),
        "is_success_strict": bool(dist < cfg.strict_distance
                                  and abs(math.degrees(dth)) < cfg.strict_angle_deg),
    }
