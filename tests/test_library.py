"""The SINDy candidate libraries: pysindy's terms and names (polynomial, generalized and
tensored libraries), specs and presets (a world's found by name), derived variables, subset
evaluation, gradients."""

from __future__ import annotations

import functools
import json
import math
import subprocess
import sys
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import pysindy as ps
import pytest
import torch

from latent_sindy.errors import UserError
from latent_sindy.sindy import (
    CandidateLibrary,
    Constant,
    Cosine,
    DerivedVariables,
    Identity,
    LibrarySpec,
    Polynomial,
    Product,
    SindyLibrary,
    Sine,
    Sum,
    library_names,
    library_spec,
    poly_library,
    register_derived,
    spec_from_dict,
)
from latent_sindy.worlds.push.library import (
    FaceFrame,
    face_library,
    face_variables,
    frame_library,
    push_library,
)

ORDERS = [1, 2, 3, 4]
NZ, NU = 3, 2
VAR_NAMES = [f"z{i}" for i in range(NZ)] + [f"u{j}" for j in range(NU)]


def _inputs(batch: int = 17, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    x = torch.randn(batch, NZ + NU, generator=gen, dtype=torch.float64)
    return x[:, :NZ], x[:, NZ:]


@pytest.mark.parametrize("order", ORDERS)
def test_polynomial_part_matches_pysindy(order: int) -> None:
    z, u = _inputs()
    x = torch.cat([z, u], dim=1).numpy()
    ref = ps.PolynomialLibrary(degree=order, include_bias=True).fit(x)
    ref_names = ref.get_feature_names(VAR_NAMES)
    ref_values = ref.transform(x)

    lib = CandidateLibrary(NZ, NU, order)
    n_poly = len(ref_names)
    assert lib.names[:n_poly] == ref_names
    assert lib.n_terms == n_poly + NZ == math.comb(NZ + NU + order, order) + NZ
    np.testing.assert_allclose(lib(z, u)[:, :n_poly].numpy(), ref_values, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("order", ORDERS)
@pytest.mark.parametrize("cosine", [False, True])
def test_trig_terms_follow_the_polynomials(order: int, cosine: bool) -> None:
    z, u = _inputs()
    lib = CandidateLibrary(NZ, NU, order, include_sine=True, include_cosine=cosine)
    n_poly = math.comb(NZ + NU + order, order)
    trig_names = [f"sin(z{i})" for i in range(NZ)]
    trig_values = [torch.sin(z)]
    if cosine:
        trig_names += [f"cos(z{i})" for i in range(NZ)]
        trig_values.append(torch.cos(z))
    assert lib.names[n_poly:] == trig_names
    torch.testing.assert_close(lib(z, u)[:, n_poly:], torch.cat(trig_values, dim=1))


def test_no_trig_terms_when_disabled() -> None:
    lib = CandidateLibrary(NZ, NU, 2, include_sine=False)
    assert lib.n_terms == math.comb(NZ + NU + 2, 2)
    assert not any("(" in name for name in lib.names)


def test_paper_size_library_has_226_terms_with_pysindy_names() -> None:
    lib = CandidateLibrary(16, 3, 2)
    assert lib.n_terms == 226
    assert lib.names[:3] == ["1", "z0", "z1"]
    assert lib.names[-1] == "sin(z15)"
    for name in ("u2", "z0 u2", "z3^2", "u0 u2", "sin(z1)"):
        assert name in lib.names
    z = torch.randn(4, 16)
    u = torch.randn(4, 3)
    theta = lib(z, u)
    assert theta.shape == (4, 226)
    torch.testing.assert_close(theta[:, lib.names.index("z0 u2")], z[:, 0] * u[:, 2])
    torch.testing.assert_close(theta[:, lib.names.index("z3^2")], z[:, 3] ** 2)


def test_pysindy_style_names_for_higher_powers() -> None:
    lib = CandidateLibrary(2, 1, 4)
    for name in ("z0^2 z1", "z0^3 u0", "z1^4", "z0 z1 u0^2"):
        assert name in lib.names


@pytest.mark.parametrize("order", [0, 5, -1, 2.5, True, "2"])
def test_invalid_order_is_a_clear_error(order: object) -> None:
    with pytest.raises(ValueError, match="order must be one of"):
        CandidateLibrary(NZ, NU, order)  # type: ignore[arg-type]


def test_wrong_input_shapes_are_rejected() -> None:
    lib = CandidateLibrary(NZ, NU, 2)
    with pytest.raises(ValueError, match="n_state=3"):
        lib(torch.zeros(4, NZ + 1), torch.zeros(4, NU))
    with pytest.raises(ValueError, match="u of shape"):
        lib(torch.zeros(4, NZ), torch.zeros(4, NU + 1))
    with pytest.raises(ValueError, match="u of shape"):
        lib(torch.zeros(4, NZ), None)


def test_library_without_controls() -> None:
    lib = CandidateLibrary(2, 0, 2)
    assert lib.names == ["1", "z0", "z1", "z0^2", "z0 z1", "z1^2", "sin(z0)", "sin(z1)"]
    z = torch.randn(5, 2)
    torch.testing.assert_close(lib(z), lib(z, torch.zeros(5, 0)))


def test_leading_batch_dimensions_are_kept() -> None:
    lib = CandidateLibrary(NZ, NU, 3)
    z, u = torch.randn(2, 5, NZ), torch.randn(2, 5, NU)
    out = lib(z, u)  # (2, 5, p)
    assert out.shape == (2, 5, lib.n_terms)
    torch.testing.assert_close(out.reshape(10, -1), lib(z.reshape(10, NZ), u.reshape(10, NU)))


@pytest.mark.parametrize("order", ORDERS)
def test_subset_equals_columns_of_full_evaluation(order: int) -> None:
    z, u = _inputs(seed=1)
    lib = CandidateLibrary(NZ, NU, order, include_cosine=True)
    full = lib(z, u)
    gen = torch.Generator().manual_seed(order)
    idx = torch.randint(0, lib.n_terms, (12,), generator=gen).tolist()
    idx += [lib.n_terms - 1, 0, -1, idx[0]]  # last (a cosine), the constant, negative, repeat
    sub = lib.subset(idx)
    assert sub.n_terms == len(idx)
    assert sub.names == [lib.names[i] for i in idx]
    torch.testing.assert_close(sub(z, u), full[:, idx], rtol=0, atol=0)
    torch.testing.assert_close(lib(z, u, terms=idx), full[:, idx], rtol=0, atol=0)
    torch.testing.assert_close(lib(z, u, terms=torch.tensor(idx)), full[:, idx], rtol=0, atol=0)


def test_subset_of_polynomials_only_and_empty_subset() -> None:
    z, u = _inputs()
    lib = CandidateLibrary(NZ, NU, 2)
    sub = lib.subset([3, 1, 7])
    assert sub.trig == ()  # no trig features are computed for it
    torch.testing.assert_close(sub(z, u), lib(z, u)[:, [3, 1, 7]])
    sines = lib.subset([lib.n_terms - 1])  # only sin(z2)
    torch.testing.assert_close(sines(z, u)[:, 0], torch.sin(z[:, 2]))
    assert lib.subset([])(z, u).shape == (z.shape[0], 0)


def test_subset_index_out_of_range() -> None:
    lib = CandidateLibrary(NZ, NU, 1)
    with pytest.raises(ValueError, match="term indices"):
        lib.subset([lib.n_terms])
    with pytest.raises(ValueError, match="term indices"):
        lib(torch.zeros(1, NZ), torch.zeros(1, NU), terms=[-lib.n_terms - 1])


@pytest.mark.parametrize("order", ORDERS)
def test_gradients_pass_gradcheck(order: int) -> None:
    lib = CandidateLibrary(2, 1, order, include_cosine=True)
    gen = torch.Generator().manual_seed(0)
    z = torch.randn(3, 2, generator=gen, dtype=torch.float64, requires_grad=True)
    u = torch.randn(3, 1, generator=gen, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda z, u: lib(z, u), (z, u))
    sub = lib.subset([lib.n_terms - 1, 2, lib.n_terms // 2])
    assert torch.autograd.gradcheck(lambda z, u: sub(z, u), (z, u))


def test_gradient_at_zero_input_is_finite_and_correct() -> None:
    # A product over gathered features must not produce NaN gradients where inputs are 0.
    lib = CandidateLibrary(2, 1, 3)
    z = torch.zeros(1, 2, requires_grad=True)
    u = torch.zeros(1, 1, requires_grad=True)
    lib(z, u).sum().backward()
    # d/dz of sum(terms) at 0: only linear terms and sin contribute (1 + cos 0 = 2 per z).
    torch.testing.assert_close(z.grad, torch.full((1, 2), 2.0))
    torch.testing.assert_close(u.grad, torch.ones(1, 1))


# ---------------------------------------------------------------- composed libraries


def _pysindy_factors(name: str) -> list[str]:
    """pysindy's product name -> our factor names, sorted: 'u1 sin(1 u0) 1' -> [sin(u0), u1]."""
    return sorted(f for f in name.replace("(1 ", "(").split(" ") if f != "1")


def test_classic_library_is_the_poly_spec() -> None:
    for order in ORDERS:
        lib = CandidateLibrary(NZ, NU, order, include_cosine=True)
        assert lib.spec == poly_library(order, include_sine=True, include_cosine=True)
        same = SindyLibrary(lib.spec, NZ, NU)
        assert same.names == lib.names and torch.equal(same.table, lib.table)


@pytest.mark.parametrize("order", ORDERS)
def test_sum_matches_pysindy_generalized_library(order: int) -> None:
    # Monomials of [z, u] + sin of the state + cos of one control.
    z, u = _inputs(seed=2)
    x = torch.cat([z, u], dim=1).numpy()
    ref = ps.GeneralizedLibrary(
        [ps.PolynomialLibrary(order), ps.FourierLibrary(1, include_cos=False),
         ps.FourierLibrary(1, include_sin=False)],
        inputs_per_library=[list(range(NZ + NU)), list(range(NZ)), [NZ + 1]],
    ).fit(x)  # fmt: skip
    lib = SindyLibrary(Polynomial("z,u", order) + Sine("z") + Cosine("u1"), NZ, NU)
    assert lib.names == [n.replace("(1 ", "(") for n in ref.get_feature_names(VAR_NAMES)]
    np.testing.assert_allclose(lib(z, u).numpy(), ref.transform(x), rtol=1e-12, atol=1e-12)


def test_product_matches_pysindy_tensored_library() -> None:
    # The push geometry: u1 * (sin u0, cos u0) * (1, z0, z1, z2).
    z, u = _inputs(seed=3)
    x = torch.cat([z, u], dim=1).numpy()
    ref = ps.TensoredLibrary(
        [ps.PolynomialLibrary(1, include_bias=False), ps.FourierLibrary(1),
         ps.PolynomialLibrary(1)],
        inputs_per_library=[[NZ + 1], [NZ], list(range(NZ))],
    ).fit(x)  # fmt: skip
    spec = Identity("u1") * (Sine("u0") + Cosine("u0")) * Polynomial("z", 1)
    lib = SindyLibrary(spec, NZ, NU)
    ref_names = ref.get_feature_names(VAR_NAMES)
    assert [sorted(n.split(" ")) for n in lib.names] == [_pysindy_factors(n) for n in ref_names]
    assert lib.names[:2] == ["u1 sin(u0)", "z0 u1 sin(u0)"]  # monomial factors, then trig
    np.testing.assert_allclose(lib(z, u).numpy(), ref.transform(x), rtol=1e-12, atol=1e-12)


def test_product_of_sums_by_hand() -> None:
    z, u = _inputs(seed=4)
    spec = (Identity("z0") + Sine("u1")) * (Identity("z0") + Cosine("z2")) + Sine("z1") * Sine("z1")
    lib = SindyLibrary(spec, NZ, NU)
    assert lib.names == [
        "z0^2", "z0 cos(z2)", "z0 sin(u1)", "cos(z2) sin(u1)", "sin(z1)^2",
    ]  # fmt: skip
    want = torch.stack(
        [z[:, 0] ** 2, z[:, 0] * torch.cos(z[:, 2]), z[:, 0] * torch.sin(u[:, 1]),
         torch.sin(u[:, 1]) * torch.cos(z[:, 2]), torch.sin(z[:, 1]) ** 2],
        dim=1,
    )  # fmt: skip
    torch.testing.assert_close(lib(z, u), want, rtol=1e-12, atol=1e-12)
    # F's trig columns: only those some term uses, sines first, each by variable.
    assert lib.trig == ((1, "sin", 1.0), (NZ + 1, "sin", 1.0), (2, "cos", 1.0))


def test_plus_and_times_flatten_and_modules_combine() -> None:
    a, b, c = Polynomial("z", 2), Sine("u"), Cosine("u0")
    assert a + b + c == Sum((a, b, c)) == a + (b + c)
    assert a * b * c == Product((a, b, c)) == a * (b * c)
    z, u = _inputs(seed=5)
    la, lb = SindyLibrary(a, NZ, NU), SindyLibrary(b, NZ, NU)
    assert (la + lb).names == SindyLibrary(a + b, NZ, NU).names
    torch.testing.assert_close((la * lb)(z, u), SindyLibrary(a * b, NZ, NU)(z, u))
    with pytest.raises(ValueError, match="sizes"):
        la + SindyLibrary(b, NZ, NU + 1)


def test_spec_round_trips_through_json() -> None:
    spec = push_library(order=3, angle=0, length=1) + Sine("u0,z1") * Polynomial("z", 1, False)
    text = json.dumps(spec.to_dict())
    back = spec_from_dict(json.loads(text))
    assert back == spec
    assert SindyLibrary(json.loads(text), NZ, NU).names == SindyLibrary(spec, NZ, NU).names
    assert str(Polynomial("z,u", 2) + Sine("z")) == "poly(z,u; 2) + sin(z)"


def test_the_push_library_adds_the_push_geometry() -> None:
    nz, nu = 4, 3
    lib = SindyLibrary(library_spec("push", order=2), nz, nu)
    classic = CandidateLibrary(nz, nu, 2)
    assert lib.names[: classic.n_terms] == classic.names
    extra = lib.names[classic.n_terms :]
    assert len(extra) == 2 * (nz + 1)
    assert extra[:2] == ["u2 sin(u1)", "z0 u2 sin(u1)"] and extra[-1] == "z3 u2 cos(u1)"
    gen = torch.Generator().manual_seed(6)
    z, u = torch.randn(9, nz, generator=gen), torch.randn(9, nu, generator=gen)
    theta = lib(z, u)
    torch.testing.assert_close(
        theta[:, lib.names.index("z3 u2 sin(u1)")], z[:, 3] * u[:, 2] * torch.sin(u[:, 1])
    )
    torch.testing.assert_close(
        theta[:, lib.names.index("u2 cos(u1)")], u[:, 2] * torch.cos(u[:, 1])
    )
    assert set(library_names()) >= {"poly", "push", "face", "frame"}
    assert library_spec("poly", order=3) == poly_library(3)


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: SindyLibrary(Polynomial("z", 2) + Identity("z1"), NZ, NU), "twice"),
        (lambda: SindyLibrary(Sine("u7"), NZ, NU), "n_control > 7"),
        (lambda: Sine("x0"), "not valid"),
        (lambda: Polynomial("z", 0), "degree"),
        (lambda: Sum(()), "non-empty"),
        (lambda: spec_from_dict({"kind": "exp", "variables": ["z"]}), "unknown"),
        (lambda: spec_from_dict({"kind": "sin", "variables": ["z"], "degree": 2}), "unknown"),
        (lambda: library_spec("fourier"), "unknown"),
        (lambda: push_library(angle=2, length=2), "different"),
        (lambda: library_spec("poly", options=("degree=2",)), "unknown settings"),
        (lambda: library_spec("face", order=2), "takes order 1"),
        (lambda: library_spec("frame", order=1, options={"degree": 7}), "degree=7"),
    ],
)
def test_bad_specs_are_user_errors(make, match: str) -> None:
    with pytest.raises(UserError, match=match):
        make()


def _mixed_library(order: int) -> SindyLibrary:
    """Trig of states and of controls, products of trig with monomials."""
    spec = (
        poly_library(order, include_sine=True, include_cosine=True)
        + Sine("u")
        + Identity("u1") * Cosine("u0") * Polynomial("z", 1)
    )
    return SindyLibrary(spec, NZ, NU)


@pytest.mark.parametrize("order", ORDERS)
def test_subset_of_a_mixed_library_equals_its_columns(order: int) -> None:
    z, u = _inputs(seed=7)
    lib = _mixed_library(order)
    full = lib(z, u)
    gen = torch.Generator().manual_seed(order)
    idx = [*torch.randint(0, lib.n_terms, (15,), generator=gen).tolist(), -1, -NZ - 2, 0]
    sub = lib.subset(idx)
    assert sub.names == [lib.names[i] for i in idx]
    assert len(sub.trig) <= len(lib.trig) and set(sub.trig) <= set(lib.trig)
    torch.testing.assert_close(sub(z, u), full[:, idx], rtol=0, atol=0)
    only_u = lib.subset([lib.names.index("z2 u1 cos(u0)")])
    assert only_u.trig == ((NZ, "cos", 1.0),)
    torch.testing.assert_close(only_u(z, u)[:, 0], z[:, 2] * u[:, 1] * torch.cos(u[:, 0]))


@pytest.mark.parametrize("order", [1, 3])
def test_gradients_of_a_mixed_library_pass_gradcheck(order: int) -> None:
    lib = _mixed_library(order)
    gen = torch.Generator().manual_seed(1)
    z = torch.randn(3, NZ, generator=gen, dtype=torch.float64, requires_grad=True)
    u = torch.randn(3, NU, generator=gen, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda z, u: lib(z, u), (z, u))
    sub = lib.subset([lib.n_terms - 1, NZ + NU + 2, 3])
    assert torch.autograd.gradcheck(lambda z, u: sub(z, u), (z, u))


# ---------------------------------------------------------------- frequencies, face library


def test_trig_at_a_frequency_is_named_evaluated_and_serialised() -> None:
    spec = Identity("z0") * Sine("u1", frequency=4) + Cosine("z1", frequency=0.5) + Sine("u1")
    lib = SindyLibrary(spec, 2, 2)
    assert lib.names == ["z0 sin(4 u1)", "cos(0.5 z1)", "sin(u1)"]
    z, u = torch.randn(6, 2), torch.randn(6, 2)
    want = torch.stack([z[:, 0] * torch.sin(4 * u[:, 1]), torch.cos(0.5 * z[:, 1]),
                        torch.sin(u[:, 1])], -1)
    torch.testing.assert_close(lib(z, u), want)
    assert spec_from_dict(json.loads(json.dumps(spec.to_dict()))) == spec
    # a record written before frequencies existed has none: frequency 1
    assert spec_from_dict({"kind": "sin", "variables": ["u1"]}) == Sine("u1")


@pytest.mark.parametrize("bad", [0, -1, float("nan"), float("inf"), True, "4"])
def test_a_bad_trig_frequency_is_refused(bad) -> None:
    with pytest.raises(UserError, match="frequency"):
        Sine("u1", frequency=bad)


def test_a_product_met_again_is_kept_once_where_it_first_appears() -> None:
    lib = SindyLibrary(Identity("z0,z1") * Identity("z0,z1"), 2, 0)
    assert lib.names == ["z0^2", "z0 z1", "z1^2"]
    lib = SindyLibrary((Constant() + Identity("z1")) * Polynomial("z0", 1, bias=False), 2, 0)
    assert lib.names == ["z0", "z0 z1"]


def test_the_face_library_spans_the_push_relative_to_the_pushed_face() -> None:
    # A state (x, y, cos 4θ, sin 4θ) and a push [p, ψ, ℓ]: what a push on a face of a square
    # does depends on ψ - θ modulo π/2, which the library reaches through sin(4 u1), cos(4 u1)
    # times the orientation features. Functions of that relative angle must lie exactly in
    # its span; one of the absolute angle θ must not.
    gen = torch.Generator().manual_seed(3)
    n = 400
    theta = (torch.rand(n, generator=gen, dtype=torch.float64) - 0.5) * 2 * math.pi
    psi = (torch.rand(n, generator=gen, dtype=torch.float64) - 0.5) * 2 * math.pi
    p, ell = torch.rand(n, 2, generator=gen, dtype=torch.float64).unbind(-1)
    xy = torch.rand(n, 2, generator=gen, dtype=torch.float64)
    z = torch.cat([xy, torch.cos(4 * theta)[:, None], torch.sin(4 * theta)[:, None]], -1)
    u = torch.stack([p, psi, ell], -1)
    lib = SindyLibrary(face_library(), 4, 3)
    theta_lib = lib(z, u)
    rel = 4 * (psi - theta)

    def residual(target: torch.Tensor) -> float:
        sol = torch.linalg.lstsq(theta_lib, target[:, None]).solution
        return float((theta_lib @ sol - target[:, None]).abs().max())

    # a turn Δc = -s·g, Δs = c·g with g = ℓ (a + b p + c p²)(1 + sin 4(ψ-θ))
    g = ell * (0.3 + p - 0.5 * p**2) * (1 + torch.sin(rel) - 0.2 * torch.cos(rel))
    assert residual(-z[:, 3] * g) < 1e-9 and residual(z[:, 2] * g) < 1e-9
    # a translation along the push bent by the contact: ℓ cos ψ (1 + p sin 4(ψ-θ))
    assert residual(ell * torch.cos(psi) * (1 + p * torch.sin(rel))) < 1e-9
    assert residual(ell * torch.cos(theta)) > 0.1  # the absolute angle is not in it
    names = set(lib.names)
    assert {"u2 sin(u1)", "z2 u2", "z2^2 u0^2 u2 cos(4 u1)", "z3 u0 u2 sin(u1) sin(4 u1)"} <= names


def test_the_face_library_refuses_repeated_action_indices() -> None:
    with pytest.raises(UserError, match="different action indices"):
        face_library(offset=1, angle=1)


def test_frequencies_that_print_alike_are_refused() -> None:
    with pytest.raises(UserError, match="twice"):
        SindyLibrary(Sine("z0", frequency=4) + Sine("z0", frequency=4.0000001), 1, 0)


def _poses_and_pushes(n: int, seed: int) -> tuple[torch.Tensor, ...]:
    gen = torch.Generator().manual_seed(seed)
    theta = (torch.rand(n, generator=gen, dtype=torch.float64) - 0.5) * 2 * math.pi
    psi = (torch.rand(n, generator=gen, dtype=torch.float64) - 0.5) * 2 * math.pi
    p = torch.rand(n, generator=gen, dtype=torch.float64) * 2 - 1
    ell = torch.rand(n, generator=gen, dtype=torch.float64)
    return theta, psi, p, ell


def test_the_face_variables_are_the_angle_from_the_nearest_face_normal() -> None:
    theta, psi, *_ = _poses_and_pushes(500, seed=1)
    c, s = torch.cos(4 * theta), torch.sin(4 * theta)
    a, n = face_variables(psi, c, s, (0, 0, 0, 4.0, 1, 0.0))
    assert bool((a >= -math.pi / 4).all() and (a < math.pi / 4).all())
    # n is one of the block's four face normals θ + kπ/2 ...
    k = (n - theta) / (math.pi / 2)
    torch.testing.assert_close(k, k.round(), rtol=0, atol=1e-9)
    # ... the one nearest the push direction
    normals = theta[:, None] + torch.arange(4, dtype=torch.float64) * math.pi / 2
    gap = torch.remainder(psi[:, None] - normals + math.pi, 2 * math.pi) - math.pi
    torch.testing.assert_close(a, gap.gather(1, gap.abs().argmin(1, keepdim=True))[:, 0])
    # features read in a mirrored frame about another reference: sense -1 and an offset
    mirrored = math.pi - 4 * theta
    a2, n2 = face_variables(psi, torch.cos(mirrored), torch.sin(mirrored),
                            (0, 0, 0, 4.0, -1, math.pi))
    torch.testing.assert_close(a2, a, rtol=0, atol=1e-9)
    torch.testing.assert_close(n2, n, rtol=0, atol=1e-9)


def test_the_frame_library_writes_a_push_along_the_face_normal_exactly() -> None:
    # A block pushed on a face slides along that face's normal n and turns, by amounts set
    # by the contact offset p and the angle a from the normal: polynomials of (p, a) times
    # ℓ cos n, ℓ sin n (and the orientation features for the turn) lie in the frame
    # library's span exactly; in the face library's (harmonics of 4(ψ - θ)) they do not.
    theta, psi, p, ell = _poses_and_pushes(600, seed=2)
    z = torch.stack([torch.rand_like(p), torch.rand_like(p), torch.cos(4 * theta),
                     torch.sin(4 * theta)], -1)
    u = torch.stack([p, psi, ell], -1)
    a, n = face_variables(psi, z[:, 2], z[:, 3], (0, 0, 0, 4.0, 1, 0.0))
    along = ell * (1.0 - 0.3 * p**2 - 0.5 * a**2)
    across = ell * (0.4 * a - 0.8 * p * a**2)
    dx = along * torch.cos(n) - across * torch.sin(n)
    turn = ell * (-0.8 * p + 1.5 * a - 1.7 * a**3)

    def residual(lib: SindyLibrary, target: torch.Tensor) -> float:
        theta_lib = lib(z, u)
        sol = torch.linalg.lstsq(theta_lib, target[:, None]).solution
        return float((theta_lib @ sol - target[:, None]).abs().max())

    frame, face = SindyLibrary(frame_library(), 4, 3), SindyLibrary(face_library(), 4, 3)
    assert residual(frame, dx) < 1e-9 and residual(frame, -z[:, 3] * turn) < 1e-9
    assert residual(face, dx) > 1e-2
    assert frame.n_terms == 8 + 9 + 4 * 10 and "u0 u2 a cos(n)" in frame.names
    assert residual(frame, turn) < 1e-9  # the turn itself, for a model that turns by it


def test_a_face_frame_round_trips_and_prints_its_definition() -> None:
    spec = frame_library(sense=-1, angle_offset=math.pi, degree=2)
    again = spec_from_dict(json.loads(json.dumps(spec.to_dict())))
    assert again == spec
    assert SindyLibrary(again, 4, 3).names == SindyLibrary(spec, 4, 3).names
    assert "a = u1 - (-atan2(z3, z2) + 3.142) / 4" in str(spec)


def test_face_variables_need_a_face_frame_and_one_definition() -> None:
    with pytest.raises(UserError, match="wrap the library in FaceFrame"):
        SindyLibrary(Identity("u2") * Cosine("n"), 4, 3)
    with pytest.raises(UserError, match="twice"):
        SindyLibrary(FaceFrame(Identity("a")) + FaceFrame(Identity("n"), frequency=2), 4, 3)
    with pytest.raises(UserError, match="name one action"):
        FaceFrame(Identity("a"), angle="z1")
    with pytest.raises(UserError, match="sense"):
        FaceFrame(Identity("a"), sense=2)
    with pytest.raises(UserError, match="n_state"):  # the orientation beyond the state
        SindyLibrary(FaceFrame(Identity("a"), orientation=("z4", "z5")), 4, 3)


# ---------------------------------------------------------------- worlds' presets and nodes


@pytest.mark.parametrize("load", [
    "library_spec('frame', order=1, include_sine=False)",
    "spec_from_dict(json.loads(json.dumps(FRAME)))",
])
def test_a_world_library_loads_by_name_without_importing_the_world(load: str) -> None:
    # A run folder or a command line names the world's preset or stores its node's dict; the
    # core finds the world through its plug-in entry point.
    code = (
        "import json, sys\n"
        "from latent_sindy.sindy import SindyLibrary, library_spec, spec_from_dict\n"
        "assert not [m for m in sys.modules if m.startswith('latent_sindy.worlds')]\n"
        f"FRAME = {frame_library().to_dict()!r}\n"
        f"spec = {load}\n"
        "assert type(spec).__module__ == 'latent_sindy.worlds.push.library', type(spec)\n"
        "assert 'u2 cos(n)' in SindyLibrary(spec, 4, 3).names\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_an_unknown_library_lists_the_worlds_libraries() -> None:
    with pytest.raises(UserError, match=r"unknown: use one of poly.*frame"):
        library_spec("fourier")
    with pytest.raises(UserError, match="rho"):  # the registered derived variables
        Sine("zz")


@dataclass(frozen=True)
class _Hypot(DerivedVariables):
    """A toy derived variable for the generic mechanism: rho = scale · |(x, y)|."""

    kind: ClassVar[str] = "test_hypot"
    names: ClassVar[tuple[str, ...]] = ("rho",)
    body: LibrarySpec
    of: tuple[str, str] = ("z0", "u1")
    scale: float = 1.0
    numba: bool = True

    def inputs(self) -> tuple[str, ...]:
        return self.of

    def evaluate(self, x: torch.Tensor, y: torch.Tensor) -> tuple[torch.Tensor]:
        return (self.scale * torch.sqrt(x * x + y * y),)

    def numba_parameters(self) -> tuple[float, ...]:
        return (self.scale,)

    def numba_function(self, dtype: str) -> Any:
        return _hypot_cfunc(dtype) if self.numba else None


register_derived(_Hypot)


@functools.cache
def _hypot_cfunc(dtype: str) -> Any:
    import numba

    from latent_sindy.control.derived import CFUNC_FLAGS, derived_signature

    def hypot(feat, rows, block, n, inputs, n_inputs, params, n_params, first):
        f = numba.carray(feat, (rows, block))
        x, y = numba.carray(inputs, (n_inputs,))[0], numba.carray(inputs, (n_inputs,))[1]
        scale = numba.carray(params, (n_params,))[0]
        for k in range(n):
            f[first, k] = scale * np.sqrt(f[x, k] * f[x, k] + f[y, k] * f[y, k])

    return numba.cfunc(derived_signature(dtype), **{**CFUNC_FLAGS, "cache": False})(hypot)


def test_a_derived_variable_is_named_evaluated_and_serialised() -> None:
    spec = _Hypot(Identity("rho") * Polynomial("z1", 1) + Sine("rho", frequency=2), scale=0.5)
    lib = SindyLibrary(spec, 2, 2)
    assert lib.names == ["rho", "z1 rho", "sin(2 rho)"]
    z, u = _inputs()[0][:, :2], _inputs()[1]
    rho = 0.5 * torch.sqrt(z[:, 0] ** 2 + u[:, 1] ** 2)
    want = torch.stack([rho, z[:, 1] * rho, torch.sin(2 * rho)], -1)
    torch.testing.assert_close(lib(z, u), want, rtol=0, atol=0)
    assert spec_from_dict(json.loads(json.dumps(spec.to_dict()))) == spec
    with pytest.raises(UserError, match=r"wrap the library in _Hypot"):
        SindyLibrary(Identity("rho"), 2, 2)
    with pytest.raises(UserError, match="names 2 variables"):
        SindyLibrary(_Hypot(Identity("rho"), of=("z", "u1")), 2, 2)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("numba_function", [True, False])
def test_the_control_kernel_computes_derived_variables_as_the_library(dtype,
                                                                      numba_function) -> None:
    # The fused CPU step calls the node's numba function for its derived variables (also as
    # arguments of trig terms); a node without one is stepped in torch.
    from latent_sindy.control.sindy_step import SindyKernelStep
    from latent_sindy.models import SindyDynamics

    spec = _Hypot(Polynomial("z,u", 2) + Identity("rho") * Polynomial("z", 1)
                  + Identity("u0") * Cosine("rho"), of=("z1", "u1"), scale=0.7,
                  numba=numba_function)
    model = SindyDynamics(3, 2, library_spec=spec, seed=1, init_scale=0.05).to(dtype)
    model.prune(0.02)
    step = SindyKernelStep(model)
    assert step._torch_only is not numba_function
    assert {"rho", "z2 rho", "u0 cos(rho)"} <= set(step._sparse.names)
    gen = torch.Generator().manual_seed(2)
    z0 = torch.randn(600, 3, generator=gen, dtype=dtype)
    actions = torch.randn(600, 5, 2, generator=gen, dtype=dtype)
    with torch.no_grad():
        want = model.rollout(z0, actions)
    tol = 1e-4 if dtype == torch.float32 else 1e-9
    torch.testing.assert_close(step.rollout(z0, actions), want, rtol=tol, atol=tol)
