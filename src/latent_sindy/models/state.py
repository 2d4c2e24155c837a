"""The state-space "encoder": a true pose instead of an image, for reference models.

A state-space model sees the pose (x, y, θ) of the one moving object, encoded so that poses
the camera cannot tell apart are equal: s = (x, y, cos(2πθ/P), sin(2πθ/P)), P the object's
visible rotational symmetry (the world's). The encoding is done by the data pipeline
(:mod:`latent_sindy.data.windows`); here encoder and decoder are the identity, so the same
latent model, loss (its reconstruction term is then 0) and trainer fit the dynamics directly
on states. These models are the upper bound the image models are measured against; they
never see an image.

    latent-sindy train sindy --order 1 --library push --lambda-l1 1e-4 state --out runs/s
    latent-sindy train mlp --harmonics 4 state --out runs/m
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import nn

from latent_sindy.errors import UserError
from latent_sindy.models.costs import cost_weights

__all__ = ["ANGLE_FEATURES", "STATE_DIM", "StateCodec", "StateConfig", "pose_cost_weights"]

#: (x, y, cos(2πθ/P), sin(2πθ/P))
STATE_DIM = 4
#: Where the angle features (cos, sin) lie in the pose: a pose latent's dynamics keep them on
#: the unit circle (:class:`~latent_sindy.models.dynamics.LatentDynamics`'s ``circle``).
ANGLE_FEATURES = (2, 3)


@dataclass(frozen=True)
class StateConfig:
    """The true pose as the latent state (a reference model; no image is used).

    Its two scales are those of MPPI's cost on the pose (:func:`pose_cost_weights`)."""

    kind: ClassVar[str] = "state"
    position_scale: float = 0.02
    """Position error (m) that costs 1 in MPPI's latent cost (the strict criterion's 2 cm).
    The cost must be on this scale, not in metres: against MPPI's temperature λ = 0.01 the
    cost differences of metres near the goal (1e-4) weigh every sample alike, and the plan
    becomes a random walk (the state MLP then met the strict criterion in 15 % of 20 random
    tasks, and in 85 % with this scale)."""
    angle_scale_deg: float = 10.0
    """Orientation error (degrees, modulo the object's symmetry) that costs 1 (the strict
    criterion's 10°)."""

    def __post_init__(self) -> None:
        for name, v in (("position-scale", self.position_scale),
                        ("angle-scale-deg", self.angle_scale_deg)):
            if not (0 < v < float("inf")):
                raise UserError(f"--{name} {v}: use a finite number > 0")

    @property
    def latent_dim(self) -> int:
        return STATE_DIM

    @property
    def resolved(self) -> bool:
        return True

    @property
    def pose_latent(self) -> bool:
        """The latent is the pose features (a library written on a pose latent can write
        dynamics on it)."""
        return True

    @property
    def fixed_encoder(self) -> bool:
        """The encoder learns nothing: the latents are the data's poses."""
        return True

    def resolve(self, channels: int, image_size: int | tuple[int, int],
                source: str = "the data") -> StateConfig:
        return self  # the pose does not depend on the images

    def build(self) -> StateCodec:
        return StateCodec(self)


class StateCodec(nn.Module):
    """Identity encoder and decoder of encoded poses s (..., 4)."""

    def __init__(self, cfg: StateConfig) -> None:
        super().__init__()
        self.config = cfg

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        return x

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        return z

    def fit_statistics(self, frames: torch.Tensor) -> None:
        """Nothing to take from the training data."""

    def cost_weights(self, period: float) -> torch.Tensor:
        """Q of MPPI's cost: :func:`pose_cost_weights` on this config's scales."""
        return pose_cost_weights(period, self.config)


def pose_cost_weights(period: float, scales: StateConfig | None = None) -> torch.Tensor:
    """The diagonal Q (4,) of a quadratic cost on pose features s (period P of the angle's
    features): an error of ``position_scale`` in x or y, or of ``angle_scale_deg`` in
    orientation, costs 1 (:func:`~latent_sindy.models.costs.cost_weights`). ``scales`` None:
    the defaults of :class:`StateConfig` (2 cm and 10°)."""
    scales = scales or StateConfig()
    return cost_weights(STATE_DIM, positions=(0, 1), position_scale=scales.position_scale,
                        circle=ANGLE_FEATURES, period=period,
                        angle_scale=math.radians(scales.angle_scale_deg))
