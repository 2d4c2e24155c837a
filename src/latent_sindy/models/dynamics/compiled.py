"""The frozen fast form of a SINDy model for control: only its active library terms."""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from latent_sindy.models.dynamics.base import LatentDynamics
from latent_sindy.sindy import LibrarySubset

if TYPE_CHECKING:
    from latent_sindy.models.dynamics.sindy import SindyDynamics

__all__ = ["CompiledSindy"]


class CompiledSindy(LatentDynamics):
    """Fast, frozen SINDy step over the terms active in any state (for control).

    ``z_{t+1} = z_t + Θ_S(z_t, u_t) C_S`` with S the active terms, Θ_S (K, |S|) and
    C_S = (M ⊙ Ψ)[S] (|S|, nz) stored as a buffer; the model's circle, if any, is kept.
    """

    kind = "sindy-sparse"
    coef: torch.Tensor  # (|S|, nz)

    def __init__(self, model: SindyDynamics) -> None:
        super().__init__(model.nz, model.nu, model.circle, model.turn)
        terms = model.active_terms()
        self.library: LibrarySubset = model.library.subset(terms)
        self.register_buffer("coef", model.coefficients().detach()[terms].clone())

    @property
    def names(self) -> list[str]:
        return self.library.names

    def _step(self, z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return z + self.library(z, u) @ self.coef  # (K, nz)
