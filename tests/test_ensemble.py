"""Sparse regression on noisy data: the windowed (integral) form of trajectories and the
bagged STLSQ (EnsembleSTLSQ), on known systems with measurement noise."""

from __future__ import annotations

import pytest
import torch

from latent_sindy.errors import UserError
from latent_sindy.sindy import (
    STLSQ,
    EnsembleSTLSQ,
    fit_state_data,
    fit_trajectory_data,
    window_regression_data,
)
from latent_sindy.sindy.systems import KnownSystem, lorenz_control


def _trajectories(
    system: KnownSystem, n_traj: int, steps: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """The system's flattened transitions as trajectories X (B, T+1, nz), U (B, T, nu)."""
    nz, nu = system.Z.shape[1], system.U.shape[1]
    Znext = system.Znext.view(n_traj, steps, nz)
    X = torch.cat([system.Z.view(n_traj, steps, nz), Znext[:, -1:]], dim=1)
    assert torch.equal(X[:, 1:-1], Znext[:, :-1])  # the flattening is trajectory-major
    return X, system.U.view(n_traj, steps, nu)


def _noisy_lorenz(seed: int, noise: float = 0.01):
    """Order-2 Lorenz (15 terms, 8 true), 4 trajectories of 250 steps, measured with Gaussian
    noise of ``noise`` times each state's std."""
    system = lorenz_control(seed=seed, n_traj=4, steps=250, order=2)
    X, U = _trajectories(system, 4, 250)
    gen = torch.Generator().manual_seed(100 + seed)
    X = X + noise * X.reshape(-1, 3).std(dim=0) * torch.randn(
        X.shape, generator=gen, dtype=torch.float64
    )
    return system, X, U


# ---------------------------------------------------------------- the windowed form


def test_window_one_is_the_one_step_fit():
    system = lorenz_control(seed=0, n_traj=3, steps=100)
    X, U = _trajectories(system, 3, 100)
    theta, target = window_regression_data(system.library, X, U, 1)
    assert torch.equal(theta, system.library(system.Z, system.U).double())
    assert torch.equal(target, system.Znext - system.Z)
    ours = fit_trajectory_data(system.library, X, U, window=1, optimizer=STLSQ())
    assert torch.equal(
        ours.coef_, fit_state_data(system.library, system.Z, system.U, system.Znext).coef_
    )


@pytest.mark.parametrize("window", [2, 7, 40])
def test_windowed_rows_telescope_exactly(window):
    """Noise-free: Σ Θ(x_j, u_j) Ψ_true over a window is x_{k+w} − x_k, and STLSQ on the
    windowed rows recovers Ψ_true."""
    system = lorenz_control(seed=1, n_traj=3, steps=100)
    X, U = _trajectories(system, 3, 100)
    theta, target = window_regression_data(system.library, X, U, window)
    assert theta.shape == (3 * (101 - window), system.library.n_terms)
    true = system.true_coefficients()
    assert torch.allclose(theta @ true, target, rtol=0, atol=1e-9)
    fit = STLSQ().fit(theta, target)
    assert torch.equal(fit.mask_, true != 0)
    assert torch.allclose(fit.coef_, true, rtol=1e-8, atol=1e-12)


# ---------------------------------------------------------------- noisy recovery


SEEDS = [0, 1, 2, 3]


def test_ensemble_on_windows_recovers_noisy_lorenz_where_stlsq_fails():
    """1 % measurement noise: over every seed the ensemble on 10-step windows finds the exact
    active set, with coefficients within 5 %; STLSQ on the one-step pairs never does, and on
    the same windows not in every seed."""
    stlsq_pairs, stlsq_windows = [], []
    for seed in SEEDS:
        system, X, U = _noisy_lorenz(seed)
        true = system.true_coefficients()
        active = true != 0
        ens = fit_trajectory_data(
            system.library, X, U, window=10, optimizer=EnsembleSTLSQ(n_models=10, seed=seed)
        )
        assert torch.equal(ens.mask_, active), f"seed {seed}"
        assert ((ens.coef_ - true)[active].abs() / true[active].abs()).max() < 0.05
        stlsq_pairs.append(torch.equal(
            fit_trajectory_data(system.library, X, U, 1, STLSQ()).mask_, active))
        stlsq_windows.append(torch.equal(
            fit_trajectory_data(system.library, X, U, 10, STLSQ()).mask_, active))
    assert not any(stlsq_pairs)
    assert sum(stlsq_windows) < len(SEEDS)


def test_the_default_trajectory_fit_recovers_noisy_lorenz_and_noise_free_data_exactly():
    """fit_trajectory_data with its defaults (windows of 10, bagged STLSQ): the exact active
    set on 1 % noise in every seed, and Ψ itself on noise-free data."""
    for seed in SEEDS[:2]:
        system, X, U = _noisy_lorenz(seed)
        active = system.true_coefficients() != 0
        assert torch.equal(fit_trajectory_data(system.library, X, U).mask_, active), seed
    system = lorenz_control(seed=2, n_traj=3, steps=200)
    X, U = _trajectories(system, 3, 200)
    fit = fit_trajectory_data(system.library, X, U)
    true = system.true_coefficients()
    assert torch.equal(fit.mask_, true != 0)
    assert torch.allclose(fit.coef_, true, rtol=1e-8, atol=1e-10)
    short = lorenz_control(seed=3, n_traj=100, steps=5)  # windows of 5 steps, 100 rows
    X, U = _trajectories(short, 100, 5)
    assert torch.equal(fit_trajectory_data(short.library, X, U).mask_, true != 0)


def test_noise_free_data_stay_exact():
    system = lorenz_control(seed=2, n_traj=3, steps=200)
    ens = EnsembleSTLSQ(n_models=3, seed=0).fit(*_rows(system))
    true = system.true_coefficients()
    assert torch.equal(ens.mask_, true != 0)
    assert torch.allclose(ens.coef_, true, rtol=1e-8, atol=1e-12)


def _rows(system: KnownSystem) -> tuple[torch.Tensor, torch.Tensor]:
    return system.library(system.Z, system.U).double(), system.Znext - system.Z


# ---------------------------------------------------------------- the estimator


@pytest.fixture(scope="module")
def noisy_rows() -> tuple[torch.Tensor, torch.Tensor]:
    system, X, U = _noisy_lorenz(0)
    return window_regression_data(system.library, X, U, 10)


def test_same_seed_same_result_other_seed_other_resamples(noisy_rows):
    a = EnsembleSTLSQ(n_models=4, library_drop=2, seed=3).fit(*noisy_rows)
    b = EnsembleSTLSQ(n_models=4, library_drop=2, seed=3).fit(*noisy_rows)
    c = EnsembleSTLSQ(n_models=4, library_drop=2, seed=4).fit(*noisy_rows)
    assert torch.equal(a.coef_, b.coef_) and torch.equal(a.coef_models_, b.coef_models_)
    assert torch.equal(a.offered_, b.offered_)
    assert not torch.equal(a.coef_models_, c.coef_models_)
    assert not torch.equal(a.offered_, c.offered_)


def test_without_resampling_it_is_the_base_fit(noisy_rows):
    """No bagging, no library drop: every model is the base fit, spread 0, inclusion 0 or 1."""
    base = STLSQ(min_share=0.02)
    ens = EnsembleSTLSQ(base, n_models=3, bagging=False).fit(*noisy_rows)
    ref = STLSQ(min_share=0.02).fit(*noisy_rows)
    assert torch.equal(ens.coef_, ref.coef_) and torch.equal(ens.mask_, ref.mask_)
    assert ens.spread_.max() < 1e-15  # round-off of the mean of equal values
    assert torch.equal(ens.inclusion_, ref.mask_.double())


def test_library_bagging_offers_all_but_the_dropped_terms(noisy_rows):
    p = noisy_rows[0].shape[1]
    ens = EnsembleSTLSQ(n_models=6, library_drop=4, seed=0).fit(*noisy_rows)
    assert ens.offered_.shape == (6, p)
    assert (ens.offered_.sum(dim=1) == p - 4).all()
    assert (ens.coef_models_[~ens.offered_] == 0).all()  # a term not offered is never fitted
    assert ((ens.inclusion_ >= 0) & (ens.inclusion_ <= 1)).all()


def test_mask_and_selection_rules(noisy_rows):
    theta, target = noisy_rows
    p, m = theta.shape[1], target.shape[1]
    allowed = torch.ones(p, m, dtype=torch.bool)
    allowed[1] = False  # term 1 (z0) is in the true model of z0 and z1
    masked = EnsembleSTLSQ(n_models=3, seed=0).fit(theta, target, allowed)
    assert not masked.mask_[1].any() and (masked.coef_[1] == 0).all()
    default = EnsembleSTLSQ(n_models=3, seed=0).fit(theta, target)
    loose = EnsembleSTLSQ(n_models=3, seed=0, z_min=0.0, inclusion=0.0).fit(theta, target)
    strict = EnsembleSTLSQ(n_models=3, seed=0, z_min=1e6).fit(theta, target)
    assert loose.mask_.sum() > default.mask_.sum() and not strict.mask_.any()
    plain = EnsembleSTLSQ(n_models=3, seed=0, refit=False).fit(theta, target)
    assert torch.equal(plain.coef_[plain.mask_], plain.centre_[plain.mask_])
    mean = EnsembleSTLSQ(n_models=3, seed=0, aggregate="mean", refit=False).fit(theta, target)
    assert torch.allclose(mean.centre_, mean.coef_models_.mean(dim=0))


# ---------------------------------------------------------------- bad arguments


@pytest.mark.parametrize(
    "kwargs",
    [
        {"n_models": 0},
        {"n_models": 2.5},
        {"inclusion": 1.5},
        {"inclusion": float("nan")},
        {"z_min": -1.0},
        {"aggregate": "mode"},
        {"library_drop": -1},
        {"seed": -1},
        {"seed": True},
        {"base": "stlsq"},
    ],
)
def test_bad_settings_raise_user_error(kwargs):
    with pytest.raises(UserError, match=next(iter(kwargs))):
        EnsembleSTLSQ(**kwargs)


def test_windows_over_invalid_states_are_left_out():
    """States marked invalid (here NaN, as a reading that failed) drop exactly the windows
    that hold them; the others are the unmasked problem's rows, and still telescope."""
    system = lorenz_control(seed=2, n_traj=2, steps=60)
    X, U = _trajectories(system, 2, 60)
    valid = torch.ones(X.shape[:2], dtype=torch.bool)
    valid[0, 10] = valid[1, 30:33] = valid[1, 60] = False
    broken = X.clone()
    broken[~valid] = float("nan")
    window = 4
    theta, target = window_regression_data(system.library, broken, U, window, valid=valid)
    full_theta, full_target = window_regression_data(system.library, X, U, window)
    keep = [b * (61 - window) + k for b in range(2) for k in range(61 - window)
            if bool(valid[b, k:k + window + 1].all())]
    assert len(keep) == 2 * (61 - window) - 5 - 7 - 1
    assert torch.allclose(theta, full_theta[keep], rtol=1e-12, atol=1e-12)
    assert torch.equal(target, full_target[keep])
    true = system.true_coefficients()
    assert torch.allclose(theta @ true, target, rtol=0, atol=1e-9)
    fit = fit_trajectory_data(system.library, broken, U, window, STLSQ(), valid=valid)
    assert torch.equal(fit.mask_, true != 0)
    with pytest.raises(UserError, match="valid must be a bool"):
        window_regression_data(system.library, X, U, window, valid=valid[:, :-1])
    with pytest.raises(UserError, match="no window of 4 steps"):
        window_regression_data(system.library, X, U, window, valid=torch.zeros_like(valid))


def test_bad_data_raise_user_error(noisy_rows):
    theta, target = noisy_rows
    with pytest.raises(UserError, match="library_drop=15"):
        EnsembleSTLSQ(library_drop=15).fit(theta, target)
    system, X, U = _noisy_lorenz(0)
    for window in (0, 251, 2.0):
        with pytest.raises(UserError, match="window="):
            window_regression_data(system.library, X, U, window)
    with pytest.raises(UserError, match=r"\(B, T\+1, nz=3\)"):
        window_regression_data(system.library, X[:, :-1], U, 2)
    with pytest.raises(UserError, match=r"\(B, T\+1, nz=3\)"):
        window_regression_data(system.library, X.reshape(-1, 3), U, 2)
