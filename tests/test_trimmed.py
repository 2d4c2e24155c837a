"""Trimmed sparse regression: the rows a smooth library cannot explain are left out."""

from __future__ import annotations

import pytest
import torch

from latent_sindy.errors import UserError
from latent_sindy.models import SindyConfig
from latent_sindy.sindy import STLSQ, CandidateLibrary, EnsembleSTLSQ, Trimmed, fit_state_data


def _rail(n: int = 600, seed: int = 0) -> tuple[torch.Tensor, ...]:
    """A damped oscillator with a kick: z' = z + 0.1 (z1, -z0 - 0.2 z1 + u), except where
    |z0| > 1.2, where a wall (not in the library) throws the velocity back."""
    g = torch.Generator().manual_seed(seed)
    Z = torch.rand(n, 2, generator=g, dtype=torch.float64) * 3 - 1.5
    U = torch.rand(n, 1, generator=g, dtype=torch.float64) * 2 - 1
    dz = torch.stack([Z[:, 1], -Z[:, 0] - 0.2 * Z[:, 1] + U[:, 0]], 1) * 0.1
    wall = Z[:, 0].abs() > 1.2
    dz[wall, 1] -= 2.0 * Z[wall, 1] + 3.0 * torch.sign(Z[wall, 0])
    return Z, U, Z + dz, wall


def test_the_rows_a_wall_spoils_are_left_out_and_the_law_is_exact():
    Z, U, Zn, wall = _rail()
    assert 0.1 < wall.double().mean() < 0.25
    lib = CandidateLibrary(2, 1, 2, include_sine=False)
    plain = fit_state_data(lib, Z, U, Zn, STLSQ())
    trimmed = fit_state_data(lib, Z, U, Zn, Trimmed(STLSQ(), share=0.3))
    assert 1 < trimmed.n_rounds_ < 20  # it stopped when the rows left out repeated
    want = torch.zeros(lib.n_terms, 2, dtype=torch.float64)
    name = {n: i for i, n in enumerate(lib.names)}
    want[name["z1"], 0] = 0.1
    want[name["z0"], 1], want[name["z1"], 1], want[name["u0"], 1] = -0.1, -0.02, 0.1
    assert torch.allclose(trimmed.coef_, want, atol=1e-9)
    assert torch.equal(trimmed.mask_, want != 0)
    assert not torch.allclose(plain.coef_, want, atol=1e-3)  # the wall spoils a plain fit
    assert not trimmed.kept_[wall].any()  # every wall row was left out
    assert int(trimmed.kept_.sum()) == 600 - 180


def test_share_zero_is_the_inner_sparsifier_alone():
    Z, U, Zn, _ = _rail(seed=1)
    lib = CandidateLibrary(2, 1, 2, include_sine=False)
    a = fit_state_data(lib, Z, U, Zn, STLSQ())
    b = fit_state_data(lib, Z, U, Zn, Trimmed(STLSQ(), share=0.0))
    assert torch.equal(a.coef_, b.coef_) and bool(b.kept_.all())


def test_it_plugs_in_wherever_a_sparsifier_does():
    Z, U, Zn, wall = _rail(seed=2)
    model = SindyConfig(order=2, include_sine=False).build(2, 1)
    model.fit_state_data(Z.float(), U.float(), Zn.float(), optimizer=Trimmed(share=0.3))
    far = ~wall
    with torch.no_grad():
        pred = model.step(Z[far].float(), U[far].float())
    assert float((pred - Zn[far].float()).abs().max()) < 1e-4
    assert model.n_active() == 4
    lib = CandidateLibrary(2, 1, 2, include_sine=False)
    bagged = Trimmed(EnsembleSTLSQ(seed=0), share=0.3)
    fit_state_data(lib, Z, U, Zn, bagged)
    assert int(bagged.mask_.sum()) == 4 and not bagged.kept_[wall].any()


@pytest.mark.parametrize("kwargs", [{"share": 1.0}, {"share": -0.1}, {"share": True},
                                    {"rounds": 0}, {"inner": "stlsq"}])
def test_bad_settings_are_refused(kwargs):
    with pytest.raises(UserError):
        Trimmed(**kwargs)


def test_rows_of_theta_and_target_must_match():
    with pytest.raises(UserError, match="one library row per target row"):
        Trimmed().fit(torch.ones(5, 3), torch.ones(4, 1))
