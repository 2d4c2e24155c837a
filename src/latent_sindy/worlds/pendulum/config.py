"""The controlled pendulum's settings: the camera and where tasks start.

The physics are gymnasium's Pendulum-v1 and fixed (:mod:`.physics`); the goal is always
upright at rest.

    >>> PendulumConfig(start="random", image_size=32)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from latent_sindy.errors import UserError

__all__ = ["PendulumConfig"]


@dataclass(frozen=True)
class PendulumConfig:
    """Settings of the controlled pendulum world."""

    image_size: int = 48
    """Side of the square camera image in pixels (E2C's 48)."""
    start: Literal["hanging", "random"] = "hanging"
    """Where tasks start: hanging down (θ = π, slightly perturbed) or anywhere (θ uniform in
    [−π, π), θ̇ uniform in [−1, 1], as Pendulum-v1's own reset)."""
    perturbation: float = 0.1
    """Hanging starts: θ = π + U(−p, p) rad and θ̇ = U(−p, p) rad/s."""

    def __post_init__(self) -> None:
        if isinstance(self.image_size, bool) or not isinstance(self.image_size, int) \
                or not 8 <= self.image_size <= 512:
            raise UserError(f"pendulum image_size {self.image_size!r}: use an integer in "
                            "8..512 (48 is E2C's)")
        if self.start not in ("hanging", "random"):
            raise UserError(f"pendulum start {self.start!r}: use 'hanging' or 'random'")
        if not (math.isfinite(self.perturbation) and 0 <= self.perturbation <= math.pi):
            raise UserError(f"pendulum perturbation {self.perturbation!r}: use a number of "
                            "radians in [0, π]")
