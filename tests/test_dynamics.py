"""Latent dynamics models: one interface, SINDy masking and libraries, the linear model's
closed-form fit (the SINDy fits are in test_fit.py), and the unit circle that a pose latent's
angle features are kept on."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch

from latent_sindy.models import (
    DYNAMICS_KINDS,
    AutoencoderConfig,
    LatentDynamics,
    LatentModel,
    LinearConfig,
    LinearDynamics,
    MlpConfig,
    MlpDynamics,
    ModelConfig,
    SindyConfig,
    SindyDynamics,
    SparseDynamics,
    StateConfig,
    make_dynamics,
)
from latent_sindy.models.dynamics import project_circle
from latent_sindy.sindy import Polynomial, Sine
from latent_sindy.worlds.push.library import push_library

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
            model.prune(0.04)
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


def test_prune_compares_magnitudes() -> None:
    model = _hand_set_model()
    names = model.names
    assert model.prune(0.1) == 3
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
    model.prune(0.1)
    mask = model.mask.clone()
    # An optimizer pushes every Ψ entry back up (AdamW momentum, weight decay, a bug...).
    opt = torch.optim.SGD(model.parameters(), lr=1.0)
    model.psi.grad = -torch.ones_like(model.psi)
    opt.step()
    with torch.no_grad():
        model.psi.add_(5.0)
    assert torch.equal(model.mask, mask)
    assert (model.coefficients()[~mask] == 0).all()  # the step does not see them
    assert model.prune(0.1) == 0  # nothing new to prune, nothing turned back on
    assert model.prune(100.0) == mask.sum()  # all survivors go; still a one-way mask
    assert model.n_active() == 0 and model.sparsity() == 1.0
    z = torch.randn(5, 2)
    torch.testing.assert_close(model.step(z, torch.randn(5, 1)), z)  # only the identity left


def test_gradient_of_a_pruned_coefficient_is_zero() -> None:
    model = _hand_set_model()
    model.prune(0.1)
    z, u = torch.randn(8, 2), torch.randn(8, 1)
    (model.step(z, u).square().sum() + model.l1_penalty()).backward()
    assert (model.psi.grad[~model.mask] == 0).all()
    assert (model.psi.grad[model.mask] != 0).any()


def test_l1_penalty_counts_active_coefficients_only() -> None:
    model = _hand_set_model()
    before = model.psi.detach().abs().sum()
    model.prune(0.1)
    expected = float(before) - 0.05 - 0.05 - 0.09999
    assert model.l1_penalty().item() == pytest.approx(expected)


def test_prune_rejects_negative_tau() -> None:
    with pytest.raises(ValueError, match="non-negative"):
        SindyDynamics(2, 1).prune(-0.1)


def test_mask_survives_save_and_load(tmp_path: Path) -> None:
    model = _hand_set_model()
    model.prune(0.1)
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
    model.prune(0.18)  # keeps ~7 % of the coefficients, scattered over the terms
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
    model.prune(10.0)
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
    model.prune(1e-6)
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
    model.prune(10.0)
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
    model.prune(0.5)
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


# ---------------------------------------------------------------- the unit circle of a pose latent

CIRCLE_CASES = ["sindy2", "sindy2-sparse", "sindy-push", "linear", "mlp"]


def _with_circle(case: str, circle: tuple[int, int] | None) -> LatentDynamics:
    """The model of ``_build(case)`` (same parameters) built with ``circle``."""
    if case.endswith("-sparse"):
        dense = _with_circle(case.removesuffix("-sparse"), circle)
        dense.prune(0.04)  # as _build does
        return dense.compile_sparse()
    model = _build(case)
    copy = make_dynamics(model.kind, **model.hparams(), circle=circle)
    copy.load_state_dict(model.state_dict())
    return copy


def _on_circle(batch: int, horizon: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """z0 (batch, 4) with (z2, z3) on the unit circle, random actions (batch, horizon, NU)."""
    gen = torch.Generator().manual_seed(seed)
    angle = 2 * torch.pi * torch.rand(batch, generator=gen)
    z0 = torch.stack([0.3 * torch.randn(batch, generator=gen), 0.3 * torch.randn(batch,
                      generator=gen), angle.cos(), angle.sin()], -1)
    return z0, torch.rand(batch, horizon, NU, generator=gen) * 2 - 1


@pytest.mark.parametrize("case", CIRCLE_CASES)
def test_a_circle_keeps_the_angle_pair_on_it_and_leaves_the_rest(case: str) -> None:
    """50 steps of random pushes: every predicted (z2, z3) has norm 1 and each step is the
    unprojected step with that pair divided by its norm; the same model without a circle
    steps off it (so the projection is what keeps it there) and is its own update exactly."""
    projected, free = _with_circle(case, (2, 3)), _with_circle(case, None)
    assert projected.circle == (2, 3) and free.circle is None
    z0, actions = _on_circle(32, 50, seed=3)
    with torch.no_grad():
        zs = projected.rollout(z0, actions)  # (32, 51, 4)
        norms = zs[:, 1:, 2:].norm(dim=-1)
        torch.testing.assert_close(norms, torch.ones_like(norms), rtol=0, atol=1e-6)
        for t in (0, 17, 49):
            raw = free.step(zs[:, t], actions[:, t])
            want = torch.cat([raw[:, :2], raw[:, 2:] / raw[:, 2:].norm(dim=-1, keepdim=True)], 1)
            torch.testing.assert_close(zs[:, t + 1], want, rtol=1e-6, atol=1e-6)
            torch.testing.assert_close(zs[:, t + 1, :2], raw[:, :2], rtol=0, atol=0)
        off = (free.step(z0, actions[:, 0])[:, 2:].norm(dim=-1) - 1).abs().max()
        assert off > 1e-3, float(off)
        short = actions[:, :8]  # the unprojected random models diverge over 50 steps
        z, chained = z0, [z0]
        for t in range(short.shape[1]):  # the unprojected computation, bit for bit
            z = free._step(z, short[:, t])
            chained.append(z)
        assert torch.stack(chained, 1).isfinite().all()
        assert torch.equal(free.rollout(z0, short), torch.stack(chained, 1))


def test_the_projection_is_differentiable_and_leaves_the_origin_finite() -> None:
    index = torch.tensor([2, 0])
    z = torch.randn(5, 4, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda v: project_circle(v, index), (z,))
    out = project_circle(torch.zeros(1, 4), index)
    assert torch.equal(out, torch.zeros(1, 4))  # no block seen (moments: (0, 0)) stays 0
    nan = project_circle(torch.tensor([[1.0, 0.0, math.nan, 1.0]]), index)
    assert nan[0, 0].isnan() and nan[0, 2].isnan() and nan[0, 1] == 0 and nan[0, 3] == 1


@pytest.mark.parametrize("case", ["sindy2", "linear", "mlp"])
def test_gradients_flow_through_the_projection(case: str) -> None:
    model = _with_circle(case, (2, 3))
    z0, actions = _on_circle(6, 5, seed=4)
    target = torch.randn(6, 6, NZ, generator=torch.Generator().manual_seed(5))
    (model.rollout(z0, actions) - target).square().mean().backward()
    for name, p in model.named_parameters():
        assert p.grad is not None and p.grad.isfinite().all(), name
        assert p.grad.abs().sum() > 0, name


@pytest.mark.parametrize("kind", sorted(DYNAMICS_KINDS))
def test_the_circle_is_part_of_the_rebuilt_model(kind: str) -> None:
    """hparams (through JSON) and compile_sparse keep the circle; the state dict has no
    entry for it, so checkpoints of models with and without one load alike."""
    model = _with_circle("sindy2" if kind == "sindy" else kind, (3, 1))
    params = json.loads(json.dumps(model.hparams()))
    assert params["circle"] == [3, 1]
    copy = make_dynamics(kind, **params)
    assert copy.circle == (3, 1)
    assert set(copy.state_dict()) == set(make_dynamics(kind, NZ, NU).state_dict())
    copy.load_state_dict(model.state_dict())
    z0, actions = _batch()
    with torch.no_grad():
        torch.testing.assert_close(copy.rollout(z0, actions), model.rollout(z0, actions))
    assert "circle" not in make_dynamics(kind, NZ, NU).hparams()
    if kind == "sindy":
        fast = model.compile_sparse()
        assert fast.circle == (3, 1)
        with torch.no_grad():
            torch.testing.assert_close(fast.rollout(z0, actions), model.rollout(z0, actions))
        assert model.summary()[-1] == "after every step (z3, z1) is scaled onto the unit circle"


@pytest.mark.parametrize("circle", [(2, 2), (1, 4), (-1, 2), (1, 2, 3)])
def test_a_bad_circle_is_one_line(circle) -> None:
    with pytest.raises(ValueError, match=r"circle .*: give two different latent coordinates in "
                                         r"0\.\.3"):
        SindyDynamics(NZ, NU, circle=circle)


FACE = SindyConfig(order=1, library="face", include_sine=False, init_scale=0.05)
POSE_MODELS = {  # name: (config, whether its latent is a pose)
    "state face": (ModelConfig(dynamics=FACE, observation=StateConfig()), True),
    "state mlp": (ModelConfig(dynamics=MlpConfig(hidden=16), observation=StateConfig()), True),
    "moments": (ModelConfig(dynamics=FACE, observation=AutoencoderConfig(
        encoder_kind="moments", latent_dim=4)), True),
    "coordinates": (ModelConfig(dynamics=LinearConfig(init_scale=0.05), pose_head="coordinates",
                                observation=AutoencoderConfig(latent_dim=6)), True),
    "linear head": (ModelConfig(dynamics=SindyConfig(order=1, init_scale=0.05),
                                pose_head="linear", observation=AutoencoderConfig(latent_dim=6)),
                    False),
    "conv": (ModelConfig(dynamics=SindyConfig(order=1, init_scale=0.05),
                         observation=AutoencoderConfig(latent_dim=6)), False),
}


@pytest.mark.parametrize("name", sorted(POSE_MODELS))
def test_a_pose_latent_model_rolls_out_on_the_circle(name: str) -> None:
    """The circle follows from the model's config: a pose latent (state, moments, coordinates
    head) projects (z2, z3) over 50 random pushes, in rollouts and in the loss; any other
    latent's rollout is the dynamics' own update, bit for bit."""
    cfg, pose = POSE_MODELS[name]
    torch.manual_seed(0)
    model = LatentModel(cfg.resolve(1, 32, 3))
    assert cfg.pose_latent is pose
    assert model.dynamics.circle == ((2, 3) if pose else None)
    nz = cfg.observation.latent_dim
    gen = torch.Generator().manual_seed(1)
    z0 = torch.randn(16, nz, generator=gen)
    u = torch.rand(16, 50, 3, generator=gen) * 2 - 1
    with torch.no_grad():
        zs = model.rollout_latent(z0, u)  # (16, 51, nz)
        raw = model.dynamics._step(z0, u[:, 0])
        norms = zs[:, 1:, 2:4].norm(dim=-1)
        if pose:
            torch.testing.assert_close(norms, torch.ones_like(norms), rtol=0, atol=1e-5)
            assert (raw[:, 2:4].norm(dim=-1) - 1).abs().max() > 1e-3  # unprojected: off it
        else:
            chained = [z0]
            for t in range(u.shape[1]):
                chained.append(model.dynamics._step(chained[-1], u[:, t]))
            assert torch.equal(zs, torch.stack(chained, 1))
    if name.startswith("state"):
        # Observations that follow the projected rollout exactly: no prediction error, so
        # the loss steps through the same projected dynamics.
        x = zs[:, :6]
        with torch.no_grad():
            assert float(model.loss(x, u[:, :5])["pred_z"]) == pytest.approx(0.0, abs=1e-12)
            torch.testing.assert_close(model.predict(x[:, 0], u[:, :5]), x, rtol=0, atol=0)


@pytest.mark.parametrize("case", MODEL_CASES)
def test_sparse_dynamics_is_the_one_answer_to_whether_a_model_is_sparse(case: str) -> None:
    """Trainable SINDy models are SparseDynamics, whose counts follow from the mask; the
    others (the frozen compiled step included: nothing left to prune) are not."""
    model = _build(case)
    sparse = isinstance(model, SparseDynamics)
    assert sparse == model.sparse == isinstance(model, SindyDynamics)
    if not sparse:
        return
    pruned = model.prune(0.03)
    assert model.n_active() == int(model.mask.sum()) == model.n_candidates() - pruned
    assert model.sparsity() == pytest.approx(pruned / model.n_candidates())
    torch.testing.assert_close(model.l1_penalty(), model.coefficients().abs().sum())
    assert torch.equal(model.active_terms(), model.mask.any(1).nonzero().flatten())
