"""A law searched with its coordinate's unit and zero (latent_sindy.sindy.unit_search)."""

import numpy as np
import pytest
import torch

from latent_sindy.errors import UserError
from latent_sindy.models.dynamics.continuous import ContinuousSindyConfig
from latent_sindy.sindy.unit_search import search_law


def library_of(nz: int):
    dyn = ContinuousSindyConfig(derivative_order=2, order=3, include_sine=True).build(nz=nz, nu=0)
    lib = dyn.library
    p = lib.n_terms
    sines = [(p - len(lib.trig) + j, var, freq) for j, (var, kind, freq) in enumerate(lib.trig)
             if kind == "sin"]

    def columns(phase):
        with torch.no_grad():
            return lib(torch.as_tensor(phase, dtype=torch.float32),
                       torch.zeros(len(phase), 0)).double().numpy()
    return columns, sines, dyn.names


def samples(rng, n, accel, span=2.8, speed=1.5):
    q = rng.uniform(-span, span, n)
    v = rng.uniform(-speed, speed, n)
    return q, v, accel(q, v)


@pytest.mark.parametrize("unit, zero", [(1.7, 0.2), (0.6, -0.3)])
def test_a_pendulum_read_in_another_unit_and_zero_is_found_with_its_law(unit, zero):
    rng = np.random.default_rng(0)
    law = lambda q, v: -2.3 * np.sin(q) - 0.15 * v  # noqa: E731
    library, sines, names = library_of(1)
    parts = []
    for n in (1200, 600):
        q, v, a = samples(rng, n, law)
        # the coordinate z = q / unit + zero: q = unit (z − zero)
        parts += [np.stack([q / unit + zero, v / unit], 1), (a / unit)[:, None]]
    found = search_law(library, sines, *parts)
    assert found.unit[0] == pytest.approx(unit, rel=1e-3)
    assert found.zero[0] == pytest.approx(zero, abs=1e-3)
    terms = {names[j]: found.coef[j, 0] for j in np.flatnonzero(found.coef[:, 0])}
    assert set(terms) == {"sin(z0)", "z0'"}
    assert terms["sin(z0)"] == pytest.approx(-2.3, rel=1e-3)
    assert terms["z0'"] == pytest.approx(-0.15, rel=1e-2)


def test_a_spring_keeps_its_plain_terms_not_a_sine_of_a_small_unit():
    rng = np.random.default_rng(1)
    library, sines, names = library_of(1)
    parts = []
    for n in (1200, 600):
        q, v, a = samples(rng, n, lambda q, v: -1.4 * q - 0.2 * v, span=1.0, speed=1.0)
        noise = 0.01 * rng.standard_normal(n)
        parts += [np.stack([q, v], 1), (a + noise)[:, None]]
    found = search_law(library, sines, *parts)
    kept = {names[j] for j in np.flatnonzero(found.coef[:, 0])}
    assert kept <= {"1", "z0", "z0'"} and {"z0", "z0'"} <= kept


def test_a_small_term_is_kept_only_where_the_held_out_samples_need_it():
    rng = np.random.default_rng(2)
    library, sines, names = library_of(1)
    for damping, kept in ((0.0, False), (0.05, True)):
        parts = []
        for n in (2000, 1000):
            q, v, a = samples(rng, n, lambda q, v, c=damping: -1.0 * np.sin(q) - c * v)
            parts += [np.stack([q, v], 1), (a + 0.003 * rng.standard_normal(n))[:, None]]
        found = search_law(library, sines, *parts)
        assert bool(found.coef[names.index("z0'"), 0] != 0) is kept
        # each law of one term more was weighed, and the damping's took away most of the error
        weighed = {tuple(names[j] for j in terms): gain for terms, gain in found.gains[0]}
        assert len(found.gains[0]) == 2
        damped = [g for terms, g in weighed.items() if "z0'" in terms and "sin(z0)" in terms]
        if kept:
            assert max(damped) > 0.5


def test_bad_samples_are_refused():
    library, sines, _ = library_of(1)
    with pytest.raises(UserError, match="10 samples"):
        search_law(library, sines, np.zeros((5, 2)), np.zeros((5, 1)), np.zeros((5, 2)),
                   np.zeros((5, 1)))
    bad = np.full((20, 2), np.nan)
    with pytest.raises(UserError, match="NaN"):
        search_law(library, sines, bad, np.zeros((20, 1)), bad, np.zeros((20, 1)))
