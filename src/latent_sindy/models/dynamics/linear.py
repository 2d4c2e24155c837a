"""The globally linear latent model (the E2C baseline): z[t+1] = A z + B u + c, its
closed-form fit and its config.

    >>> model = LinearConfig().build(nz=4, nu=2)
    >>> model.fit_least_squares(Z, U, Znext)  # Z (N, 4), U (N, 2), Znext (N, 4)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import torch
from torch import nn

from latent_sindy.models.dynamics.base import (
    LatentDynamics,
    Row,
    check_init_scale,
    format_equations,
)

__all__ = ["LinearConfig", "LinearDynamics"]


class LinearDynamics(LatentDynamics):
    """Globally linear latent model ``z_{t+1} = A z_t + B u_t + c`` (the E2C-style baseline).

    A (nz, nz) starts near the identity, B (nz, nu) small, c (nz,) zero; ``circle``: see
    :class:`LatentDynamics`.
    """

    kind = "linear"

    def __init__(self, nz: int, nu: int, init_scale: float = 1e-3, seed: int | None = None,
                 circle: Sequence[int] | None = None, turn: bool = False) -> None:
        super().__init__(nz, nu, circle, turn)
        gen = None if seed is None else torch.Generator().manual_seed(seed)
        self.A = nn.Parameter(torch.eye(nz) + init_scale * torch.randn(nz, nz, generator=gen))
        self.B = nn.Parameter(init_scale * torch.randn(nz, nu, generator=gen))
        self.c = nn.Parameter(torch.zeros(nz))
        self._init = {"init_scale": init_scale, "seed": seed}

    def hparams(self) -> dict[str, Any]:
        return {**super().hparams(), **self._init}

    def _step(self, z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return z @ self.A.T + u @ self.B.T + self.c  # (K, nz)

    @torch.no_grad()
    def coefficient_rows(self) -> list[Row]:
        """Every entry of A, B and c, by state: (z_j, z_k | u_k | 1, value)."""
        A, B, c = (p.detach().cpu() for p in (self.A, self.B, self.c))
        rows: list[Row] = []
        for j in range(self.nz):
            rows += [(f"z{j}", f"z{k}", float(A[j, k])) for k in range(self.nz)]
            rows += [(f"z{j}", f"u{k}", float(B[j, k])) for k in range(self.nu)]
            rows.append((f"z{j}", "1", float(c[j])))
        return rows

    def equations(self, precision: int = 3) -> list[str]:
        return format_equations(self.coefficient_rows(), self.nz, precision, residual=False)

    def summary(self) -> list[str]:
        return [f"linear latent dynamics z[t+1] = A z + B u + c (A {self.nz}x{self.nz}, "
                f"B {self.nz}x{self.nu}, c {self.nz}), every coefficient active",
                *self._circle_note()]

    def export_info(self) -> dict[str, Any]:
        return {"n_coefficients": self.nz * (self.nz + self.nu + 1), **super().export_info()}

    def stats(self) -> dict[str, float | None]:
        n = self.nz * (self.nz + self.nu + 1)
        return {**super().stats(), "sindy/active": n, "sindy/coefficients": n}

    @torch.no_grad()
    def fit_least_squares(
        self, Z: torch.Tensor, U: torch.Tensor, Znext: torch.Tensor
    ) -> LinearDynamics:
        """Set A, B, c to the least-squares fit of Znext ≈ A Z + B U + c; returns self.

        Z (N, nz), U (N, nu), Znext (N, nz); solved in float64.
        """
        n = Z.shape[0]
        if U.shape != (n, self.nu) or Z.shape != (n, self.nz) or Znext.shape != Z.shape:
            raise ValueError(
                f"fit_least_squares expects Z, Znext (N, {self.nz}) and U (N, {self.nu}), got "
                f"{tuple(Z.shape)}, {tuple(Znext.shape)}, {tuple(U.shape)}"
            )
        X = torch.cat([Z, U, torch.ones(n, 1, dtype=Z.dtype, device=Z.device)], dim=1)
        W = torch.linalg.lstsq(X.double().cpu(), Znext.double().cpu()).solution  # (nz+nu+1, nz)
        W = W.to(self.A.dtype).to(self.A.device)
        self.A.copy_(W[: self.nz].T)
        self.B.copy_(W[self.nz : self.nz + self.nu].T)
        self.c.copy_(W[-1])
        return self

    @classmethod
    def from_least_squares(
        cls, Z: torch.Tensor, U: torch.Tensor, Znext: torch.Tensor
    ) -> LinearDynamics:
        """A new model fitted by least squares (see :meth:`fit_least_squares`)."""
        return cls(Z.shape[1], U.shape[1]).fit_least_squares(Z, U, Znext)


@dataclass(frozen=True)
class LinearConfig:
    """Globally linear (the E2C baseline): z[t+1] = A z + B u + c."""

    kind: ClassVar[str] = "linear"
    model_class: ClassVar[type[LatentDynamics]] = LinearDynamics
    init_scale: float = 1e-3
    """Standard deviation of A − I and B at initialisation."""

    def __post_init__(self) -> None:
        check_init_scale("linear", self.init_scale)

    def build(self, nz: int, nu: int, circle: Sequence[int] | None = None,
              turn: bool = False) -> LinearDynamics:
        return LinearDynamics(nz, nu, init_scale=self.init_scale, circle=circle, turn=turn)

