"""Fit a latent dynamics model to state transitions (z_t, u_t, z_{t+1}), SINDy style.

The recipe of the paper's trainer without the images: minimise the one-step loss
``mean ‖step(z_t, u_t) − z_{t+1}‖²`` (plus ``l1 · ‖M ⊙ Ψ‖₁`` for SINDy) with AdamW, prune
coefficients with ``|Ψ| < threshold`` every ``every`` epochs (sequential thresholding), then
optionally *debias*: train on with the L1 weight at zero and the mask frozen, so the surviving
coefficients lose the shrinkage L1 gave them. Useful for known systems (tests), for fitting a
model on encoded latents, and as a reference for the image trainer.

    >>> from latent_sindy.sindy.fit import fit_state_data
    >>> result = fit_state_data(model, Z, U, Znext, epochs=1500, lr=1e-2, l1=1e-4,
    ...                         threshold=0.02, every=300, debias_epochs=500)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
import torch.nn.functional as F

from latent_sindy.models.dynamics import LatentDynamics, SindyDynamics

__all__ = ["FitResult", "fit_state_data", "refit_active_least_squares"]


@dataclass
class FitResult:
    """What :func:`fit_state_data` did."""

    losses: list[float] = field(default_factory=list)
    """One-step MSE per epoch (mean over the epoch's batches), both phases."""
    pruned: list[tuple[int, int]] = field(default_factory=list)
    """(epoch, number newly pruned) at each thresholding, epochs counted from 1."""
    n_active: int | None = None
    """Active coefficients at the end (None for models without a mask)."""


def _check_data(
    model: LatentDynamics, Z: torch.Tensor, U: torch.Tensor, Znext: torch.Tensor
) -> None:
    n = Z.shape[0]
    if Z.shape != (n, model.nz) or Znext.shape != Z.shape or U.shape != (n, model.nu):
        raise ValueError(
            f"expected Z and Znext of shape (N, nz={model.nz}) and U of shape (N, nu={model.nu}), "
            f"got Z {tuple(Z.shape)}, U {tuple(U.shape)}, Znext {tuple(Znext.shape)}"
        )


def _train(
    model: LatentDynamics,
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
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=weight_decay)
    n = Z.shape[0]
    bs = n if batch_size is None else batch_size
    start = len(result.losses)
    for epoch in range(1, epochs + 1):
        order = torch.randperm(n, generator=generator) if bs < n else None
        total, batches = 0.0, 0
        for b in range(0, n, bs):
            idx = slice(b, b + bs) if order is None else order[b : b + bs]
            mse = F.mse_loss(model.step(Z[idx], U[idx]), Znext[idx])
            loss = mse + l1 * model.l1_penalty() if l1 else mse
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            total += float(mse.detach())
            batches += 1
        result.losses.append(total / batches)
        if threshold and every and epoch % every == 0:
            result.pruned.append((start + epoch, model.threshold(threshold)))


def fit_state_data(
    model: LatentDynamics,
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
    """Fit ``model`` in place to transitions ``Znext ≈ model.step(Z, U)``.

    Args:
        model: any latent dynamics model; ``l1`` and ``threshold`` need a
            :class:`SindyDynamics` (they use its ``l1_penalty`` and ``threshold``).
        Z, U, Znext: (N, nz), (N, nu), (N, nz) transitions.
        epochs: passes over the data in the sparsifying phase.
        lr: AdamW learning rate.
        l1: weight of ‖M ⊙ Ψ‖₁ added to the mean squared one-step error.
        threshold: prune active coefficients with |Ψ| below it ...
        every: ... every this many epochs of the sparsifying phase (0: never).
        debias_epochs: then this many epochs with a fresh optimizer, ``l1 = 0`` and no
            thresholding (the mask stays as it is): removes the L1 shrinkage of the surviving
            coefficients. 0 skips the phase.
        debias_lr: learning rate of that phase (default ``lr``).
        batch_size: minibatch size, None for full batch (shuffled each epoch otherwise).
        weight_decay: AdamW decoupled weight decay (0: plain Adam).
        seed: seeds the minibatch shuffling.

    Returns:
        A :class:`FitResult` with the loss per epoch and the pruning events.
    """
    _check_data(model, Z, U, Znext)
    sparse = isinstance(model, SindyDynamics)
    if (l1 or threshold) and not sparse:
        raise ValueError(
            f"l1={l1} and threshold={threshold} need a SindyDynamics model, got "
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
        result.n_active = model.n_active()
    return result


@torch.no_grad()
def refit_active_least_squares(
    model: SindyDynamics, Z: torch.Tensor, U: torch.Tensor, Znext: torch.Tensor
) -> SindyDynamics:
    """Closed-form debiasing: per state, least squares on its active terms; returns ``model``.

    The one-step SINDy residual ``Znext − Z = Θ(Z, U) (M ⊙ Ψ)`` is linear in Ψ, so with the
    mask fixed each column of Ψ is an ordinary least-squares problem (solved in float64). The
    mask is not changed; inactive entries stay 0.
    """
    _check_data(model, Z, U, Znext)
    theta = model.library(Z.double(), U.double())  # (N, p)
    target = (Znext - Z).double()  # (N, nz)
    psi = torch.zeros_like(model.psi, dtype=torch.float64)
    for j in range(model.nz):
        active = model.mask[:, j].nonzero().flatten()
        if active.numel():
            sol = torch.linalg.lstsq(theta[:, active].cpu(), target[:, j : j + 1].cpu()).solution
            psi[active, j] = sol[:, 0].to(psi.device)
    model.psi.copy_(psi.to(model.psi.dtype))
    return model
