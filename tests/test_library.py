"""The SINDy candidate library: pysindy's terms and names, subset evaluation, gradients."""

from __future__ import annotations

import math

import numpy as np
import pysindy as ps
import pytest
import torch

from latent_sindy.sindy import CandidateLibrary

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
    assert not sub._needs_sin  # no trig features are computed for it
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
