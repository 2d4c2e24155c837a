"""The state-space "encoder": the block's true pose instead of an image, for reference models.

A state-space model sees the pose (x, y, θ) encoded so that poses the camera cannot tell apart
are equal: s = (x, y, cos(2πθ/P), sin(2πθ/P)), P the block's visible rotational symmetry
(:attr:`~latent_sindy.envs.config.PushEnvConfig.angle_period`). The encoding is done by the
data pipeline (:mod:`latent_sindy.data.windows`); here encoder and decoder are the identity,
so the same latent model, loss (its reconstruction term is then 0) and trainer fit the
dynamics directly on states. These models are the upper bound the image models are measured
against; they never see an image.

    latent-sindy train sindy --order 1 --library push --lambda-l1 1e-4 state --out runs/s
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import nn

from latent_sindy.errors import UserError

__all__ = ["STATE_DIM", "StateCodec", "StateConfig"]

#: (x, y, cos(2πθ/P), sin(2πθ/P))
STATE_DIM = 4


@dataclass(frozen=True)
class StateConfig:
    """The true pose as the latent state (a reference model; no image is used)."""

    kind: ClassVar[str] = "state"
    angle_weight: float = 0.01
    """Weight of the two orientation features in MPPI's latent cost, against 1 for x and y
    (metres): small, so the planner reaches the position first."""

    def __post_init__(self) -> None:
        if not (0 <= self.angle_weight < float("inf")):
            raise UserError(f"--angle-weight {self.angle_weight}: use a finite number >= 0")

    @property
    def latent_dim(self) -> int:
        return STATE_DIM

    @property
    def resolved(self) -> bool:
        return True

    def resolve(self, channels: int, image_size: int, source: str = "the data") -> StateConfig:
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

    def cost_weights(self) -> torch.Tensor:
        w = self.config.angle_weight
        return torch.tensor([1.0, 1.0, w, w])
