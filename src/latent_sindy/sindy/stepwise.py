"""Backward stepwise sparse regression: :class:`StepwiseSR`, for libraries with dependent terms.

STLSQ judges a term by the size of its coefficient. When the data lie on a manifold, the
library's columns are linearly dependent there (on a circle x² + y² = r², every monomial
times x² + y² equals r² times the monomial), the least-squares solution spreads over every
dependent set, and thresholding by coefficient size keeps most of the library. This
sparsifier judges a term instead by what the fit loses without it. Per target column j,
from every allowed term, it repeatedly drops one term and refits, while some term can be
dropped at a cost

    Δ mean((target_j − theta_A ξ_A)²) <= tolerance · mean(target_j²),

the cost of term k on the active set A being ξ_k² / [(theta_Aᵀ theta_A / N)⁻¹]_kk (the
exact increase of the mean squared residual when k is left out and the rest refitted).
Among the terms that can be dropped it drops the most complex one (``complexity``, e.g. the
library's :attr:`~latent_sindy.sindy.SindyLibrary.degrees`), the cheapest of those first.
The complexity order matters on a manifold: a linear term and a cubic one can be equal
there, but only the linear one keeps a fitted map's rollouts off the manifold tame. Without
``complexity`` it is plain backward elimination by cost (stepwise sparse regression with the
model-residual criterion, Boninsegna et al. 2018).

Each drop inverts the active terms' Gram matrix again, so a target column with p terms costs
O(p⁴) (BENCHMARKS.md has times); STLSQ is much faster and the better choice where the terms
are independent.

    >>> opt = StepwiseSR(tolerance=1e-4, complexity=library.degrees).fit(theta, target)
    >>> opt.coef_.shape, opt.mask_.shape  # (p, m) float64, (p, m) bool
"""

from __future__ import annotations

import math

import torch

from latent_sindy.errors import UserError
from latent_sindy.sindy.optimizers import ArrayLike, normalised_problem

__all__ = ["StepwiseSR"]


class StepwiseSR:
    """Backward elimination of library terms by the fit they cost; see the module.

    Args:
        tolerance: largest share of a target's mean square that one dropped term may cost
            (the model's residual grows by at most this much per term dropped).
        complexity: optional (p,) numbers, one per library term: among the terms that may
            be dropped, the most complex goes first. None: all equal.
        alpha: ridge weight of the normalised Gram matrix while eliminating (keeps exactly
            dependent sets solvable; the final fit is ordinary least squares).
        unbias: refit the final active set by ordinary least squares (else the ridge fit).

    Attributes (after :meth:`fit`):
        coef_: (p, m) float64 coefficients in the original scale, 0 where inactive.
        mask_: (p, m) bool active terms.
        n_iter_: terms dropped, over all columns.
        column_scale_: (p,) RMS of each library column.
        target_scale_: (m,) RMS of each target column.
    """

    coef_: torch.Tensor
    mask_: torch.Tensor
    n_iter_: int
    column_scale_: torch.Tensor
    target_scale_: torch.Tensor

    def __init__(self, tolerance: float = 1e-4, complexity: ArrayLike | None = None,
                 alpha: float = 1e-10, unbias: bool = True) -> None:
        for name, value in (("tolerance", tolerance), ("alpha", alpha)):
            if not (isinstance(value, (int, float)) and not isinstance(value, bool)
                    and math.isfinite(value) and value >= 0):
                raise UserError(f"StepwiseSR {name}={value!r} is not valid: use a number >= 0")
        self.tolerance = float(tolerance)
        self.alpha = float(alpha)
        self.unbias = bool(unbias)
        self.complexity = None
        if complexity is not None:
            c = torch.as_tensor(complexity).to("cpu", torch.float64).flatten()
            if not c.isfinite().all():
                raise UserError("StepwiseSR complexity must be finite numbers, one per term")
            self.complexity = c

    def __repr__(self) -> str:
        return (f"StepwiseSR(tolerance={self.tolerance:g}, alpha={self.alpha:g}, "
                f"complexity={'given' if self.complexity is not None else None}, "
                f"unbias={self.unbias})")

    def fit(self, theta: ArrayLike, target: ArrayLike,
            mask: ArrayLike | None = None) -> StepwiseSR:
        """Fit ``target ≈ theta @ coef_``; returns ``self``.

        Args:
            theta: (N, p) library evaluated on the data.
            target: (N, m) what the terms should explain.
            mask: optional (p, m) bool: terms allowed (default all); others stay 0.
        """
        prob = normalised_problem(theta, target, mask, "StepwiseSR.fit")
        p, m = prob.rhs.shape
        complexity = torch.zeros(p, dtype=torch.float64) if self.complexity is None \
            else self.complexity
        if complexity.shape != (p,):
            raise ValueError(f"StepwiseSR.fit: complexity has {complexity.numel()} entries "
                             f"but theta {p} columns: give one per library term")
        gram, rhs, active = prob.gram, prob.rhs, prob.active.clone()
        self.n_iter_ = 0
        for j in range(m):
            idx = active[:, j].nonzero().flatten()
            budget = self.tolerance * float(prob.target_scale[j]) ** 2
            while len(idx):
                inv = torch.linalg.inv(gram[idx][:, idx]
                                       + self.alpha * torch.eye(len(idx), dtype=gram.dtype))
                xi = inv @ rhs[idx, j]
                cost = xi.square() / inv.diagonal()  # mean-square residual gained per drop
                droppable = cost <= budget
                if not droppable.any():
                    break
                level = complexity[idx]
                top = droppable & (level == level[droppable].max())
                k = int(torch.where(top, cost, torch.full_like(cost, math.inf)).argmin())
                active[idx[k], j] = False
                idx = torch.cat([idx[:k], idx[k + 1:]])
                self.n_iter_ += 1
        self.coef_ = prob.refit(active, self.unbias, self.alpha)
        self.mask_ = active
        self.column_scale_ = prob.column_scale
        self.target_scale_ = prob.target_scale
        return self
