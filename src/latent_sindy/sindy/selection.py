"""A sparsifier's setting chosen on held-out trajectories: the sparsest model that still
predicts them.

A sparsifier's setting trades terms for accuracy, and the one-step residual it bounds says
little of what a planner needs, many steps of prediction. On data that lie on a manifold,
two models with equal one-step fits can differ in whether their rollouts stay near it.
:func:`select_on_rollouts` fits a path of settings, rolls every fitted model out from the
first state of each held-out trajectory under its recorded inputs, and keeps the sparsest
model whose rollout error is within ``slack`` times the best on the path. A model whose step
ends with a map of its own (``project``: an angle's (cos, sin) pair scaled back onto the
unit circle) is rolled out with it, as it will predict.

    >>> choice = select_on_rollouts(library, Z, U, Znext, X_val, U_val)
    >>> choice.model.coef_, choice.setting   # the chosen fit and its tolerance
    >>> print(choice.table())                # the whole path: terms and rollout error

A continuous-time law is checked the same way on held-out derivatives: :func:`select_law`
compares a trained law with its neighbours (one term added, removed or swapped), each
refitted by least squares, by the fraction of the held-out target's variance it leaves
unexplained (FVU), and keeps the sparsest within ``tolerance`` of the best: a term that a
fixed pruning cut lost comes back where it explains what the others cannot.

    >>> law = select_law(theta_train, zdd_train, theta_val, zdd_val, start=trained_mask)
    >>> law.coef.shape, law.fvu, law.start_fvu   # (p, m), held-out FVU, the trained law's
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

__all__ = ["TOLERANCES", "LawChoice", "PathPoint", "Project", "Selection", "held_out_fvu",
           "rollout_error", "select_law", "select_on_rollouts"]

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


#: A map applied to the state after every step of a rollout, (B, nz) -> (B, nz).
Project = Callable[[torch.Tensor], torch.Tensor]


@torch.no_grad()
def rollout_error(library: SindyLibrary, coef: torch.Tensor, X: torch.Tensor,
                  U: torch.Tensor, project: Project | None = None) -> float:
    """Mean distance of the rollouts ``x_{t+1} = x_t + Θ(x_t, u_t) coef`` from ``X`` (B, T+1,
    nz), started at ``X[:, 0]`` under ``U`` (B, T, nu), each latent divided by its standard
    deviation over ``X``; inf when a rollout overflows. ``project``: what the model's own step
    does after the library's update (e.g. scale an angle's (cos, sin) pair back onto the
    unit circle), applied after every step here too; None: nothing."""
    X = torch.as_tensor(X, dtype=torch.float64)
    U = torch.as_tensor(U, dtype=torch.float64)
    if X.ndim != 3 or U.ndim != 3 or U.shape[:2] != (X.shape[0], X.shape[1] - 1):
        raise ValueError(f"rollout_error: X (B, T+1, nz) and U (B, T, nu) do not match: got "
                         f"{tuple(X.shape)} and {tuple(U.shape)}")
    spread = X.reshape(-1, X.shape[-1]).std(0).clamp_min(1e-12)
    coef = torch.as_tensor(coef, dtype=torch.float64)
    x = X[:, 0]
    total = 0.0
    for t in range(U.shape[1]):
        x = x + library(x, U[:, t]) @ coef
        if project is not None:
            x = project(x)
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
    project: Project | None = None,
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
        project: the model's map after every step (:func:`rollout_error`), so the fits are
            judged by the rollouts the model will make; None: none.

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
    fits = []
    path = []
    for setting in settings:
        fit = fit_state_data(library, Z, U, Znext, make(float(setting)))
        coef = fit.coef_ * fit.mask_
        fits.append(fit)
        path.append(PathPoint(float(setting), int(fit.mask_.sum()),
                              rollout_error(library, coef, X_val, U_val, project)))
    best = min(p.error for p in path)
    if not math.isfinite(best):
        raise UserError("select_on_rollouts: every fit's rollouts diverged on the held-out "
                        "trajectories: try smaller settings or a richer library")
    ok = [k for k, p in enumerate(path) if p.error <= slack * best]
    k = min(ok, key=lambda i: (path[i].active, path[i].error))
    return Selection(fits[k], path[k].setting, tuple(path))


@dataclass
class LawChoice:
    """The law kept: coefficients (p, m) with pruned entries 0, its mask, its held-out FVU
    (the fraction of the held-out target's variance it leaves unexplained), the starting
    law's, and how many laws were compared."""

    coef: np.ndarray
    mask: np.ndarray
    fvu: float
    start_fvu: float
    compared: int = 0


def held_out_fvu(theta: np.ndarray, target: np.ndarray, coef: np.ndarray) -> float:
    """Σ (target − θ coef)² / Σ (target − its mean)², over every sample and column."""
    resid = target - theta @ coef
    spread = ((target - target.mean(0)) ** 2).sum()
    return float((resid ** 2).sum() / max(spread, 1e-300))


def _lstsq(theta: np.ndarray, y: np.ndarray, active: tuple[int, ...]) -> np.ndarray:
    coef = np.zeros(theta.shape[1])
    if active:
        cols = list(active)
        coef[cols] = np.linalg.lstsq(theta[:, cols], y, rcond=None)[0]
    return coef


def select_law(theta: np.ndarray | torch.Tensor, target: np.ndarray | torch.Tensor,
               theta_val: np.ndarray | torch.Tensor, target_val: np.ndarray | torch.Tensor,
               start: np.ndarray, tolerance: float = 0.25, floor: float = 1e-6) -> LawChoice:
    """The law of each target column chosen among ``start``'s (p, m) bool mask and its
    neighbours: one term added, one removed, one swapped for another, each refitted by least
    squares on ``theta`` (N, p), ``target`` (N, m) and scored on ``theta_val``,
    ``target_val``. The sparsest whose held-out FVU is within (1 + ``tolerance``) of the
    best compared (plus ``floor``) is kept (ties: the lower FVU): a term is added only where
    it explains what the others cannot, removed where it explains nothing, and a law never
    grows by more than one term a column."""
    arrays = [np.asarray(a.detach().cpu() if isinstance(a, torch.Tensor) else a, np.float64)
              for a in (theta, target, theta_val, target_val)]
    th, y, thv, yv = arrays
    start = np.asarray(start, bool)
    if th.ndim != 2 or y.ndim != 2 or thv.shape[1:] != th.shape[1:] or (
            yv.shape[1:] != y.shape[1:]) or len(th) != len(y) or len(thv) != len(yv) or (
            start.shape != (th.shape[1], y.shape[1])):
        raise UserError(f"select_law: theta (N, p) and target (N, m) for both sets and a start "
                        f"mask (p, m), got {th.shape}, {y.shape}, {thv.shape}, {yv.shape}, "
                        f"{start.shape}")
    if not (np.isfinite(th).all() and np.isfinite(y).all() and np.isfinite(thv).all()
            and np.isfinite(yv).all()):
        raise UserError("select_law: the library or target holds NaN or inf")
    p, m = start.shape
    coef = np.zeros((p, m))
    start_coef = np.zeros((p, m))
    compared = 0
    for j in range(m):
        now = tuple(np.flatnonzero(start[:, j]))
        others = [k for k in range(p) if k not in now]
        laws = {now}
        laws |= {tuple(sorted((*now, k))) for k in others}
        laws |= {tuple(i for i in now if i != r) for r in now}
        laws |= {tuple(sorted((*(i for i in now if i != r), k))) for r in now for k in others}
        scored = []
        for law in laws:
            c = _lstsq(th, y[:, j], law)
            scored.append((law, c, held_out_fvu(thv, yv[:, j:j + 1], c[:, None])))
        compared += len(scored)
        start_coef[:, j] = next(c for law, c, _ in scored if law == now)
        best = min(f for _, _, f in scored)
        ok = [s for s in scored if s[2] <= (1 + tolerance) * best + floor]
        _, coef[:, j], _ = min(ok, key=lambda s: (len(s[0]), s[2]))
    mask = coef != 0
    return LawChoice(coef, mask, held_out_fvu(thv, yv, coef),
                     held_out_fvu(thv, yv, start_coef), compared)
