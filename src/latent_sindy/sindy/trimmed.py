"""Trimmed sparse regression: SINDy fitted to the transitions a smooth library can explain.

Real systems have events a library of smooth terms cannot write: a cart at the end of its
rail, a contact, a joint limit. Fitted with everything else, those transitions pull every
coefficient. :class:`Trimmed` wraps any sparsifier (``fit(theta, target, mask)`` with
``coef_`` and ``mask_``; :class:`~latent_sindy.sindy.STLSQ` by default) and fits it again
after leaving out the ``share`` of the rows it explains worst, and again, until the rows
left out, or the coefficients, no longer change (least trimmed squares by concentration
steps). It is a sparsifier itself, so it goes wherever one does:

    >>> from latent_sindy.sindy import STLSQ, Trimmed, fit_state_data
    >>> opt = fit_state_data(library, Z, U, Znext, Trimmed(STLSQ(), share=0.3))
    >>> opt.coef_, opt.kept_          # (p, nz) coefficients, (N,) rows the last fit used

A row's misfit is its squared residual summed over the targets, each target's residual in
units of that target's RMS, so no target outweighs another by its scale.
"""

from __future__ import annotations

import math
from typing import Any

import torch

from latent_sindy.errors import UserError
from latent_sindy.sindy.optimizers import STLSQ, ArrayLike, as_matrix

__all__ = ["Trimmed"]


class Trimmed:
    """Least trimmed squares around a sparsifier.

    Args:
        inner: the sparsifier fitted each round (default ``STLSQ()``); fitted in place.
        share: the share of the rows left out of the final fit, those of the largest misfit
            under the previous round's coefficients (0 <= share < 1; 0 is ``inner`` alone).
        rounds: most fits after the first one on all rows (the rows left out are chosen anew
            each round from the last coefficients; it stops when they or the coefficients repeat).

    Attributes (after :meth:`fit`): ``coef_`` (p, m) and ``mask_`` (p, m) of the last fit,
    ``kept_`` (N,) bool, the rows it used, ``n_rounds_`` the trimmed fits run, and ``inner``
    itself (its own attributes).
    """

    coef_: torch.Tensor
    mask_: torch.Tensor
    kept_: torch.Tensor
    n_rounds_: int

    def __init__(self, inner: Any = None, share: float = 0.3, rounds: int = 20) -> None:
        if isinstance(share, bool) or not isinstance(share, int | float) or not (
                0 <= share < 1):
            raise UserError(f"Trimmed share {share!r}: use a share of the rows in [0, 1)")
        if isinstance(rounds, bool) or not isinstance(rounds, int) or rounds < 1:
            raise UserError(f"Trimmed rounds {rounds!r}: use an integer >= 1")
        self.inner = STLSQ() if inner is None else inner
        if not callable(getattr(self.inner, "fit", None)):
            raise UserError(f"Trimmed wraps a sparsifier with fit(theta, target, mask); got "
                            f"{type(self.inner).__name__}")
        self.share, self.rounds = float(share), rounds

    def fit(self, theta: ArrayLike, target: ArrayLike, mask: ArrayLike | None = None
            ) -> Trimmed:
        """Fit ``target ≈ theta @ coef_`` on all rows, then on the rows of the smallest
        misfit until they repeat (at most ``rounds`` times); returns ``self``."""
        th = as_matrix(theta, "theta", "Trimmed.fit")
        y = as_matrix(target, "target", "Trimmed.fit")
        if th.shape[0] != y.shape[0]:
            raise UserError(f"Trimmed.fit: theta has {th.shape[0]} rows, target "
                            f"{y.shape[0]}: give one library row per target row")
        n = th.shape[0]
        keep_n = n - math.floor(self.share * n)
        kept = torch.ones(n, dtype=torch.bool)
        self.inner.fit(th, y, mask)
        self.n_rounds_ = 0
        if self.share > 0:
            scale = y.pow(2).mean(0).sqrt().clamp_min(torch.finfo(y.dtype).tiny)  # (m,)
            while self.n_rounds_ < self.rounds:
                coef = torch.as_tensor(self.inner.coef_, dtype=th.dtype)
                misfit = ((y - th @ coef) / scale).pow(2).sum(1)  # (N,)
                now = torch.zeros(n, dtype=torch.bool)
                now[torch.argsort(misfit, stable=True)[:keep_n]] = True
                if self.n_rounds_ and torch.equal(now, kept):
                    break
                kept = now
                self.inner.fit(th[kept], y[kept], mask)
                self.n_rounds_ += 1
                if torch.allclose(torch.as_tensor(self.inner.coef_, dtype=th.dtype), coef,
                                  rtol=1e-9, atol=1e-12):
                    break  # (rows of equal misfit may swap places without changing the fit)
        self.coef_, self.mask_, self.kept_ = self.inner.coef_, self.inner.mask_, kept
        return self
