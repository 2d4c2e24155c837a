"""Ensemble sparse regression (bagging) for noisy data: :class:`EnsembleSTLSQ`.

In the manner of ensemble SINDy (E-SINDy, Fasel et al. 2022): fit the base sparsifier
(:class:`~latent_sindy.sindy.optimizers.STLSQ`) ``n_models`` times, each on a bootstrap
resample of the rows (bagging) and optionally without ``library_drop`` random library terms
(library bagging), all drawn from one generator seeded by ``seed``. Over the models that were
offered a term, its *inclusion probability* is the share that kept it active, its centre the
median (or mean) of its coefficients, its spread their standard deviation. A term is kept when

    inclusion > ``inclusion``  and  |centre| >= ``z_min`` · spread,

the second rule dropping terms whose sign and size the resamples do not agree on (on noisy,
nearly collinear libraries such terms are kept by most resamples, so inclusion alone does not
remove them; ``z_min=0`` gives the inclusion rule alone). The kept terms are then refitted on
all rows by the base sparsifier restricted to them (``refit``), or take the centre.

    >>> from latent_sindy.sindy.systems import lorenz_control
    >>> s = lorenz_control(seed=0)  # 5000 transitions, 35 terms, 8 of them true
    >>> theta, target = s.library(s.Z, s.U), s.Znext - s.Z  # (N, p), (N, m)
    >>> opt = EnsembleSTLSQ(STLSQ(), n_models=10, seed=0).fit(theta, target)
    >>> opt.coef_.shape, int(opt.mask_.sum()), opt.inclusion_.shape
    (torch.Size([35, 3]), 8, torch.Size([35, 3]))

On noisy trajectories, fit their windowed form (:func:`latent_sindy.sindy.fit_trajectory_data`)
with it: ``BENCHMARKS.md`` (``benchmarks/fit_state.py``) has the measurements.
"""

from __future__ import annotations

import copy
import math

import torch

from latent_sindy.errors import UserError
from latent_sindy.sindy.optimizers import STLSQ, ArrayLike, as_matrix

__all__ = ["AGGREGATES", "EnsembleSTLSQ"]

AGGREGATES = ("median", "mean")


def _check_number(name: str, value: object, low: float, high: float = math.inf) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    if not (ok and math.isfinite(value) and low <= value <= high):  # type: ignore[arg-type]
        bounds = f"in [{low:g}, {high:g}]" if math.isfinite(high) else f">= {low:g}"
        raise UserError(f"EnsembleSTLSQ {name}={value!r} is not valid: use a number {bounds}")
    return float(value)  # type: ignore[arg-type]


def _check_int(name: str, value: object, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise UserError(f"EnsembleSTLSQ {name}={value!r} is not valid: use an integer >= {low}")
    return value


class EnsembleSTLSQ:
    """Bagged STLSQ with selection by inclusion probability and agreement; see the module.

    Args:
        base: the sparsifier fitted on every resample and in the refit (default ``STLSQ()``).
        n_models: resamples fitted.
        bagging: resample the N rows with replacement (N draws) for every model; without it
            every model sees all rows (then only ``library_drop`` varies them).
        library_drop: library terms left out of each model, drawn at random (0: none).
        aggregate: ``"median"`` or ``"mean"`` of a term's coefficients over the models.
        inclusion: keep a term only if more than this share of the models kept it.
        z_min: keep a term only if |centre| >= z_min · (standard deviation over the models).
        refit: refit the kept terms on all rows with ``base`` (else ``coef_`` is the centre).
        seed: seeds the one generator behind every random draw.

    Attributes (after :meth:`fit`):
        coef_: (p, m) float64 coefficients, 0 where inactive.
        mask_: (p, m) bool active terms.
        inclusion_: (p, m) share of the models offered a term that kept it active.
        centre_: (p, m) median or mean coefficient over the models offered the term.
        spread_: (p, m) standard deviation of those coefficients.
        coef_models_: (n_models, p, m) every model's coefficients (0 where not offered).
        offered_: (n_models, p) bool, the terms each model was offered.
    """

    coef_: torch.Tensor
    mask_: torch.Tensor
    inclusion_: torch.Tensor
    centre_: torch.Tensor
    spread_: torch.Tensor
    coef_models_: torch.Tensor
    offered_: torch.Tensor

    def __init__(
        self,
        base: STLSQ | None = None,
        n_models: int = 20,
        bagging: bool = True,
        library_drop: int = 0,
        aggregate: str = "median",
        inclusion: float = 0.5,
        z_min: float = 3.0,
        refit: bool = True,
        seed: int = 0,
    ) -> None:
        if base is not None and not isinstance(base, STLSQ):
            raise UserError(f"EnsembleSTLSQ base={base!r} is not valid: use an STLSQ(...)")
        if aggregate not in AGGREGATES:
            raise UserError(
                f"EnsembleSTLSQ aggregate={aggregate!r} is not valid: use one of {AGGREGATES}"
            )
        self.base = STLSQ() if base is None else base
        self.n_models = _check_int("n_models", n_models, 1)
        self.bagging = bool(bagging)
        self.library_drop = _check_int("library_drop", library_drop, 0)
        self.aggregate = aggregate
        self.inclusion = _check_number("inclusion", inclusion, 0.0, 1.0)
        self.z_min = _check_number("z_min", z_min, 0.0)
        self.refit = bool(refit)
        self.seed = _check_int("seed", seed, 0)

    def __repr__(self) -> str:
        return (
            f"EnsembleSTLSQ({self.base!r}, n_models={self.n_models}, bagging={self.bagging}, "
            f"library_drop={self.library_drop}, aggregate={self.aggregate!r}, "
            f"inclusion={self.inclusion:g}, z_min={self.z_min:g}, refit={self.refit}, "
            f"seed={self.seed})"
        )

    def fit(
        self, theta: ArrayLike, target: ArrayLike, mask: ArrayLike | None = None
    ) -> EnsembleSTLSQ:
        """Fit ``target ≈ theta @ coef_`` by the ensemble; returns ``self``.

        Args:
            theta: (N, p) library evaluated on the data.
            target: (N, m) what the terms should explain.
            mask: optional (p, m) bool: terms allowed (default all); never turned on.
        """
        th = as_matrix(theta, "theta", "EnsembleSTLSQ.fit")  # (N, p)
        y = as_matrix(target, "target", "EnsembleSTLSQ.fit")  # (N, m)
        n, p = th.shape
        m = y.shape[1]
        if y.shape[0] != n:
            raise ValueError(f"EnsembleSTLSQ.fit: theta has {n} rows but target {y.shape[0]}")
        if self.library_drop >= p:
            raise UserError(
                f"EnsembleSTLSQ library_drop={self.library_drop} leaves no term of the {p}: "
                f"use a value below {p}"
            )
        allowed = torch.ones(p, m, dtype=torch.bool)
        if mask is not None:
            allowed = torch.as_tensor(mask).to("cpu", torch.bool)
            if allowed.shape != (p, m):
                raise ValueError(
                    f"EnsembleSTLSQ.fit: mask must be ({p}, {m}), got {tuple(allowed.shape)}"
                )
        gen = torch.Generator().manual_seed(self.seed)
        coefs = torch.zeros(self.n_models, p, m, dtype=torch.float64)
        offered = torch.ones(self.n_models, p, dtype=torch.bool)
        for k in range(self.n_models):
            rows = torch.randint(n, (n,), generator=gen) if self.bagging else torch.arange(n)
            if self.library_drop:
                offered[k, torch.randperm(p, generator=gen)[: self.library_drop]] = False
            model = copy.copy(self.base).fit(th[rows], y[rows], allowed & offered[k, :, None])
            coefs[k] = model.coef_

        seen = offered[:, :, None].expand(-1, -1, m)  # (K, p, m)
        count = seen.sum(0).clamp(min=1)  # (p, m)
        self.inclusion_ = ((coefs != 0) & seen).sum(0) / count
        masked = torch.where(seen, coefs, torch.full_like(coefs, math.nan))
        mean = masked.nansum(0) / count
        self.centre_ = masked.nanmedian(0).values if self.aggregate == "median" else mean
        self.centre_ = torch.nan_to_num(self.centre_, nan=0.0)
        dev = torch.where(seen, coefs - mean, torch.zeros_like(coefs))
        self.spread_ = (dev.square().sum(0) / count).sqrt()
        keep = (
            allowed
            & (self.inclusion_ > self.inclusion)
            & (self.centre_.abs() >= self.z_min * self.spread_)
        )
        if self.refit:
            final = copy.copy(self.base).fit(th, y, keep)
            self.coef_, self.mask_ = final.coef_, final.mask_
        else:
            self.coef_ = torch.where(keep, self.centre_, torch.zeros_like(self.centre_))
            self.mask_ = keep
        self.coef_models_ = coefs
        self.offered_ = offered
        return self
