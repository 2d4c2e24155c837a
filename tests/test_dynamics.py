"""Latent dynamics models: one interface, SINDy masking and libraries, the linear model's
closed-form fit (the SINDy fits are in test_fit.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from latent_sindy.models import (
    DYNAMICS_KINDS,
    LatentDynamics,
    LinearDynamics,
    MlpDynamics,
    SindyDynamics,
    make_dynamics,
)
from latent_sindy.sindy import Polynomial, Sine, push_library

NZ, NU = 4, 2

# Every implementation of the interface, the compiled sparse SINDy step included.
MODEL_CASES = [
    *(f"sindy{order}" for order in (1, 2, 3, 4)),
    "sindy2-sparse",
    "sindy-push",
    "linear",
    "mlp",
]


PUSH = push_library(order=2, angle=0, length=1)


def _build(case: str) -> LatentDynamics:
    """A model with non-trivial (random, seeded) parameters, so steps differ from identity."""
    torch.manual_seed(0)
    if case == "sindy-push":  # a composed library: trig of an action times the state
        return SindyDynamics(NZ, NU, library_spec=PUSH, seed=0, init_scale=0.05)
    if case.startswith("sindy"):
        model = SindyDynamics(NZ, NU, order=int(case[5]), seed=0, init_scale=0.05)
        if case.endswith("-sparse"):
            model.threshold(0.04)
            return model.compile_sparse()
        return model
    model = make_dynamics(case, NZ, NU)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.1 * torch.randn_like(p))
    return model


@pytest.fixture(params=MODEL_CASES)
def model(request: pytest.FixtureRequest) -> LatentDynamics:
    return _build(request.param)


def _batch(batch: int = 6, horizon: int = 5, seed: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    z0 = 0.5 * torch.randn(batch, NZ, generator=gen)
    actions = torch.rand(batch, horizon, NU, generator=gen) * 2 - 1
    return z0, actions


# ---------------------------------------------------------------- the common interface


def test_rollout_shape_and_consistency_with_step(model: LatentDynamics) -> None:
    z0, actions = _batch()
    zs = model.rollout(z0, actions)
    assert zs.shape == (6, 6, NZ)
    torch.testing.assert_close(zs[:, 0], z0, rtol=0, atol=0)
    torch.testing.assert_close(zs[:, 1], model.step(z0, actions[:, 0]))
    for t in range(actions.shape[1]):
        torch.testing.assert_close(zs[:, t + 1], model.step(zs[:, t], actions[:, t]))
    assert not torch.allclose(zs[:, 1], z0)  # the model does something


def test_forward_is_step(model: LatentDynamics) -> None:
    z0, actions = _batch()
    torch.testing.assert_close(model(z0, actions[:, 0]), model.step(z0, actions[:, 0]))


def test_step_depends_on_the_action(model: LatentDynamics) -> None:
    # The paper's code left the action out of the library; every model here must use it.
    z0, actions = _batch()
    assert not torch.allclose(model.step(z0, actions[:, 0]), model.step(z0, -actions[:, 0]))


def test_rollout_rejects_mismatched_actions(model: LatentDynamics) -> None:
    z0, actions = _batch()
    with pytest.raises(ValueError, match="rollout expects actions"):
        model.rollout(z0, actions[:, :, :1])
    with pytest.raises(ValueError, match="rollout expects actions"):
        model.rollout(z0, actions[0])


@pytest.mark.parametrize("kind", sorted(DYNAMICS_KINDS))
def test_gradients_reach_every_parameter(kind: str) -> None:
    model = _build("sindy2" if kind == "sindy" else kind)
    z0, actions = _batch()
    model.rollout(z0, actions).square().mean().backward()
    for name, p in model.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name


@pytest.mark.parametrize("kind", sorted(DYNAMICS_KINDS))
def test_factory_rebuilds_from_hparams(kind: str) -> None:
    model = _build("sindy3" if kind == "sindy" else kind)
    assert model.kind == kind
    copy = make_dynamics(model.kind, **model.hparams())
    assert type(copy) is type(model)
    copy.load_state_dict(model.state_dict())
    z0, actions = _batch()
    torch.testing.assert_close(copy.rollout(z0, actions), model.rollout(z0, actions))


def test_factory_names_valid_kinds() -> None:
    with pytest.raises(ValueError, match="linear, mlp, sindy"):
        make_dynamics("e2c", NZ, NU)


def test_seeded_initialisation_is_reproducible() -> None:
    a, b = SindyDynamics(NZ, NU, seed=7), SindyDynamics(NZ, NU, seed=7)
    torch.testing.assert_close(a.psi, b.psi, rtol=0, atol=0)
    assert not torch.equal(a.psi, SindyDynamics(NZ, NU, seed=8).psi)
    assert a.psi.abs().max() < 0.01  # small: the untrained model is close to the identity


def test_linear_starts_near_identity_and_mlp_near_residual_zero() -> None:
    z0, actions = _batch()
    for model in (LinearDynamics(NZ, NU, seed=0), MlpDynamics(NZ, NU)):
        step = model.step(z0, actions[:, 0])
        assert (step - z0).abs().max() < 0.2


# ---------------------------------------------------------------- SINDy mask and pruning


def _hand_set_model() -> SindyDynamics:
    """nz=2, nu=1, order 2: p = 1 + 3 + 6 + 2 = 12 terms; Ψ all 1 except a few test values."""
    model = SindyDynamics(2, 1, order=2)
    names = model.names
    with torch.no_grad():
        model.psi.fill_(1.0)
        model.psi[names.index("z0"), 0] = -0.5
        model.psi[names.index("u0"), 0] = 0.05
        model.psi[names.index("z0 z1"), 0] = -0.05
        model.psi[names.index("1"), 1] = -0.09999
        model.psi[names.index("sin(z1)"), 1] = 0.1  # exactly tau: kept (|Ψ| < tau prunes)
    return model


def test_threshold_compares_magnitudes() -> None:
    model = _hand_set_model()
    names = model.names
    assert model.threshold(0.1) == 3
    pruned = {(names[i], j) for i, j in (~model.mask).nonzero().tolist()}
    assert pruned == {("u0", 0), ("z0 z1", 0), ("1", 1)}
    coef = model.coefficients().detach()
    assert coef[names.index("z0"), 0] == -0.5  # negative and large: survives
    assert float(coef[names.index("sin(z1)"), 1]) == pytest.approx(0.1)
    assert model.psi[~model.mask].abs().max() == 0  # pruned Ψ entries are zeroed
    assert model.n_active() == 24 - 3
    assert model.sparsity() == pytest.approx(3 / 24)


def test_pruned_terms_are_never_revived() -> None:
    model = _hand_set_model()
    model.threshold(0.1)
    mask = model.mask.clone()
    # An optimizer pushes every Ψ entry back up (AdamW momentum, weight decay, a bug...).
    opt = torch.optim.SGD(model.parameters(), lr=1.0)
    model.psi.grad = -torch.ones_like(model.psi)
    opt.step()
    with torch.no_grad():
        model.psi.add_(5.0)
    assert torch.equal(model.mask, mask)
    assert (model.coefficients()[~mask] == 0).all()  # the step does not see them
    assert model.threshold(0.1) == 0  # nothing new to prune, nothing turned back on
    assert model.threshold(100.0) == mask.sum()  # all survivors go; still a one-way mask
    assert model.n_active() == 0 and model.sparsity() == 1.0
    z = torch.randn(5, 2)
    torch.testing.assert_close(model.step(z, torch.randn(5, 1)), z)  # only the identity left


def test_gradient_of_a_pruned_coefficient_is_zero() -> None:
    model = _hand_set_model()
    model.threshold(0.1)
    z, u = torch.randn(8, 2), torch.randn(8, 1)
    (model.step(z, u).square().sum() + model.l1_penalty()).backward()
    assert (model.psi.grad[~model.mask] == 0).all()
    assert (model.psi.grad[model.mask] != 0).any()


def test_l1_penalty_counts_active_coefficients_only() -> None:
    model = _hand_set_model()
    before = model.psi.detach().abs().sum()
    model.threshold(0.1)
    expected = float(before) - 0.05 - 0.05 - 0.09999
    assert model.l1_penalty().item() == pytest.approx(expected)


def test_threshold_rejects_negative_tau() -> None:
    with pytest.raises(ValueError, match="non-negative"):
        SindyDynamics(2, 1).threshold(-0.1)


def test_mask_survives_save_and_load(tmp_path: Path) -> None:
    model = _hand_set_model()
    model.threshold(0.1)
    path = tmp_path / "model.pt"
    torch.save(model.state_dict(), path)

    fresh = SindyDynamics(**model.hparams())
    assert fresh.mask.all()
    state = torch.load(path, weights_only=True)
    assert state["mask"].dtype == torch.bool
    fresh.load_state_dict(state)
    assert torch.equal(fresh.mask, model.mask)

    # The loaded step uses the mask: raising pruned Ψ entries changes nothing.
    z, u = torch.randn(8, 2), torch.randn(8, 1)
    expected = model.step(z, u)
    with torch.no_grad():
        fresh.psi[~fresh.mask] = 3.0
    torch.testing.assert_close(fresh.step(z, u), expected)


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_sparse_fast_path_equals_dense_step(order: int) -> None:
    model = SindyDynamics(16, 3, order=order, seed=order, init_scale=0.1)
    model.threshold(0.18)  # keeps ~7 % of the coefficients, scattered over the terms
    fast = model.compile_sparse()
    active_rows = int(model.mask.any(dim=1).sum())
    assert fast.library.n_terms == active_rows < model.library.n_terms
    assert fast.names == [model.names[i] for i in model.active_terms().tolist()]
    gen = torch.Generator().manual_seed(0)
    z, u = 0.5 * torch.randn(64, 16, generator=gen), torch.rand(64, 3, generator=gen)
    torch.testing.assert_close(fast.step(z, u), model.step(z, u), rtol=1e-5, atol=1e-6)
    # Random order-4 coefficients diverge fast: a short, gentle rollout keeps values finite.
    z, actions = 0.1 * z, 0.2 * torch.rand(64, 2, 3, generator=gen)
    dense = model.rollout(z, actions)
    assert dense.isfinite().all()
    torch.testing.assert_close(fast.rollout(z, actions), dense, rtol=1e-5, atol=1e-5)


def test_sparse_fast_path_is_a_snapshot_and_handles_all_pruned() -> None:
    model = _hand_set_model()
    fast = model.compile_sparse()
    assert fast.library.n_terms == model.library.n_terms  # nothing pruned yet
    model.threshold(10.0)
    z, u = torch.randn(3, 2), torch.randn(3, 1)
    assert not torch.allclose(fast.step(z, u), z)  # the old snapshot is unchanged
    empty = model.compile_sparse()
    assert empty.library.n_terms == 0
    torch.testing.assert_close(empty.step(z, u), z)


def test_equations_and_coefficient_rows() -> None:
    model = SindyDynamics(2, 1, order=2)
    names = model.names
    with torch.no_grad():
        model.psi.zero_()
        model.psi[names.index("u0"), 0] = 0.51234
        model.psi[names.index("z0 z1"), 0] = -0.031249
        model.psi[names.index("1"), 1] = 1.5
        model.psi[names.index("sin(z0)"), 1] = -2.0e-5
    model.threshold(1e-6)
    assert model.equations() == [
        "z0[t+1] = z0 + 0.512 u0 - 0.0312 z0 z1",
        "z1[t+1] = z1 + 1.5 - 2e-05 sin(z0)",
    ]
    assert model.equations(precision=5)[0] == "z0[t+1] = z0 + 0.51234 u0 - 0.031249 z0 z1"
    table = model.coefficient_rows()
    assert [(s, t) for s, t, _ in table] == [
        ("z0", "u0"), ("z0", "z0 z1"), ("z1", "1"), ("z1", "sin(z0)"),
    ]  # fmt: skip
    assert table[0][2] == pytest.approx(0.51234)
    model.threshold(10.0)
    assert model.equations() == ["z0[t+1] = z0", "z1[t+1] = z1"]


# ---------------------------------------------------------------- fits against known answers


def test_linear_least_squares_recovers_the_system() -> None:
    gen = torch.Generator().manual_seed(0)
    A = torch.eye(NZ) + 0.3 * torch.randn(NZ, NZ, generator=gen)
    B = torch.randn(NZ, NU, generator=gen)
    c = torch.randn(NZ, generator=gen)
    Z, U = torch.randn(200, NZ, generator=gen), torch.randn(200, NU, generator=gen)
    Znext = Z @ A.T + U @ B.T + c
    model = LinearDynamics.from_least_squares(Z, U, Znext)
    torch.testing.assert_close(model.A.detach(), A, rtol=0, atol=1e-5)
    torch.testing.assert_close(model.B.detach(), B, rtol=0, atol=1e-5)
    torch.testing.assert_close(model.c.detach(), c, rtol=0, atol=1e-5)
    torch.testing.assert_close(model.step(Z, U), Znext, rtol=0, atol=1e-4)


# ---------------------------------------------------------------- SINDy libraries and coefficients


def test_library_spec_model_rebuilds_from_json_hparams() -> None:
    model = _build("sindy-push")
    assert model.names[-1] == "z3 u1 cos(u0)"
    params = json.loads(json.dumps(model.hparams()))  # JSON-able
    assert "order" not in params and params["library_spec"] == PUSH.to_dict()
    copy = make_dynamics("sindy", **params)
    assert copy.names == model.names
    copy.load_state_dict(model.state_dict())
    z0, actions = _batch()
    torch.testing.assert_close(copy.rollout(z0, actions), model.rollout(z0, actions))
    with pytest.raises(ValueError, match="library_spec and order=3"):
        SindyDynamics(NZ, NU, order=3, library_spec=PUSH)


def test_classic_arguments_build_the_same_model_as_their_spec() -> None:
    spec = Polynomial("z,u", 3) + Sine("z")
    a = SindyDynamics(NZ, NU, order=3, seed=1)
    b = SindyDynamics(NZ, NU, library_spec=spec, seed=1)
    assert a.names == b.names and a.library.spec == spec
    z0, actions = _batch()
    torch.testing.assert_close(a.rollout(z0, actions), b.rollout(z0, actions), rtol=0, atol=0)


def test_set_coefficients_replaces_psi_and_mask() -> None:
    model = _hand_set_model()
    model.threshold(0.5)
    coef = torch.zeros(12, 2, dtype=torch.float64)
    coef[model.names.index("u0"), 0] = 0.25
    coef[model.names.index("z0 z1"), 1] = -1.5
    assert model.set_coefficients(coef) is model
    assert model.n_active() == 2 and model.psi.dtype == torch.float32
    assert model.equations() == ["z0[t+1] = z0 + 0.25 u0", "z1[t+1] = z1 - 1.5 z0 z1"]
    mask = coef != 0
    mask[0, 0] = True  # an active coefficient may be 0
    model.set_coefficients(coef.float() + 1.0, mask)  # entries outside the mask are zeroed
    assert model.n_active() == 3 and int((model.psi != 0).sum()) == 3
    with pytest.raises(ValueError, match="set_coefficients expects"):
        model.set_coefficients(torch.zeros(11, 2))
