"""Fit SINDy to state transitions (z_t, u_t, z_{t+1}) by sparse regression.

The residual step ``z_{t+1} − z_t = Θ(z_t, u_t) Ψ`` is linear in Ψ, so a sparsifier (default
:class:`STLSQ`) solves it in closed form on the library evaluated at the data:
:func:`fit_state_data` returns the fitted sparsifier (``coef_`` (p, nz), ``mask_`` (p, nz));
``SindyDynamics.fit_state_data`` puts them into a model. Models that are not linear in their
parameters train by gradient in :mod:`latent_sindy.training` (the one gradient loop, with the
one pruning rule).

This package does not import :mod:`latent_sindy.models` (which imports it).

    >>> lib = CandidateLibrary(n_state=3, n_control=1, order=2)
    >>> opt = fit_state_data(lib, Z, U, Znext)  # Z (N, 3), U (N, 1), Znext (N, 3)
    >>> opt.coef_.shape, int(opt.mask_.sum())  # (p, nz), active coefficients
"""

from __future__ import annotations

import torch

from latent_sindy.sindy.optimizers import STLSQ
from latent_sindy.sindy.torch_library import SindyLibrary

__all__ = ["fit_state_data", "library_regression_data"]


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
