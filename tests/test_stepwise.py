"""StepwiseSR: backward elimination finds the sparse law where the library's terms are
dependent on the data (where STLSQ keeps most of them), and as many terms as STLSQ where
they are not; its tolerance bounds what the fit loses; bad settings are refused."""

from __future__ import annotations

import pytest
import torch

from latent_sindy.errors import UserError
from latent_sindy.sindy import STLSQ, Polynomial, SindyLibrary, StepwiseSR, fit_state_data
from latent_sindy.sindy.systems import lorenz_control


def _circle_data(seed: int = 0, n: int = 800):
    """Points on the unit circle and a linear law of them: every cubic monomial times
    x² + y² equals the monomial, so the order-3 library is dependent there."""
    gen = torch.Generator().manual_seed(seed)
    angle = torch.rand(n, generator=gen, dtype=torch.float64) * 6.283
    z = torch.stack([angle.cos(), angle.sin()], 1)  # (n, 2)
    lib = SindyLibrary(Polynomial("z", 3), n_state=2, n_control=0)
    theta = lib(z)  # (n, 10)
    target = torch.stack([z[:, 0] + 2 * z[:, 1], -0.5 * z[:, 0]], 1)
    target = target + 1e-6 * torch.randn(target.shape, generator=gen, dtype=torch.float64)
    return lib, theta, target


def _active(lib, opt, j):
    return {lib.names[i] for i in opt.mask_[:, j].nonzero().flatten().tolist()}


def test_on_a_dependent_library_it_finds_the_simplest_law():
    lib, theta, target = _circle_data()
    opt = StepwiseSR(tolerance=1e-6, complexity=lib.degrees).fit(theta, target)
    assert _active(lib, opt, 0) == {"z0", "z1"}
    assert _active(lib, opt, 1) == {"z0"}
    coef = {name: opt.coef_[lib.names.index(name), 0].item() for name in ("z0", "z1")}
    assert coef == pytest.approx({"z0": 1.0, "z1": 2.0}, abs=1e-5)
    # STLSQ judges coefficients: the spread over the dependent terms keeps more of them
    stlsq = STLSQ(min_share=0.01).fit(theta, target)
    assert int(stlsq.mask_.sum()) > int(opt.mask_.sum())


def test_without_complexity_it_may_keep_an_equal_term_of_higher_degree():
    lib, theta, target = _circle_data()
    plain = StepwiseSR(tolerance=1e-6).fit(theta, target)
    ranked = StepwiseSR(tolerance=1e-6, complexity=lib.degrees).fit(theta, target)
    fit = (theta @ plain.coef_ - target).square().mean()
    assert float(fit) < 1e-10  # as good a fit either way ...
    degree = lib.degrees.double()
    mean_degree = [float(degree[o.mask_.any(1)].mean()) for o in (plain, ranked)]
    assert mean_degree[1] < mean_degree[0]  # ... but the ranked one is the simpler law


def test_on_an_independent_library_it_recovers_lorenz_like_stlsq():
    system = lorenz_control(seed=0)
    theta = system.library(system.Z, system.U)
    target = system.Znext - system.Z
    opt = StepwiseSR(tolerance=1e-5, complexity=system.library.degrees).fit(theta, target)
    true = system.true_coefficients()
    assert torch.equal(opt.mask_, true != 0)
    assert torch.allclose(opt.coef_, true, atol=1e-6)


def test_the_tolerance_bounds_what_the_fit_loses():
    gen = torch.Generator().manual_seed(3)
    theta = torch.randn(500, 12, generator=gen, dtype=torch.float64)
    coef = torch.zeros(12, 2, dtype=torch.float64)
    coef[:4, 0] = torch.tensor([1.0, 0.3, 0.05, 0.01], dtype=torch.float64)
    coef[5:8, 1] = torch.tensor([2.0, -0.2, 0.02], dtype=torch.float64)
    target = theta @ coef + 1e-3 * torch.randn(500, 2, generator=gen, dtype=torch.float64)
    full = torch.linalg.lstsq(theta, target).solution
    base = (theta @ full - target).square().mean(0)
    for tol in (1e-5, 1e-3, 1e-2):
        opt = StepwiseSR(tolerance=tol).fit(theta, target)
        loss = (theta @ opt.coef_ - target).square().mean(0)
        dropped = (~opt.mask_).sum(0).double()
        budget = tol * target.square().mean(0) * dropped
        assert (loss - base <= budget + 1e-12).all()
    # a looser tolerance drops more: the smallest true terms go first
    few = StepwiseSR(tolerance=1e-2).fit(theta, target)
    assert few.mask_[:2, 0].all() and not few.mask_[3, 0]
    assert opt.n_iter_ == int((~opt.mask_).sum())


def test_a_mask_keeps_terms_out_and_the_fit_plugs_into_fit_state_data():
    system = lorenz_control(seed=1)
    allowed = torch.ones(system.library.n_terms, 3, dtype=torch.bool)
    allowed[system.library.names.index("z1"), 0] = False  # a true term of ẋ
    opt = fit_state_data(system.library, system.Z, system.U, system.Znext,
                         StepwiseSR(1e-5, complexity=system.library.degrees), allowed)
    assert not opt.mask_[system.library.names.index("z1"), 0]
    assert opt.coef_[system.library.names.index("z1"), 0] == 0
    assert opt.mask_[:, 1:].sum() == (system.true_coefficients()[:, 1:] != 0).sum()


def test_the_library_reports_its_terms_degrees():
    lib = SindyLibrary(Polynomial("z,u", 2), n_state=2, n_control=1)
    degrees = dict(zip(lib.names, lib.degrees.tolist(), strict=True))
    assert degrees["1"] == 0 and degrees["z0"] == 1 and degrees["z0 u0"] == 2
    assert degrees["z1^2"] == 2


@pytest.mark.parametrize("kwargs", [dict(tolerance=-1.0), dict(tolerance=float("nan")),
                                    dict(alpha=-1.0), dict(tolerance=True),
                                    dict(complexity=[1.0, float("inf")])])
def test_bad_settings_are_refused(kwargs):
    with pytest.raises(UserError, match="StepwiseSR"):
        StepwiseSR(**kwargs)


def test_bad_data_is_refused():
    _, theta, target = _circle_data()
    with pytest.raises(ValueError, match="complexity has 3 entries"):
        StepwiseSR(complexity=[1, 2, 3]).fit(theta, target)
    with pytest.raises(ValueError, match="rows"):
        StepwiseSR().fit(theta, target[:10])
    bad = theta.clone()
    bad[0, 0] = float("nan")
    with pytest.raises(ValueError, match="finite"):
        StepwiseSR().fit(bad, target)
    with pytest.raises(ValueError, match="mask"):
        StepwiseSR().fit(theta, target, torch.ones(3, 2, dtype=torch.bool))
