"""Sparse regression for SINDy: sequentially thresholded least squares (STLSQ).

Solves ``target ≈ theta @ coef`` for a sparse ``coef``, one column of ``target`` at a time.
Scales are taken out first, so the defaults need no tuning per system: every library column
is divided by its root mean square (RMS) and every coefficient is judged by the RMS of its
term's contribution, relative to the RMS of the target column it explains. A term stays
active in column j while

    |coef[i, j]| · rms(theta[:, i]) >= min_share · rms(target[:, j]),

i.e. while it contributes at least the share ``min_share`` of that target's size (a relative
cut, unlike pysindy's STLSQ, whose ``threshold`` is an absolute coefficient magnitude). Each
round solves a ridge regression (``alpha`` relative to the unit diagonal of the normalised
Gram matrix) on the active terms and drops those below the rule, until nothing changes; then
an ordinary least-squares refit on the final active set removes the ridge's shrinkage
(``unbias``).
The mask only ever turns terms off, so a given starting ``mask`` (e.g. a model's) is kept.
The checked, normalised problem and the per-column solves (:func:`normalised_problem`,
:func:`ridge_solve`, :func:`lstsq_solve`) are shared with the other sparsifiers.

    >>> opt = STLSQ(min_share=1e-2).fit(theta, target)  # theta (N, p), target (N, m)
    >>> opt.coef_.shape, opt.mask_.shape  # (p, m) float64, (p, m) bool
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from latent_sindy.errors import UserError

__all__ = ["STLSQ", "NormalisedProblem", "lstsq_solve", "normalised_problem", "ridge_solve"]

ArrayLike = torch.Tensor | np.ndarray


def as_matrix(x: ArrayLike, name: str, where: str = "STLSQ.fit") -> torch.Tensor:
    """``x`` as a 2-D float64 CPU tensor; ``where`` names the caller in the error."""
    t = torch.as_tensor(x).detach().to("cpu", torch.float64)
    if t.ndim != 2:
        raise ValueError(
            f"{where} expects {name} as a 2-D (N, .) array, got shape {tuple(t.shape)}"
        )
    return t


class STLSQ:
    """Sequentially thresholded least squares on RMS-normalised columns.

    Args:
        min_share: smallest relative contribution of an active term (see the module
            docstring): the default (None: 0.01) keeps the terms that explain at least 1 % of
            a target's RMS. 0 keeps every term (then it is a ridge / least-squares fit).
            A share of the target, not pysindy's absolute coefficient cut ``threshold``.
        alpha: ridge weight during thresholding, relative to the unit diagonal of the
            normalised Gram matrix ``theta_nᵀ theta_n / N``. Keep it below that matrix's
            smallest eigenvalue: a larger ridge moves weight between nearly collinear columns
            (high-order monomials) and misleads the thresholding (on Lorenz with an order-4
            library 1e-7 already does; 1e-10 does not).
        max_iter: most thresholding rounds (it stops earlier when the mask settles).
        unbias: refit the final active set by ordinary least squares (no ridge).

    Attributes (after :meth:`fit`):
        coef_: (p, m) float64 coefficients in the original scale, 0 where inactive.
        mask_: (p, m) bool active terms.
        n_iter_: thresholding rounds run.
        column_scale_: (p,) RMS of each library column (inactive where 0).
        target_scale_: (m,) RMS of each target column.
    """

    coef_: torch.Tensor
    mask_: torch.Tensor
    n_iter_: int
    column_scale_: torch.Tensor
    target_scale_: torch.Tensor

    def __init__(
        self,
        min_share: float | None = None,
        alpha: float = 1e-10,
        max_iter: int = 20,
        unbias: bool = True,
    ) -> None:
        min_share = 1e-2 if min_share is None else min_share
        for name, value in (("min_share", min_share), ("alpha", alpha)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise UserError(f"STLSQ {name}={value!r} is not valid: use a number >= 0")
        if isinstance(max_iter, bool) or not isinstance(max_iter, int) or max_iter < 1:
            raise UserError(f"STLSQ max_iter={max_iter!r} is not valid: use an integer >= 1")
        self.min_share = float(min_share)
        self.alpha = float(alpha)
        self.max_iter = max_iter
        self.unbias = bool(unbias)

    def __repr__(self) -> str:
        return (
            f"STLSQ(min_share={self.min_share:g}, alpha={self.alpha:g}, "
            f"max_iter={self.max_iter}, unbias={self.unbias})"
        )

    def fit(self, theta: ArrayLike, target: ArrayLike, mask: ArrayLike | None = None) -> STLSQ:
        """Fit ``target ≈ theta @ coef_``; returns ``self``.

        Args:
            theta: (N, p) library evaluated on the data.
            target: (N, m) what the terms should explain (for SINDy steps: z_{t+1} − z_t).
            mask: optional (p, m) bool: terms allowed at the start (default all).
        """
        prob = normalised_problem(theta, target, mask, "STLSQ.fit")
        gram, rhs, active = prob.gram, prob.rhs, prob.active
        bound = self.min_share * prob.target_scale  # (m,) in the coefficients' normalised scale

        n_iter = 0
        while n_iter < self.max_iter:
            n_iter += 1
            xi = ridge_solve(gram, rhs, active, self.alpha)
            keep = active & (xi.abs() >= bound)
            if torch.equal(keep, active):
                break
            active = keep
        self.coef_ = prob.refit(active, self.unbias, self.alpha)  # (p, m)
        self.mask_ = active
        self.n_iter_ = n_iter
        self.column_scale_ = prob.column_scale
        self.target_scale_ = prob.target_scale
        return self

    @torch.no_grad()
    def keep_mask(
        self,
        coef: ArrayLike,
        theta: ArrayLike,
        target: ArrayLike,
        mask: ArrayLike | None = None,
    ) -> torch.Tensor:
        """The thresholding rule alone, without refitting: which of ``coef`` stay active.

        For a trainer that fits Ψ by gradient steps and prunes now and then (the image
        trainer): ``coef`` (p, m) its current coefficients, ``theta`` (N, p) and ``target``
        (N, m) a batch of library values and targets (for latent SINDy: Θ(z_t, u_t) and
        z_{t+1} − z_t of encoded frames) that set the scales. Returns the (p, m) bool mask
        ``mask & (|coef| · rms(theta) >= min_share · rms(target))``, on ``coef``'s device.
        """
        c = torch.as_tensor(coef).detach()
        th = as_matrix(theta, "theta")
        y = as_matrix(target, "target")
        if c.shape != (th.shape[1], y.shape[1]):
            raise ValueError(
                f"keep_mask: coef must be (p, m) = ({th.shape[1]}, {y.shape[1]}) to match theta "
                f"and target, got {tuple(c.shape)}"
            )
        share = c.to("cpu", torch.float64).abs() * th.square().mean(dim=0).sqrt()[:, None]
        keep = share >= self.min_share * y.square().mean(dim=0).sqrt()[None, :]
        if mask is not None:
            keep &= torch.as_tensor(mask).to("cpu", torch.bool)
        return keep.to(c.device)


@dataclass(frozen=True)
class NormalisedProblem:
    """A checked regression ``target ≈ theta @ coef`` with RMS-normalised library columns,
    as the sparsifiers solve it (see the module)."""

    theta_n: torch.Tensor
    """(N, p) float64 library columns divided by their RMS (unused columns as they are)."""
    target: torch.Tensor
    """(N, m) float64 targets."""
    column_scale: torch.Tensor
    """(p,) each library column's RMS (0: a column of zeros)."""
    target_scale: torch.Tensor
    """(m,) each target column's RMS."""
    gram: torch.Tensor
    """(p, p) theta_nᵀ theta_n / N."""
    rhs: torch.Tensor
    """(p, m) theta_nᵀ target / N."""
    active: torch.Tensor
    """(p, m) bool: the terms a fit may use (allowed by the mask, non-zero column and
    target)."""

    def refit(self, active: torch.Tensor, unbias: bool, alpha: float) -> torch.Tensor:
        """The (p, m) coefficients in the original scale on ``active``: least squares
        (``unbias``) or the ridge fit at ``alpha``."""
        xi = (lstsq_solve(self.theta_n, self.target, active) if unbias
              else ridge_solve(self.gram, self.rhs, active, alpha))
        safe = torch.where(self.column_scale > 0, self.column_scale,
                           torch.ones_like(self.column_scale))
        return xi / safe[:, None]


def normalised_problem(theta: ArrayLike, target: ArrayLike, mask: ArrayLike | None,
                       where: str) -> NormalisedProblem:
    """Check ``theta`` (N, p), ``target`` (N, m) and ``mask`` (p, m) for the fit named
    ``where`` (ValueError naming it) and normalise the columns."""
    th = as_matrix(theta, "theta", where)  # (N, p)
    y = as_matrix(target, "target", where)  # (N, m)
    n, p = th.shape
    m = y.shape[1]
    if y.shape[0] != n:
        raise ValueError(f"{where}: theta has {n} rows but target {y.shape[0]}")
    if not (th.isfinite().all() and y.isfinite().all()):
        raise ValueError(f"{where}: theta and target must be finite (found NaN or inf)")
    allowed = torch.ones(p, m, dtype=torch.bool)
    if mask is not None:
        allowed = torch.as_tensor(mask).to("cpu", torch.bool)
        if allowed.shape != (p, m):
            raise ValueError(f"{where}: mask must be ({p}, {m}), got {tuple(allowed.shape)}")
    scale = th.square().mean(dim=0).sqrt()  # (p,)
    y_scale = y.square().mean(dim=0).sqrt()  # (m,)
    usable = scale > 0
    th_n = th / torch.where(usable, scale, torch.ones_like(scale))  # unit-RMS columns
    return NormalisedProblem(
        th_n, y, scale, y_scale, th_n.T @ th_n / n, th_n.T @ y / n,
        allowed & usable[:, None] & (y_scale > 0)[None, :])


def ridge_solve(gram: torch.Tensor, rhs: torch.Tensor, active: torch.Tensor,
                alpha: float) -> torch.Tensor:
    """Per column j: (G_aa + αI) ξ_a = rhs_aj on the active set a; 0 elsewhere: (p, m)."""
    xi = torch.zeros_like(rhs)
    for j, idx in _column_sets(active):
        g = gram[idx][:, idx] + alpha * torch.eye(len(idx), dtype=gram.dtype)
        xi[idx[:, None], j] = torch.linalg.lstsq(g, rhs[idx][:, j]).solution
    return xi


def lstsq_solve(th_n: torch.Tensor, y: torch.Tensor, active: torch.Tensor) -> torch.Tensor:
    """Per column j: least squares of y[:, j] on th_n's active columns: (p, m)."""
    xi = torch.zeros(th_n.shape[1], y.shape[1], dtype=th_n.dtype)
    for j, idx in _column_sets(active):
        xi[idx[:, None], j] = torch.linalg.lstsq(th_n[:, idx], y[:, j], driver="gelsd").solution
    return xi


def _column_sets(active: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """Columns with the same active set, grouped: [(column indices (c,), term indices (a,))]."""
    groups: dict[tuple[int, ...], list[int]] = {}
    for j in range(active.shape[1]):
        idx = tuple(active[:, j].nonzero().flatten().tolist())
        if idx:
            groups.setdefault(idx, []).append(j)
    return [(torch.tensor(cols), torch.tensor(idx)) for idx, cols in groups.items()]
