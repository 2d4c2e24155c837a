"""Fit latent dynamics to state transitions (z_t, u_t, z_{t+1}).

Two fits:

* :func:`fit_state_data`: SINDy on states as sparse regression. The residual step
  ``z_{t+1} − z_t = Θ(z_t, u_t) Ψ`` is linear in Ψ, so a sparsifier (default :class:`STLSQ`)
  solves it in closed form on the library evaluated at the data. It returns the fitted
  sparsifier (``coef_`` (p, nz), ``mask_`` (p, nz)); ``SindyDynamics.fit_state_data`` puts
  them into a model.
* :func:`fit_gradient`: minibatch AdamW on the one-step loss for models that are not linear
  in their parameters (the MLP baseline), with optional L1 and magnitude pruning for models
  that have ``psi`` / ``mask`` (pruning also clears AdamW's moments of pruned entries, as the
  image trainer does).

This package does not import :mod:`latent_sindy.models` (which imports it); models are
taken by their methods (``step``, ``l1_penalty``, ``threshold``).

    >>> lib = CandidateLibrary(n_state=3, n_control=1, order=2)
    >>> opt = fit_state_data(lib, Z, U, Znext)  # Z (N, 3), U (N, 1), Znext (N, 3)
    >>> opt.coef_.shape, int(opt.mask_.sum())  # (p, nz), active coefficients
    >>> result = fit_gradient(mlp, Z, U, Znext, epochs=200, lr=3e-3, batch_size=500)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import torch
import torch.nn.functional as F
from torch import nn

from latent_sindy.sindy.library import SindyLibrary
from latent_sindy.sindy.optimizers import STLSQ

__all__ = ["FitResult", "fit_gradient", "fit_state_data", "library_regression_data"]


def _check_data(nz: int, nu: int, Z: torch.Tensor, U: torch.Tensor, Znext: torch.Tensor) -> None:
    n = Z.shape[0]
    if Z.shape != (n, nz) or Znext.shape != Z.shape or U.shape != (n, nu):
        raise ValueError(
            f"expected Z and Znext of shape (N, nz={nz}) and U of shape (N, nu={nu}), "
            f"got Z {tuple(Z.shape)}, U {tuple(U.shape)}, Znext {tuple(Znext.shape)}"
        )


@torch.no_grad()
def library_regression_data(
    library: SindyLibrary, Z: torch.Tensor, U: torch.Tensor, Znext: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The linear problem of a residual SINDy step: Θ(Z, U) (N, p) and Znext − Z (N, nz),
    both float64 on the CPU."""
    _check_data(library.n_state, library.n_control, Z, U, Znext)
    dev = library.table.device
    Z64 = Z.detach().to(dev, torch.float64)
    theta = library(Z64, U.detach().to(dev, torch.float64))  # (N, p)
    return theta.cpu(), (Znext.detach().to(dev, torch.float64) - Z64).cpu()


def fit_state_data(
    library: SindyLibrary,
    Z: torch.Tensor,
    U: torch.Tensor,
    Znext: torch.Tensor,
    optimizer: STLSQ | None = None,
    mask: torch.Tensor | None = None,
) -> STLSQ:
    """Sparse regression of ``Znext − Z`` on ``library(Z, U)``; returns the fitted optimizer.

    Args:
        library: the candidate library (its sizes must match the data).
        Z, U, Znext: (N, nz), (N, nu), (N, nz) transitions.
        optimizer: the sparsifier (default ``STLSQ()``); it is fitted in place and returned.
        mask: optional (p, nz) bool, the terms allowed (default all).

    Returns:
        ``optimizer`` with ``coef_`` (p, nz) float64 and ``mask_`` (p, nz) bool.
    """
    theta, target = library_regression_data(library, Z, U, Znext)
    return (STLSQ() if optimizer is None else optimizer).fit(theta, target, mask)


# ---------------------------------------------------------------- gradient-based fit


class _Steppable(Protocol):
    """What :func:`fit_gradient` needs of a model (every LatentDynamics has it)."""

    nz: int
    nu: int

    def step(self, z: torch.Tensor, u: torch.Tensor) -> torch.Tensor: ...
    def parameters(self) -> object: ...
    def train(self, mode: bool = True) -> object: ...


@dataclass
class FitResult:
    """What :func:`fit_gradient` did."""

    losses: list[float] = field(default_factory=list)
    """One-step MSE per epoch (mean over the epoch's batches), both phases."""
    pruned: list[tuple[int, int]] = field(default_factory=list)
    """(epoch, number newly pruned) at each thresholding, epochs counted from 1."""
    n_active: int | None = None
    """Active coefficients at the end (None for models without a mask)."""


@torch.no_grad()
def _prune(model: nn.Module, opt: torch.optim.Optimizer, tau: float) -> int:
    """Threshold ``|Ψ| < tau``; clear the optimizer's moments of pruned entries so Ψ stays 0."""
    pruned = int(model.threshold(tau))  # type: ignore[operator]
    state = opt.state.get(model.psi, {})  # type: ignore[arg-type]
    for key in ("exp_avg", "exp_avg_sq"):
        if key in state:
            state[key].masked_fill_(~model.mask, 0.0)  # type: ignore[operator]
    return pruned


def _train(
    model: _Steppable,
    Z: torch.Tensor,
    U: torch.Tensor,
    Znext: torch.Tensor,
    *,
    epochs: int,
    lr: float,
    l1: float,
    threshold: float,
    every: int,
    batch_size: int | None,
    weight_decay: float,
    generator: torch.Generator,
    result: FitResult,
) -> None:
    """One phase: a fresh AdamW, ``epochs`` passes over the data."""
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=weight_decay)  # type: ignore[arg-type]
    n = Z.shape[0]
    bs = n if batch_size is None else batch_size
    start = len(result.losses)
    for epoch in range(1, epochs + 1):
        order = torch.randperm(n, generator=generator) if bs < n else None
        total, batches = 0.0, 0
        for b in range(0, n, bs):
            idx = slice(b, b + bs) if order is None else order[b : b + bs]
            mse = F.mse_loss(model.step(Z[idx], U[idx]), Znext[idx])
            loss = mse + l1 * model.l1_penalty() if l1 else mse  # type: ignore[attr-defined]
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            total += float(mse.detach())
            batches += 1
        result.losses.append(total / batches)
        if threshold and every and epoch % every == 0:
            result.pruned.append((start + epoch, _prune(model, opt, threshold)))  # type: ignore[arg-type]


def fit_gradient(
    model: _Steppable,
    Z: torch.Tensor,
    U: torch.Tensor,
    Znext: torch.Tensor,
    *,
    epochs: int = 2000,
    lr: float = 1e-2,
    l1: float = 0.0,
    threshold: float = 0.0,
    every: int = 0,
    debias_epochs: int = 0,
    debias_lr: float | None = None,
    batch_size: int | None = None,
    weight_decay: float = 0.0,
    seed: int = 0,
) -> FitResult:
    """Fit ``model`` in place to ``Znext ≈ model.step(Z, U)`` by gradient descent.

    For models not linear in their parameters (the MLP baseline). A SINDy model on states is
    better fitted by :func:`fit_state_data`; ``l1``/``threshold`` (the image trainer's recipe
    without images) need a model with ``l1_penalty``, ``threshold``, ``psi`` and ``mask``.

    Args:
        model: any latent dynamics model.
        Z, U, Znext: (N, nz), (N, nu), (N, nz) transitions.
        epochs: passes over the data in the sparsifying phase.
        lr: AdamW learning rate.
        l1: weight of ‖M ⊙ Ψ‖₁ added to the mean squared one-step error.
        threshold: prune active coefficients with |Ψ| below it ...
        every: ... every this many epochs of the sparsifying phase (0: never).
        debias_epochs: then this many epochs with a fresh optimizer, ``l1 = 0`` and no
            thresholding (the mask stays as it is). 0 skips the phase.
        debias_lr: learning rate of that phase (default ``lr``).
        batch_size: minibatch size, None for full batch (shuffled each epoch otherwise).
        weight_decay: AdamW decoupled weight decay (0: plain Adam).
        seed: seeds the minibatch shuffling.

    Returns:
        A :class:`FitResult` with the loss per epoch and the pruning events.
    """
    _check_data(model.nz, model.nu, Z, U, Znext)
    sparse = all(hasattr(model, a) for a in ("l1_penalty", "threshold", "psi", "mask"))
    if (l1 or threshold) and not sparse:
        raise ValueError(
            f"l1={l1} and threshold={threshold} need a SINDy model (psi, mask, threshold), got "
            f"{type(model).__name__}; pass l1=0 and threshold=0 for it"
        )
    if threshold and not every:
        raise ValueError(f"threshold={threshold} given but every=0; set every to prune")
    gen = torch.Generator().manual_seed(seed)
    result = FitResult()
    # (epochs, lr, l1, threshold, every) per phase: sparsify, then optionally debias.
    phases = [(epochs, lr, l1, threshold, every)]
    if debias_epochs:
        phases.append((debias_epochs, lr if debias_lr is None else debias_lr, 0.0, 0.0, 0))
    model.train()
    for n_epochs, phase_lr, phase_l1, tau, period in phases:
        _train(
            model, Z, U, Znext, epochs=n_epochs, lr=phase_lr, l1=phase_l1, threshold=tau,
            every=period, batch_size=batch_size, weight_decay=weight_decay, generator=gen,
            result=result,
        )  # fmt: skip
    if sparse:
        result.n_active = int(model.mask.sum())  # type: ignore[attr-defined]
    return result
