"""Fit SINDy to state transitions (z_t, u_t, z_{t+1}) by sparse regression.

The residual step ``z_{t+1} − z_t = Θ(z_t, u_t) Ψ`` is linear in Ψ, so a sparsifier (default
:class:`STLSQ`) solves it in closed form on the library evaluated at the data:
:func:`fit_state_data` returns the fitted sparsifier (``coef_`` (p, nz), ``mask_`` (p, nz));
``SindyDynamics.fit_state_data`` puts them into a model. Models that are not linear in their
parameters train by gradient in :mod:`latent_sindy.training` (the one gradient loop, with the
one pruning rule).

On noisy states, :func:`fit_trajectory_data` fits whole trajectories in a windowed (integral)
form: summed over any ``w`` consecutive steps, the model telescopes to
``x_{k+w} − x_k = (Σ_{j<w} Θ(x_{k+j}, u_{k+j})) Ψ`` exactly, so the target grows with ``w``
while its measurement noise does not, and the sums average the noise of the regressors. The
inputs enter step by step, so unlike smoothing the states this keeps every input's effect
(window 1 is the plain one-step fit). Pair it with :class:`EnsembleSTLSQ` on noisy data.

This package does not import :mod:`latent_sindy.models` (which imports it).

    >>> lib = CandidateLibrary(n_state=3, n_control=1, order=2)
    >>> opt = fit_state_data(lib, Z, U, Znext)  # Z (N, 3), U (N, 1), Znext (N, 3)
    >>> opt.coef_.shape, int(opt.mask_.sum())  # (p, nz), active coefficients
    >>> opt = fit_trajectory_data(lib, X, U)  # windows of 10 steps, bagged STLSQ
    >>> # X (B, T+1, 3) measured trajectories, U (B, T, 1) their inputs
"""

from __future__ import annotations

import torch

from latent_sindy.errors import UserError
from latent_sindy.sindy.ensemble import EnsembleSTLSQ
from latent_sindy.sindy.optimizers import STLSQ
from latent_sindy.sindy.stepwise import StepwiseSR
from latent_sindy.sindy.torch_library import SindyLibrary
from latent_sindy.sindy.trimmed import Trimmed

__all__ = [
    "Sparsifier",
    "fit_state_data",
    "fit_trajectory_data",
    "library_regression_data",
    "window_regression_data",
]

Sparsifier = STLSQ | EnsembleSTLSQ | StepwiseSR | Trimmed


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
    optimizer: Sparsifier | None = None,
    mask: torch.Tensor | None = None,
) -> Sparsifier:
    """Sparse regression of ``Znext − Z`` on ``library(Z, U)``; returns the fitted optimizer.

    Args:
        library: the candidate library (its sizes must match the data).
        Z, U, Znext: (N, nz), (N, nu), (N, nz) transitions.
        optimizer: the sparsifier (default ``STLSQ()``; ``EnsembleSTLSQ(...)`` on noisy
            data); it is fitted in place and returned.
        mask: optional (p, nz) bool, the terms allowed (default all).

    Returns:
        ``optimizer`` with ``coef_`` (p, nz) float64 and ``mask_`` (p, nz) bool.
    """
    theta, target = library_regression_data(library, Z, U, Znext)
    return (STLSQ() if optimizer is None else optimizer).fit(theta, target, mask)


def checked_valid(valid: torch.Tensor, X: torch.Tensor) -> torch.Tensor:
    """``valid`` as a (B, T+1) bool CPU tensor for trajectories X (B, T+1, nz), or an error."""
    valid = torch.as_tensor(valid).detach().to("cpu")
    if valid.dtype != torch.bool or valid.shape != X.shape[:2]:
        raise UserError(f"valid must be a bool array of shape (B, T+1) = {tuple(X.shape[:2])}, "
                        f"one flag per state; got {valid.dtype} {tuple(valid.shape)}")
    return valid


@torch.no_grad()
def window_regression_data(
    library: SindyLibrary, X: torch.Tensor, U: torch.Tensor, window: int = 1,
    valid: torch.Tensor | None = None, targets: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The windowed linear problem of trajectories, float64 on the CPU.

    Args:
        library: the candidate library.
        X: (B, T+1, nz) states of B trajectories; U: (B, T, nu) the inputs between them.
        window: steps per window, 1 <= window <= T.
        valid: optional (B, T+1) bool, the states read well (False: a frame where the
            reading failed, e.g. the object out of the picture; its values, even NaN, are
            not used): only windows whose every state is valid are rows.
        targets: optional (B, T+1, nz), what each window's change is taken of (default X);
            a model whose step is fitted to something else than the next state (an angle
            turned) gives its running sum here.

    Returns:
        Θ_w (R, p) and target (R, nz), R = B·(T+1−window) (fewer with ``valid``), one row per
        window start k: ``Σ_{j<window} Θ(x_{k+j}, u_{k+j})`` and ``x_{k+window} − x_k``.
    """
    nz, nu = library.n_state, library.n_control
    if (
        X.ndim != 3
        or U.ndim != 3
        or X.shape[2] != nz
        or U.shape[2] != nu
        or (X.shape[0] != U.shape[0] or X.shape[1] != U.shape[1] + 1)
    ):
        raise UserError(
            f"expected trajectories X of shape (B, T+1, nz={nz}) and inputs U of shape "
            f"(B, T, nu={nu}), got X {tuple(X.shape)}, U {tuple(U.shape)}"
        )
    steps = U.shape[1]
    if isinstance(window, bool) or not isinstance(window, int) or not 1 <= window <= steps:
        raise UserError(
            f"window={window!r} is not valid: use an integer from 1 to the {steps} steps "
            "of a trajectory"
        )
    B, p = X.shape[0], library.n_terms
    if valid is not None:
        valid = checked_valid(valid, X)
        X = torch.where(valid[..., None].to(X.device), X, torch.zeros((), dtype=X.dtype,
                                                                      device=X.device))
    theta, _ = library_regression_data(
        library, X[:, :-1].reshape(-1, nz), U.reshape(-1, nu), X[:, 1:].reshape(-1, nz)
    )
    theta = theta.reshape(B, steps, p)  # (B, T, p)
    if targets is not None and targets.shape != X.shape:
        raise UserError(f"targets must have the states' shape {tuple(X.shape)}, got "
                        f"{tuple(targets.shape)}")
    X64 = (X if targets is None else targets).detach().to("cpu", torch.float64)
    if window > 1:  # window sums as differences of running sums
        run = torch.cat([theta.new_zeros(B, 1, p), theta.cumsum(dim=1)], dim=1)  # (B, T+1, p)
        theta = run[:, window:] - run[:, :-window]
    target = X64[:, window:] - X64[:, :-window]  # (B, T+1−window, nz)
    theta, target = theta.reshape(-1, p), target.reshape(-1, nz)
    if valid is None:
        return theta, target
    whole = valid.unfold(1, window + 1, 1).all(-1).reshape(-1)  # every state of the window
    if not bool(whole.any()):
        raise UserError(f"no window of {window} steps has every state valid: give longer "
                        "valid stretches or a shorter window")
    return theta[whole], target[whole]


#: Steps a window of :func:`fit_trajectory_data` sums by default (fewer where the
#: trajectories are shorter).
DEFAULT_WINDOW = 10


def fit_trajectory_data(
    library: SindyLibrary,
    X: torch.Tensor,
    U: torch.Tensor,
    window: int | None = None,
    optimizer: Sparsifier | None = None,
    mask: torch.Tensor | None = None,
    valid: torch.Tensor | None = None,
    targets: torch.Tensor | None = None,
) -> Sparsifier:
    """Sparse regression of trajectories in the windowed form (:func:`window_regression_data`).

    X (B, T+1, nz), U (B, T, nu); ``optimizer`` is fitted in place and returned, with
    ``coef_`` (p, nz) the one-step Ψ, as :func:`fit_state_data` gives. The defaults are the
    fit that recovers noisy systems: windows of :data:`DEFAULT_WINDOW` steps (T where the
    trajectories are shorter) and ``EnsembleSTLSQ(seed=0)`` (bagged STLSQ); on noise-free
    data they find what STLSQ on the transitions finds. ``window=1`` with
    ``optimizer=STLSQ()`` is :func:`fit_state_data` on the trajectories' transitions.
    ``valid`` (B, T+1) bool keeps the windows whose states were all read well; ``targets``:
    see :func:`window_regression_data`.

    States read with an error (a camera's) are what the windowed form is for: a one-step fit
    regresses the next change on a state that shares a frame's error with it, and fits that
    error's correlation as dynamics; over a window the shared errors are the two ends' only.
    With events a smooth library cannot write (end stops, contacts), wrap the sparsifier in
    ``Trimmed`` and keep windows short (RESULTS.md measures both on a cart-pole).
    """
    from latent_sindy.sindy.ensemble import EnsembleSTLSQ

    if window is None:
        window = max(1, min(DEFAULT_WINDOW, X.shape[1] - 1))
    theta, target = window_regression_data(library, X, U, window, valid, targets)
    return (EnsembleSTLSQ(seed=0) if optimizer is None else optimizer).fit(theta, target, mask)
