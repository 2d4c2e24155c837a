"""A sparsifier's setting chosen on held-out trajectories: the sparsest model that still
predicts them.

A sparsifier's setting trades terms for accuracy, and the one-step residual it bounds says
little of what a planner needs, many steps of prediction. On data that lie on a manifold,
two models with equal one-step fits can differ in whether their rollouts stay near it.
:func:`select_on_rollouts` fits a path of settings, rolls every fitted model out from the
first state of each held-out trajectory under its recorded inputs, and keeps the sparsest
model whose rollout error is within ``slack`` times the best on the path.

    >>> choice = select_on_rollouts(library, Z, U, Znext, X_val, U_val)
    >>> choice.model.coef_, choice.setting   # the chosen fit and its tolerance
    >>> print(choice.table())                # the whole path: terms and rollout error
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from latent_sindy.errors import UserError
from latent_sindy.sindy.fit import Sparsifier, fit_state_data
from latent_sindy.sindy.stepwise import StepwiseSR
from latent_sindy.sindy.torch_library import SindyLibrary

__all__ = ["TOLERANCES", "PathPoint", "Selection", "rollout_error", "select_on_rollouts"]

TOLERANCES: tuple[float, ...] = tuple(float(t) for t in 10.0 ** np.linspace(-5, -2, 13))
"""StepwiseSR tolerances tried by default: 1e-5 to 1e-2, four to a decade."""


@dataclass(frozen=True)
class PathPoint:
    """One setting on the path: its active terms and its held-out rollout error."""

    setting: float
    active: int
    error: float
    """Mean over trajectories and steps of the rollout's distance from the data, each latent
    in units of its spread over the data; inf where a rollout left the floats."""


@dataclass(frozen=True)
class Selection:
    """The chosen fit, its setting, and the path it was chosen from."""

    model: Sparsifier
    setting: float
    path: tuple[PathPoint, ...]

    def table(self) -> str:
        """The path as text: a line per setting, the chosen one marked."""
        return "\n".join(
            f"{'*' if p.setting == self.setting else ' '} setting {p.setting:.3g}: "
            f"{p.active} terms, rollout error {p.error:.4g}" for p in self.path)


@torch.no_grad()
def rollout_error(library: SindyLibrary, coef: torch.Tensor, X: torch.Tensor,
                  U: torch.Tensor) -> float:
    """Mean distance of the rollouts ``x_{t+1} = x_t + Θ(x_t, u_t) coef`` from ``X`` (B, T+1,
    nz), started at ``X[:, 0]`` under ``U`` (B, T, nu), each latent divided by its standard
    deviation over ``X``; inf when a rollout overflows."""
    X = torch.as_tensor(X, dtype=torch.float64)
    U = torch.as_tensor(U, dtype=torch.float64)
    if X.ndim != 3 or U.ndim != 3 or U.shape[:2] != (X.shape[0], X.shape[1] - 1):
        raise ValueError(f"rollout_error: X (B, T+1, nz) and U (B, T, nu) do not match: got "
                         f"{tuple(X.shape)} and {tuple(U.shape)}")
    spread = X.reshape(-1, X.shape[-1]).std(0).clamp_min(1e-12)
    coef = torch.as_tensor(coef, dtype=torch.float64)
    x, total = X[:, 0], 0.0
    for t in range(U.shape[1]):
        x = x + library(x, U[:, t]) @ coef
        step = float(((x - X[:, t + 1]) / spread).norm(dim=-1).mean())
        if not math.isfinite(step):
            return math.inf
        total += step
    return total / max(U.shape[1], 1)


def select_on_rollouts(
    library: SindyLibrary,
    Z: torch.Tensor,
    U: torch.Tensor,
    Znext: torch.Tensor,
    X_val: torch.Tensor,
    U_val: torch.Tensor,
    settings: Sequence[float] = TOLERANCES,
    make: Callable[[float], Sparsifier] | None = None,
    slack: float = 3.0,
) -> Selection:
    """Fit ``Znext − Z ≈ Θ(Z, U) Ψ`` at every setting and keep the sparsest fit whose rollout
    error on the held-out trajectories is at most ``slack`` times the best one's.

    Args:
        library: the candidate library.
        Z, U, Znext: (N, nz), (N, nu), (N, nz) training transitions.
        X_val, U_val: (B, T+1, nz) held-out trajectories and (B, T, nu) their inputs.
        settings: the sparsifier settings tried.
        make: a setting -> a fresh sparsifier (default: ``StepwiseSR(setting,
            complexity=library.degrees)``).
        slack: how much worse than the best a sparser fit may roll out (>= 1).

    Raises:
        UserError: no settings, a slack below 1, or no fit that rolls out finitely.
    """
    if not settings:
        raise UserError("select_on_rollouts: give at least one setting to try")
    if not (isinstance(slack, (int, float)) and math.isfinite(slack) and slack >= 1):
        raise UserError(f"select_on_rollouts slack={slack!r} is not valid: use a number >= 1")
    if make is None:
        def make(setting: float) -> Sparsifier:
            return StepwiseSR(setting, complexity=library.degrees)
    fits, path = [], []
    for setting in settings:
        fit = fit_state_data(library, Z, U, Znext, make(float(setting)))
        coef = fit.coef_ * fit.mask_
        fits.append(fit)
        path.append(PathPoint(float(setting), int(fit.mask_.sum()),
                              rollout_error(library, coef, X_val, U_val)))
    best = min(p.error for p in path)
    if not math.isfinite(best):
        raise UserError("select_on_rollouts: every fit's rollouts diverged on the held-out "
                        "trajectories: try smaller settings or a richer library")
    ok = [k for k, p in enumerate(path) if p.error <= slack * best]
    k = min(ok, key=lambda i: (path[i].active, path[i].error))
    return Selection(fits[k], path[k].setting, tuple(path))
