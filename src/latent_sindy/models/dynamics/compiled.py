"""The frozen fast form of a SINDy model for control: only its active library terms."""

from __future__ import annotations

from collections.abc import Sequence

import torch

from latent_sindy.models.dynamics.base import LatentDynamics
from latent_sindy.sindy import LibrarySubset

__all__ = ["CompiledSindy"]


class CompiledSindy(LatentDynamics):
    """Fast, frozen SINDy step over the terms active in any state (for control).

    ``z_{t+1} = z_t + Θ_S(z_t, u_t) C_S`` with S the active terms, Θ_S (K, |S|) and
    C_S = (M ⊙ Ψ)[S] (|S|, nz) stored as a buffer; the model's circle, if any, is kept.
    Made by :meth:`SindyDynamics.compile_sparse
    <latent_sindy.models.dynamics.sindy.SindyDynamics.compile_sparse>`.
    """

    kind = "sindy-sparse"
    coef: torch.Tensor  # (|S|, nz)

    def __init__(self, library: LibrarySubset, coef: torch.Tensor, nu: int,
                 circle: Sequence[int] | None, turn: bool) -> None:
        super().__init__(coef.shape[1], nu, circle, turn)
        self.library = library
        self.register_buffer("coef", coef.detach().clone())  # (|S|, nz)

    @property
    def names(self) -> list[str]:
        return self.library.names

    def _step(self, z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return z + self.library(z, u) @ self.coef  # (K, nz)
