"""SINDy on the pendulum's true state: what the data say about the physics, and a model an
oracle planner can use.

The state's features x = (cos θ, sin θ, θ̇) and the torque u; the library holds all
monomials of (x, u) up to ``order``; STLSQ fits x[t+1] − x[t]. The rate's row should read
Δθ̇ = 0.75 sin θ + 0.15 u (the discretised physics, docs/design.md §6); the angle's rows
are a polynomial approximation of the rotation by θ̇ dt. Steps where the rate hit its
clip (±8) are left out of the fit.

    >>> model = StateSindy().fit(data)     # data: PendulumWorld(...).collect(...)
    >>> print("\\n".join(model.equations()))
    >>> x_next = model.step(x, u)          # (K, 3), (K, 1) -> (K, 3)
"""

from __future__ import annotations

import numpy as np
import torch

import latent_sindy.worlds.pendulum.physics as physics
from latent_sindy.data import SequenceData
from latent_sindy.errors import UserError
from latent_sindy.sindy import Polynomial, SindyLibrary
from latent_sindy.sindy.fit import fit_state_data

__all__ = ["FEATURE_NAMES", "StateSindy"]

FEATURE_NAMES = ("cos θ", "sin θ", "θ_dot")


class StateSindy:
    """Sparse regression of the state features' steps on a polynomial library."""

    def __init__(self, order: int = 2) -> None:
        self.order = order
        self.library = SindyLibrary(Polynomial("z,u", order), n_state=3, n_control=1)

    def fit(self, data: SequenceData) -> StateSindy:
        if data.states is None or data.states.shape[-1] != 2:
            raise UserError(f"{data.source}: the state SINDy needs the pendulum's states "
                            "(θ, θ̇); these data have none")
        x = physics.features(data.states.astype(np.float64))  # (N, T+1, 3)
        z, z_next = x[:, :-1].reshape(-1, 3), x[:, 1:].reshape(-1, 3)
        u = data.actions.reshape(-1, 1).astype(np.float64)
        keep = np.abs(z_next[:, 2]) < physics.MAX_SPEED
        fit = fit_state_data(self.library, *(torch.tensor(a[keep]) for a in (z, u, z_next)))
        coef = torch.as_tensor(fit.coef_, dtype=torch.float64) * torch.as_tensor(fit.mask_)
        self.coef_ = coef.clone()  # (p, 3), pruned entries 0
        self.mask_ = np.asarray(fit.mask_, bool)
        return self

    def sparsity(self) -> float:
        """Fraction of the library's coefficients pruned."""
        return float(1 - self.mask_.mean())

    def equations(self, precision: int = 3) -> list[str]:
        names = [self._rename(n) for n in self.library.names]
        lines = []
        for i, state in enumerate(FEATURE_NAMES):
            terms = [f"{float(self.coef_[j, i]):+.{precision}g}"
                     + ("" if names[j] == "1" else f" {names[j]}")
                     for j in np.flatnonzero(self.mask_[:, i])]
            lines.append(f"Δ{state} = " + (" ".join(terms) if terms else "0"))
        return lines

    @staticmethod
    def _rename(name: str) -> str:
        for k, v in (("z0", "cos θ"), ("z1", "sin θ"), ("z2", "θ_dot"), ("u0", "torque")):
            name = name.replace(k, v)
        return name

    def step(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """x (K, 3), u (K, 1) -> (K, 3): the fitted step (torque clipped into the box)."""
        return sindy_step(self.library, self.coef_, x, u)


@torch.no_grad()
def sindy_step(library, coef: torch.Tensor, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """x + Θ(x, u) Ξ in float64 for x (K, n), u (K, 1), the torque clipped into the box."""
    x64 = x.to(torch.float64)
    u64 = u.to(torch.float64).clamp(-physics.MAX_TORQUE, physics.MAX_TORQUE)
    return (x64 + library(x64, u64) @ coef).to(x.dtype)
