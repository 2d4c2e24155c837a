"""Fits to state transitions: STLSQ against known systems and pysindy, the model hook, and the
closed-form refit on a fixed mask."""

from __future__ import annotations

import subprocess
import sys
import warnings

import numpy as np
import pysindy as ps
import pytest
import torch

from latent_sindy.errors import UserError
from latent_sindy.models import SindyDynamics
from latent_sindy.sindy import STLSQ, CandidateLibrary, fit_state_data
from latent_sindy.sindy.fit import library_regression_data
from latent_sindy.sindy.systems import KnownSystem, duffing_forced, lorenz_control

# ---------------------------------------------------------------- a small known system

# nz=2, nu=1, 7 true terms out of 2 x 12 candidates (order 2 + sin).
TRUE_TERMS = {
    ("z0", "z0"): -0.1,
    ("z0", "z1"): 0.2,
    ("z0", "u0"): 0.5,
    ("z1", "1"): 0.05,
    ("z1", "z0^2"): 0.1,
    ("z1", "z0 z1"): -0.3,
    ("z1", "z1 u0"): -0.2,
}


def _true_step(z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    z0, z1, u0 = z[:, 0], z[:, 1], u[:, 0]
    dz0 = -0.1 * z0 + 0.2 * z1 + 0.5 * u0
    dz1 = 0.05 + 0.1 * z0**2 - 0.3 * z0 * z1 - 0.2 * z1 * u0
    return z + torch.stack([dz0, dz1], dim=1)


@pytest.fixture(scope="module")
def known_data() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """400 random trajectories of 5 steps from random states and actions in [-1, 1]."""
    gen = torch.Generator().manual_seed(0)
    z = torch.rand(400, 2, generator=gen) * 2 - 1
    Z, U, Znext = [], [], []
    for _ in range(5):
        u = torch.rand(400, 1, generator=gen) * 2 - 1
        z_next = _true_step(z, u)
        Z.append(z), U.append(u), Znext.append(z_next)
        z = z_next
    return torch.cat(Z), torch.cat(U), torch.cat(Znext)


def _recovered(model: SindyDynamics) -> dict[tuple[str, str], float]:
    return {(state, term): value for state, term, value in model.coefficient_rows()}


def _worst_relative_error(model: SindyDynamics) -> float:
    got = _recovered(model)
    return max(abs(got.get(k, 0.0) - v) / abs(v) for k, v in TRUE_TERMS.items())


def test_sindy_recovers_a_known_controlled_system(known_data) -> None:
    model = SindyDynamics(2, 1, order=2, seed=0)
    opt = STLSQ()
    assert model.fit_state_data(*known_data, optimizer=opt) is model
    assert set(_recovered(model)) == set(TRUE_TERMS)
    assert model.n_active() == len(TRUE_TERMS)
    assert _worst_relative_error(model) < 1e-5  # float32 data and Ψ
    assert opt.n_iter_ <= 3 and opt.mask_.shape == (12, 2)
    assert int((model.psi != 0).sum()) == len(TRUE_TERMS)


def test_fit_state_data_works_on_a_library_and_arrays(known_data) -> None:
    lib = CandidateLibrary(2, 1, 2)
    opt = fit_state_data(lib, *known_data)
    assert opt.coef_.dtype == torch.float64 and opt.coef_.shape == (12, 2)
    names = lib.names
    got = {(f"z{j}", names[i]) for i, j in opt.mask_.nonzero().tolist()}
    assert got == set(TRUE_TERMS)


def test_the_sindy_package_does_not_import_models() -> None:
    code = (
        "import sys, latent_sindy.sindy, latent_sindy.sindy.systems\n"
        "bad = sorted(m for m in sys.modules if m.startswith('latent_sindy.models'))\n"
        "assert not bad, bad\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


# ---------------------------------------------------------------- STLSQ itself


def _random_problem(seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """theta (400, 10) with very different column scales, a sparse (10, 3) coef, target."""
    gen = torch.Generator().manual_seed(seed)
    theta = torch.randn(400, 10, generator=gen, dtype=torch.float64)
    theta = theta * torch.logspace(-3, 3, 10, dtype=torch.float64)
    coef = torch.zeros(10, 3, dtype=torch.float64)
    coef[[0, 4, 9], [0, 1, 2]] = torch.tensor([500.0, 2.0, -1e-3], dtype=torch.float64)
    coef[5, 0] = 3e-2
    return theta, coef, theta @ coef


def test_stlsq_is_scale_free_and_exact_on_noise_free_data() -> None:
    theta, coef, target = _random_problem()
    opt = STLSQ().fit(theta, target)
    assert torch.equal(opt.mask_, coef != 0)
    torch.testing.assert_close(opt.coef_, coef, rtol=1e-9, atol=0)
    # Rescaling columns and targets rescales the coefficients and keeps the mask.
    col = torch.logspace(2, -2, 10, dtype=torch.float64)
    out = torch.tensor([1e-4, 1.0, 1e5], dtype=torch.float64)
    scaled = STLSQ().fit((theta * col).numpy(), (target * out).numpy())
    assert torch.equal(scaled.mask_, opt.mask_)
    torch.testing.assert_close(scaled.coef_, coef / col[:, None] * out, rtol=1e-9, atol=0)


def test_stlsq_min_share_is_relative_to_the_target() -> None:
    theta, coef, target = _random_problem()
    # coef[5, 0] = 0.03 on a column of RMS ~ 10**0.33: a small share of target 0's RMS.
    share = float(
        coef[5, 0] * theta[:, 5].square().mean().sqrt() / target[:, 0].square().mean().sqrt()
    )
    assert bool(STLSQ(min_share=0.9 * share).fit(theta, target).mask_[5, 0])
    assert not bool(STLSQ(min_share=1.1 * share).fit(theta, target).mask_[5, 0])


def test_keep_mask_is_the_fit_rule_without_refitting() -> None:
    theta, coef, target = _random_problem()
    opt = STLSQ(min_share=0.05)
    noisy = coef + 1e-9  # every coefficient nonzero; the tiny ones must go
    keep = opt.keep_mask(noisy, theta, target)
    assert torch.equal(keep, opt.fit(theta, target).mask_)
    some = torch.ones_like(keep)
    some[0, 0] = False
    assert torch.equal(opt.keep_mask(noisy.float(), theta, target, mask=some), keep & some)
    with pytest.raises(ValueError, match="keep_mask"):
        opt.keep_mask(noisy[:-1], theta, target)


def test_stlsq_mask_only_turns_off_and_min_share_zero_is_least_squares() -> None:
    theta, _, target = _random_problem(1)
    allowed = torch.ones(10, 3, dtype=torch.bool)
    allowed[4, 1] = False  # a true term excluded by the caller stays excluded
    opt = STLSQ().fit(theta, target, mask=allowed)
    assert not opt.mask_[4, 1] and not (opt.mask_ & ~allowed).any()
    gen = torch.Generator().manual_seed(3)
    noisy = target + 0.01 * torch.randn(target.shape, generator=gen, dtype=torch.float64)
    ls = STLSQ(min_share=0.0).fit(theta, noisy)
    assert ls.mask_.all()
    want = torch.linalg.lstsq(theta, noisy, driver="gelsd").solution
    torch.testing.assert_close(ls.coef_, want, rtol=1e-7, atol=1e-12)


def test_stlsq_handles_zero_columns_and_targets() -> None:
    theta, _, target = _random_problem(2)
    theta[:, 3] = 0.0
    target[:, 2] = 0.0
    opt = STLSQ().fit(theta, target)
    assert not opt.mask_[3].any() and not opt.mask_[:, 2].any()
    assert torch.isfinite(opt.coef_).all() and (opt.coef_[:, 2] == 0).all()


@pytest.mark.parametrize(
    "kwargs", [{"min_share": -1.0}, {"alpha": float("nan")}, {"max_iter": 0}, {"max_iter": 2.5}]
)
def test_stlsq_rejects_bad_settings(kwargs) -> None:
    with pytest.raises(UserError, match="STLSQ"):
        STLSQ(**kwargs)


def test_stlsq_rejects_bad_arrays() -> None:
    theta, _, target = _random_problem()
    with pytest.raises(ValueError, match="rows"):
        STLSQ().fit(theta, target[:-1])
    with pytest.raises(ValueError, match="2-D"):
        STLSQ().fit(theta[:, 0], target)
    with pytest.raises(ValueError, match="mask"):
        STLSQ().fit(theta, target, mask=torch.ones(3, 3, dtype=torch.bool))
    theta[0, 0] = float("nan")
    with pytest.raises(ValueError, match="finite"):
        STLSQ().fit(theta, target)


# ---------------------------------------------------------------- known systems vs pysindy

SEEDS = range(5)
SYSTEMS = {"lorenz": lorenz_control, "duffing": duffing_forced}


def _exact(mask: np.ndarray, system: KnownSystem) -> bool:
    return bool(np.array_equal(mask, system.true_coefficients().numpy() != 0))


@pytest.mark.parametrize("name", sorted(SYSTEMS))
def test_defaults_recover_known_systems_at_least_as_often_as_pysindy(name: str) -> None:
    ours, theirs = 0, 0
    for seed in SEEDS:
        system = SYSTEMS[name](seed=seed)
        assert system.Z.shape[0] == 5000 and torch.isfinite(system.Znext).all()
        theta, target = library_regression_data(system.library, system.Z, system.U, system.Znext)
        opt = STLSQ().fit(theta, target)
        if _exact(opt.mask_.numpy(), system):
            ours += 1
            true = system.true_coefficients()
            active = true != 0
            rel = (opt.coef_[active] - true[active]).abs() / true[active].abs()
            assert float(rel.max()) < 0.01, (name, seed)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # pysindy warns when it prunes everything
            ref = ps.STLSQ().fit(theta.numpy(), target.numpy())
        theirs += _exact(ref.coef_.T != 0, system)
    assert ours >= theirs
    assert ours == len(SEEDS)


def test_model_hook_on_a_library_with_trig_of_a_control() -> None:
    system = duffing_forced(seed=0)
    model = SindyDynamics(2, 2, library_spec=system.library.spec)
    model.double().fit_state_data(system.Z, system.U, system.Znext)
    assert {(s, t) for s, t, _ in model.coefficient_rows()} == set(system.true)
    for state, term, value in model.coefficient_rows():
        assert value == pytest.approx(system.true[(state, term)], rel=1e-9)
    z0 = system.Z[:7]
    actions = system.U[:35].reshape(7, 5, 2)
    assert torch.isfinite(model.rollout(z0, actions)).all()


# ---------------------------------------------------------------- the refit on a mask


def test_closed_form_refit_on_the_mask_removes_a_shrinkage(known_data) -> None:
    # A mask with shrunken coefficients (what L1 leaves behind in the image trainer): STLSQ
    # with min_share 0 restricted to the mask keeps the mask and refits the values exactly.
    model = SindyDynamics(2, 1, order=2, seed=0)
    model.fit_state_data(*known_data, optimizer=STLSQ())
    mask = model.mask.clone()
    with torch.no_grad():
        model.psi.mul_(0.8)
    assert _worst_relative_error(model) > 0.1
    model.fit_state_data(*known_data, optimizer=STLSQ(min_share=0.0), restrict_to_mask=True)
    assert torch.equal(model.mask, mask)
    assert set(_recovered(model)) == set(TRUE_TERMS)
    assert _worst_relative_error(model) < 1e-4
