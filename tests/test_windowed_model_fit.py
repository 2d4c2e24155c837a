"""A SINDy model fitted to whole trajectories in the windowed form
(:meth:`SindyDynamics.fit_trajectory_data`): the same problem as the library's function,
a turning angle's targets, states read badly left out, and a camera's error that spoils
the one-step fit of a frame-difference latent but not the windowed one."""

from __future__ import annotations

import math

import pytest
import torch

from latent_sindy.errors import UserError
from latent_sindy.models import SindyConfig
from latent_sindy.sindy import STLSQ, fit_trajectory_data

H, GRAVITY, GAIN = 0.05, 10.0, 4.0  # step, -sin φ's and u's weight in the acceleration


def _swinging(seed: int, noise: float = 0.0, trajectories: int = 4, steps: int = 300):
    """A driven pendulum seen as a frame-difference latent: z = (cos φ, sin φ, d) with
    d_t = (φ_t − φ_{t−1}) / H, φ read with Gaussian error of ``noise`` rad. Exactly,
    φ_{t+1} − φ_t = H d_t + H² (−GRAVITY sin φ_t + GAIN u_t) and d_{t+1} − d_t = H (…)."""
    g = torch.Generator().manual_seed(seed)
    U = torch.rand(trajectories, steps, 1, generator=g, dtype=torch.float64) * 2 - 1
    phi = torch.zeros(trajectories, steps + 2, dtype=torch.float64)
    phi[:, 0] = torch.rand(trajectories, generator=g, dtype=torch.float64) * 2 * math.pi
    phi[:, 1] = phi[:, 0] + H * (torch.rand(trajectories, generator=g, dtype=torch.float64) - 0.5)
    for t in range(1, steps + 1):
        accel = -GRAVITY * torch.sin(phi[:, t]) + GAIN * U[:, t - 1, 0]
        phi[:, t + 1] = 2 * phi[:, t] - phi[:, t - 1] + H * H * accel
    read = phi + noise * torch.randn(phi.shape, generator=g, dtype=torch.float64)
    d = (read[:, 1:] - read[:, :-1]) / H
    X = torch.stack([torch.cos(read[:, 1:]), torch.sin(read[:, 1:]), d], -1)  # (B, T+1, 3)
    return X, U


def _model(turn: bool = True):
    return SindyConfig(order=2, include_sine=False).build(3, 1, circle=(0, 1), turn=turn).double()


def _coefficient(model, state: int, term: str) -> float:
    return dict(((s, t), v) for s, t, v in model.coefficient_rows()).get((f"z{state}", term), 0.0)


def test_without_a_turn_it_is_the_library_fit():
    X, U = _swinging(0)
    model = _model(turn=False).fit_trajectory_data(X, U, 5, STLSQ())
    direct = fit_trajectory_data(model.library, X, U, 5, STLSQ())
    assert torch.equal(model.mask, direct.mask_)
    assert torch.allclose(model.coefficients(), direct.coef_, rtol=1e-12, atol=0)


@pytest.mark.parametrize("window", [1, 5])
def test_a_turn_is_fitted_to_the_angle_turned_over_each_window(window):
    """Noise-free, the turn's equation is H d − H² GRAVITY sin φ + H² GAIN u at any window."""
    X, U = _swinging(1)
    model = _model().fit_trajectory_data(X, U, window, STLSQ(min_share=1e-3))
    expected = {(0, "z2"): H, (0, "z1"): -H * H * GRAVITY, (0, "u0"): H * H * GAIN,
                (2, "z1"): -H * GRAVITY, (2, "u0"): H * GAIN}
    assert {(int(s[1:]), t) for s, t, _ in model.coefficient_rows()} == set(expected)
    for (state, term), value in expected.items():
        assert _coefficient(model, state, term) == pytest.approx(value, rel=1e-6)
    assert model.equations()[0].startswith("ω = turn of (z0, z1) = ")


def test_states_read_badly_are_left_out_even_when_nan():
    X, U = _swinging(2)
    valid = torch.ones(X.shape[:2], dtype=torch.bool)
    valid[0, 40:45] = valid[2, 100] = False
    broken = X.clone()
    broken[~valid] = float("nan")
    model = _model().fit_trajectory_data(broken, U, 5, STLSQ(min_share=1e-3), valid=valid)
    clean = _model().fit_trajectory_data(X, U, 5, STLSQ(min_share=1e-3))
    assert torch.equal(model.mask, clean.mask)
    assert torch.allclose(model.coefficients(), clean.coefficients(), rtol=1e-6, atol=1e-12)
    with pytest.raises(UserError, match="valid must be a bool"):
        _model().fit_trajectory_data(X, U, 5, valid=valid[:, 1:])


def test_the_window_recovers_the_swing_that_a_cameras_error_hides_from_one_step():
    """An angle read with 0.01 rad error: regressing the next frame difference on this one
    (sharing a frame's error) gets gravity and gain wrong; sums over windows of 5 steps
    get them within a few percent, over seeds."""
    for seed in range(3):
        X, U = _swinging(10 + seed, noise=0.01, trajectories=8)
        errors = {}
        for window in (1, 5):
            model = _model().fit_trajectory_data(X, U, window, STLSQ(min_share=1e-3))
            errors[window] = max(
                abs(_coefficient(model, 2, "z1") / (-H * GRAVITY) - 1),
                abs(_coefficient(model, 2, "u0") / (H * GAIN) - 1))
        assert errors[5] < 0.1 and errors[5] < errors[1] / 3, (seed, errors)


def test_terms_tied_by_the_circle_are_pruned_and_the_fit_keeps_one_of_each():
    """cos² + sin² = 1: at order 3 the regression spreads each effect over z, z0² z and
    z1² z (15 terms for 5); pruning the terms with z1² first leaves the 5 exact ones."""
    X, U = _swinging(3)
    counts = {}
    for prune in (False, True):
        model = SindyConfig(order=3, include_sine=False).build(
            3, 1, circle=(0, 1), turn=True).double()
        pruned = model.prune_circle_ties() if prune else 0
        if prune:
            names = model.names
            assert pruned == 2 * sum("z1^" in n for n in names)  # z2's and ω's columns
            assert not any("z1^" in names[i] for i in model.mask.any(1).nonzero().flatten())
        model.fit_trajectory_data(X, U, 5, STLSQ(min_share=1e-3), restrict_to_mask=prune)
        counts[prune] = model.n_active()
    assert counts[True] == 5 < counts[False]
    assert _coefficient(model, 2, "z1") == pytest.approx(-H * GRAVITY, rel=1e-6)
    with pytest.raises(UserError, match="needs a model built with a circle"):
        SindyConfig(order=3).build(3, 1).prune_circle_ties()
