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

A continuous-time law is chosen the same way on held-out derivatives: :func:`select_law`
fits STLSQ (a term kept while it carries at least ``min_share`` of its target's size) at
every share of a path from fine to coarse, scores each law by the fraction of the held-out
target's variance it leaves unexplained (FVU), and keeps the sparsest law within
``tolerance`` of the best: a term stays when it explains what the others cannot, wherever
its coefficient sits against a fixed cut.

    >>> law = select_law(theta_train, zdd_train, theta_val, zdd_val)
    >>> law.coef.shape, law.fvu, law.share   # (p, m), held-out FVU, the cut it came from
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from latent_sindy.errors import UserError
from latent_sindy.sindy.fit import Sparsifier, fit_state_data
from latent_sindy.sindy.optimizers import STLSQ
from latent_sindy.sindy.stepwise import StepwiseSR
from latent_sindy.sindy.torch_library import SindyLibrary

__all__ = ["SHARES", "TOLERANCES", "LawChoice", "PathPoint", "Selection", "held_out_fvu",
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


#: The path of STLSQ cuts (each term's share of its target's size), fine to coarse.
SHARES = tuple(float(s) for s in np.geomspace(0.005, 0.5, 21))


@dataclass
class LawChoice:
    """The law kept: coefficients (p, m) with pruned entries 0, its mask, the STLSQ share it
    came from, its held-out FVU, and every candidate on the path (share, active terms, FVU)."""

    coef: np.ndarray
    mask: np.ndarray
    share: float
    fvu: float
    path: list[dict[str, float]] = field(default_factory=list)


def held_out_fvu(theta: np.ndarray, target: np.ndarray, coef: np.ndarray) -> float:
    """Σ (target − θ coef)² / Σ (target − its mean)², over every sample and column."""
    resid = target - theta @ coef
    spread = ((target - target.mean(0)) ** 2).sum()
    return float((resid ** 2).sum() / max(spread, 1e-300))


def select_law(theta: np.ndarray | torch.Tensor, target: np.ndarray | torch.Tensor,
               theta_val: np.ndarray | torch.Tensor, target_val: np.ndarray | torch.Tensor,
               shares: tuple[float, ...] = SHARES, tolerance: float = 0.25,
               floor: float = 1e-6) -> LawChoice:
    """The sparsest law along ``shares`` whose held-out FVU is at most (1 + ``tolerance``)
    times the path's best plus ``floor`` (ties: the lower FVU). ``theta`` (N, p), ``target``
    (N, m) fit; ``theta_val``, ``target_val`` score. A law of no term is a candidate too
    (FVU 1 on centred targets)."""
    arrays = [np.asarray(a.detach().cpu() if isinstance(a, torch.Tensor) else a, np.float64)
              for a in (theta, target, theta_val, target_val)]
    th, y, thv, yv = arrays
    if th.ndim != 2 or y.ndim != 2 or thv.shape[1:] != th.shape[1:] or (
            yv.shape[1:] != y.shape[1:]) or len(th) != len(y) or len(thv) != len(yv):
        raise UserError(f"select_law: theta (N, p) and target (N, m) for both sets, got "
                        f"{th.shape}, {y.shape}, {thv.shape}, {yv.shape}")
    if not (np.isfinite(th).all() and np.isfinite(y).all() and np.isfinite(thv).all()
            and np.isfinite(yv).all()):
        raise UserError("select_law: the library or target holds NaN or inf")
    candidates = []
    seen = set()
    for share in shares:
        opt = STLSQ(min_share=share).fit(th, y)
        coef = np.asarray(opt.coef_, np.float64) * np.asarray(opt.mask_)
        key = np.asarray(opt.mask_).tobytes()
        if key in seen:
            continue
        seen.add(key)
        candidates.append((share, coef, np.asarray(opt.mask_, bool)))
    zero = np.zeros((th.shape[1], y.shape[1]))
    candidates.append((float("inf"), zero, zero.astype(bool)))
    scored = [(share, coef, mask, held_out_fvu(thv, yv, coef)) for share, coef, mask in
              candidates]
    best = min(s[3] for s in scored)
    ok = [s for s in scored if s[3] <= (1 + tolerance) * best + floor]
    share, coef, mask, fvu = min(ok, key=lambda s: (int(s[2].sum()), s[3]))
    path = [{"share": s, "active": int(m.sum()), "fvu": f} for s, _, m, f in scored]
    return LawChoice(coef, mask, share, fvu, path)
