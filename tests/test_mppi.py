"""MPPI and its costs: closed loop on known linear systems, the §II.D update by hand, seeds,
bounds, NaN safety, sparse-vs-dense SINDy, and every latent model behind the same controller."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch

from latent_sindy.control import (
    MPPI,
    ImageCost,
    LatentCost,
    MPPIConfig,
    SindyKernelStep,
    latent_step,
)
from latent_sindy.errors import UserError
from latent_sindy.models import SindyConfig, SindyDynamics, make_dynamics
from latent_sindy.sindy import Cosine, Identity, Polynomial, Sine, poly_library

B = torch.tensor([[0.5, 0.1], [0.0, 0.4]])  # integrator z_{t+1} = z + B u, nz = nu = 2
PUSH_LOW, PUSH_HIGH = (-1.0, -math.pi / 2, 0.0), (1.0, math.pi / 2, 1.0)  # the env's box


def integrator(z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    return z + u @ B.T.to(z.dtype)


def config(**overrides) -> dict:
    kw = {"nu": 2, "K": 256, "H": 5, "sigma": 0.1, "lambda_": 0.05, "low": -1.0, "high": 1.0}
    return {**kw, **overrides}


def mppi_of(step, cost, nu: int, K: int = 100, H: int = 10, low=-math.inf, high=math.inf,
            seed: int = 0, dtype: torch.dtype = torch.float32, **settings) -> MPPI:
    """An MPPI from the test's flat settings: the planner's config, the action box, the rest."""
    def vec(v):
        return (float(v),) * nu if isinstance(v, int | float) else tuple(v)

    return MPPI(step, cost, MPPIConfig(samples=K, horizon=H, **settings), vec(low), vec(high),
                seed=seed, dtype=dtype)


def closed_loop(mppi: MPPI, step, z: torch.Tensor, steps: int) -> list[torch.Tensor]:
    actions = []
    for _ in range(steps):
        u, _ = mppi.command(z)
        actions.append(u)
        z = step(z[None], u[None])[0]
    return actions


# ---------------------------------------------------------------- behaviour on known systems


def test_drives_integrator_to_goal_and_cost_falls() -> None:
    goal = torch.tensor([2.0, -1.5])
    mppi = mppi_of(integrator, goal, **config())
    z, dist = torch.zeros(2), []
    for _ in range(15):
        u, info = mppi.command(z)
        assert info.discarded == 0
        z = integrator(z[None], u[None])[0]
        dist.append(float((z - goal).norm()))
    assert max(dist[-5:]) < 0.06  # arrived and stays
    far = [d for d in dist if d > 0.3]  # while far from the goal, every step gets closer
    assert len(far) >= 4 and all(b < a for a, b in itertools.pairwise(far))


def test_more_updates_a_command_reach_the_goal_sooner() -> None:
    goal = torch.tensor([2.0, -1.5])  # small noise: one update a command moves slowly
    dist = {}
    for iterations in (1, 4):
        mppi = mppi_of(integrator, goal, **config(K=32, sigma=0.01, iterations=iterations))
        z, total = torch.zeros(2), 0.0
        for _ in range(10):
            u, _ = mppi.command(z)
            z = integrator(z[None], u[None])[0]
            total += float((z - goal).norm())
        dist[iterations] = total
    assert dist[4] < 0.8 * dist[1], dist
    with pytest.raises(UserError, match="iterations 0"):
        MPPIConfig(iterations=0)


def test_drives_double_integrator_to_rest_at_goal() -> None:
    dt = 0.2

    def double_integrator(z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        p, v = z[:, :1], z[:, 1:]
        return torch.cat((p + dt * v, v + dt * u), dim=1)

    goal = torch.tensor([1.0, 0.0])
    cfg = dict(nu=1, K=512, H=15, sigma=0.5, lambda_=0.1, Q=(1.0, 0.1), low=-1.0,
                     high=1.0, terminal_weight=5.0, shift="repeat")
    mppi = mppi_of(double_integrator, goal, **cfg)
    z, costs = torch.zeros(2), []
    for _ in range(40):
        u, _ = mppi.command(z)
        z = double_integrator(z[None], u[None])[0]
        costs.append(float(LatentCost(goal, (1.0, 0.1))(z[None])))
    assert abs(float(z[0]) - 1.0) < 0.1 and abs(float(z[1])) < 0.1
    assert np.mean(costs[-5:]) < 0.01 * np.mean(costs[:5])


def test_weights_are_the_softmax_of_the_costs() -> None:
    mppi = mppi_of(integrator, torch.tensor([1.0, 1.0]), **config(lambda_=0.5))
    mppi.command(torch.zeros(2))
    w, c = mppi.weights, mppi.costs
    assert w.shape == c.shape == (256,) and (w >= 0).all()
    assert float(w.sum()) == pytest.approx(1.0, abs=1e-5)
    torch.testing.assert_close(w, torch.softmax(-c / 0.5, dim=0))
    assert int(w.argmax()) == int(c.argmin())


def test_same_seed_same_actions_different_seed_different() -> None:
    def run(seed: int) -> torch.Tensor:
        mppi = mppi_of(integrator, torch.tensor([1.0, -1.0]), **config(seed=seed))
        return torch.stack(closed_loop(mppi, integrator, torch.zeros(2), 3))

    a, b, c = run(0), run(0), run(1)
    torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert not torch.allclose(a, c)


def test_reset_restores_nominal_and_reseeds() -> None:
    mppi = mppi_of(integrator, torch.tensor([1.0, -1.0]), **config(u_init=(0.1, -0.2), seed=3))
    first, _ = mppi.command(torch.zeros(2))
    mppi.command(torch.ones(2))
    assert not torch.equal(mppi.nominal, torch.tensor([[0.1, -0.2]] * 5))
    mppi.reset(seed=3)
    torch.testing.assert_close(mppi.nominal, torch.tensor([[0.1, -0.2]] * 5))
    assert mppi.discarded_total == 0
    again, _ = mppi.command(torch.zeros(2))
    torch.testing.assert_close(again, first, rtol=0, atol=0)


@pytest.mark.parametrize("sigma", [0.1, 1e6])
def test_actions_stay_in_bounds(sigma: float) -> None:
    cfg = dict(nu=3, K=200, H=4, sigma=sigma, lambda_=0.01, low=PUSH_LOW, high=PUSH_HIGH)
    step = latent_step(make_dynamics("linear", 3, 3, init_scale=0.3, seed=0))
    mppi = mppi_of(step, torch.tensor([1.0, -2.0, 0.5]), **cfg)
    low, high = torch.tensor(PUSH_LOW), torch.tensor(PUSH_HIGH)
    z = torch.zeros(3)
    for _ in range(4):
        u, _ = mppi.command(z)
        for x in (u, mppi.nominal, mppi.actions):
            assert torch.isfinite(x).all()
            assert ((x >= low) & (x <= high)).all()
        z = step(z[None], u[None])[0]
    if sigma > 1:  # huge noise: nearly every candidate sits on a face of the box
        assert ((mppi.actions == low) | (mppi.actions == high)).float().mean() > 0.9


# ---------------------------------------------------------------- the update, by hand


@pytest.mark.parametrize("shift", ["init", "repeat"])
def test_one_update_equals_the_formula(shift: str) -> None:
    K, H, nu, lam, sigma, wT = 6, 3, 2, 0.5, (0.2, 0.5), 2.0
    q, goal, z0 = np.array([1.0, 3.0]), np.array([0.7, -0.4]), np.array([0.1, 0.2])
    u_init, low, high = np.array([0.2, -0.1]), np.array([-0.5, -0.6]), np.array([0.5, 0.4])
    eps = np.random.default_rng(0).normal(0.0, 0.6, (K, H, nu))  # some leave the box
    cfg = dict(nu=nu, K=K, H=H, sigma=sigma, lambda_=lam, Q=tuple(q), terminal_weight=wT,
                     low=tuple(low), high=tuple(high), u_init=tuple(u_init), shift=shift,
                     dtype=torch.float64)
    mppi = mppi_of(integrator, torch.tensor(goal), **cfg)
    action, info = mppi.command(torch.tensor(z0), noise=torch.tensor(eps))

    U = np.tile(u_init, (H, 1))
    cand = np.clip(U + eps, low, high)
    e = cand - U  # clamped perturbation
    Bn = B.double().numpy()
    z, cost = np.tile(z0, (K, 1)), np.zeros(K)
    for t in range(H):
        z = z + cand[:, t] @ Bn.T
        c = ((z - goal) ** 2 * q).sum(1)
        cost += c
    cost += wT * c + lam * np.einsum("ti,kti->k", U / np.array(sigma), e)
    w = np.exp(-(cost - cost.min()) / lam)
    w /= w.sum()
    U_new = U + np.einsum("k,kti->ti", w, e)

    np.testing.assert_allclose(mppi.costs.numpy(), cost, rtol=1e-12)
    np.testing.assert_allclose(mppi.weights.numpy(), w, rtol=1e-10, atol=1e-15)
    np.testing.assert_allclose(action.numpy(), U_new[0], rtol=1e-12)
    fill = U_new[-1] if shift == "repeat" else u_init
    np.testing.assert_allclose(mppi.nominal.numpy(), np.vstack([U_new[1:], fill]), rtol=1e-12)
    assert info.min_cost == pytest.approx(cost.min()) and info.mean_cost == pytest.approx(
        cost.mean())


def test_injected_noise_must_have_the_right_shape() -> None:
    mppi = mppi_of(integrator, torch.zeros(2), **config())
    with pytest.raises(ValueError, match=r"\(K, H, nu\)"):
        mppi.command(torch.zeros(2), noise=torch.zeros(5, 256, 2))


# ---------------------------------------------------------------- safety


@pytest.mark.parametrize("failure", ["overflow", "nan"])
def test_diverging_samples_get_zero_weight(failure: str) -> None:
    def unstable(z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        bad = (u[:, :1] > 0.5).expand_as(z)  # these samples blow up
        blown = z * 1e30 if failure == "overflow" else torch.full_like(z, math.nan)
        return torch.where(bad, blown, integrator(z, u))

    mppi = mppi_of(unstable, torch.tensor([3.0, 3.0]), **config(K=128))
    z, total = torch.ones(2), 0
    for _ in range(3):
        u, info = mppi.command(z)
        bad = (mppi.actions[:, :, 0] > 0.5).any(dim=1)  # (K,)
        assert 0 < info.discarded == int(bad.sum()) < 128
        total += info.discarded
        assert info.discarded_total == mppi.discarded_total == total
        assert (mppi.weights[bad] == 0).all() and torch.isinf(mppi.costs[bad]).all()
        assert float(mppi.weights.sum()) == pytest.approx(1.0, abs=1e-5)
        assert math.isfinite(info.min_cost) and math.isfinite(info.mean_cost)
        for x in (u, mppi.nominal):
            assert torch.isfinite(x).all() and (x.abs() <= 1).all()
        assert float(u[0]) <= 0.5  # the executed action is a blend of the safe samples
        z = integrator(z[None], u[None])[0]


def test_all_samples_diverging_keeps_the_nominal() -> None:
    mppi = mppi_of(integrator, torch.tensor([1.0, 1.0]), **config(shift="repeat"))
    mppi.command(torch.zeros(2))  # a non-trivial nominal to keep
    before = mppi.nominal
    mppi.step = lambda z, u: z * math.nan
    u, info = mppi.command(torch.zeros(2))
    assert info.discarded == 256 and info.discarded_total == 256
    assert info.min_cost == math.inf and math.isnan(info.mean_cost)
    assert (mppi.weights == 0).all()
    torch.testing.assert_close(u, before[0])
    torch.testing.assert_close(mppi.nominal, torch.cat((before[1:], before[-1:])))


# ---------------------------------------------------------------- every model, sparse SINDy

NZ, NU = 4, 3
KINDS = ["sindy1", "sindy2", "sindy3", "sindy4", "sindy2-sparse", "linear", "mlp"]


def build(case: str):
    torch.manual_seed(0)
    if case.startswith("sindy"):
        model = SindyDynamics(NZ, NU, order=int(case[5]), seed=0, init_scale=0.05)
        model.prune(0.04)
        return model.compile_sparse() if case.endswith("-sparse") else model
    model = make_dynamics(case, NZ, NU)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.05 * torch.randn_like(p))
    return model


@pytest.mark.parametrize("case", KINDS)
def test_every_model_runs_finite_and_in_bounds(case: str) -> None:
    model = build(case)
    cfg = dict(nu=NU, K=64, H=5, low=PUSH_LOW, high=PUSH_HIGH, seed=1, u_init=(0.0,) * NU)
    mppi = mppi_of(latent_step(model), torch.full((NZ,), 0.5), **cfg)
    low, high = torch.tensor(PUSH_LOW), torch.tensor(PUSH_HIGH)
    z = torch.zeros(NZ)
    with torch.no_grad():
        for _ in range(3):
            u, info = mppi.command(z)
            assert u.shape == (NU,) and torch.isfinite(u).all()
            assert ((u >= low) & (u <= high)).all()
            assert info.discarded == 0 and math.isfinite(info.min_cost)
            assert info.min_cost <= info.mean_cost and info.seconds > 0
            assert float(mppi.weights.sum()) == pytest.approx(1.0, abs=1e-5)
            z = model.step(z[None], u[None])[0]


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_sparse_active_terms_give_the_dense_actions(order: int) -> None:
    model = SindyDynamics(NZ, NU, order=order, seed=0, init_scale=0.05)
    model.prune(0.04)
    sparse = model.compile_sparse()
    fast = latent_step(model)
    assert isinstance(fast, SindyKernelStep)
    assert fast.n_terms == sparse.library.n_terms < model.library.n_terms
    cfg = dict(nu=NU, K=128, H=6, low=PUSH_LOW, high=PUSH_HIGH, seed=2, u_init=(0.0,) * NU)
    runs = []
    with torch.no_grad():
        for step in (model.step, sparse.step, fast):
            mppi = mppi_of(step, torch.full((NZ,), 0.5), **cfg)
            runs.append(torch.stack(closed_loop(mppi, model.step, torch.zeros(NZ), 4)))
    torch.testing.assert_close(runs[1], runs[0], rtol=0, atol=1e-5)
    torch.testing.assert_close(runs[2], runs[0], rtol=0, atol=1e-5)


def _trig_model(order: int, trig: str, init_scale: float) -> SindyDynamics:
    """nz=3, nu=2 SINDy model; trig "none", "sin", "sin+cos" (of the state) or "u" (sin and cos
    of the state, of the controls, products of a control's cosine with u1 and the state, and
    trig at other frequencies: sin(4 u1) z0, cos(0.5 z2))."""
    if trig != "u":
        return SindyDynamics(3, 2, order=order, seed=order, init_scale=init_scale,
                             include_sine=trig != "none", include_cosine=trig == "sin+cos")
    spec = (poly_library(order, include_sine=True, include_cosine=True) + Sine("u")
            + Cosine("u1") + Identity("u1") * Cosine("u0") * Polynomial("z", 1)
            + Identity("z0") * Sine("u1", frequency=4) + Cosine("z2", frequency=0.5))
    return SindyDynamics(3, 2, library_spec=spec, seed=order, init_scale=init_scale)


@pytest.mark.parametrize("order", [1, 2, 3, 4])
@pytest.mark.parametrize("trig", ["none", "sin", "sin+cos", "u"])
@pytest.mark.parametrize("tau", [0.0, 0.05, 0.12, 10.0])
def test_sparse_sindy_step_matches_the_model(order: int, trig: str, tau: float) -> None:
    model = _trig_model(order, trig, init_scale=0.1)
    model.prune(tau)
    step = SindyKernelStep(model)
    gen = torch.Generator().manual_seed(0)
    for k in (5, 9, 5):  # buffers per batch size, reused
        z, u = torch.randn(k, 3, generator=gen), torch.randn(k, 2, generator=gen)
        out = step(z, u)
        keep = out.clone()
        torch.testing.assert_close(out, model.step(z, u).detach(), rtol=1e-5, atol=1e-5)
        step(z + 1, u)
        torch.testing.assert_close(out, keep, rtol=0, atol=0)  # results do not alias buffers


@pytest.mark.parametrize("order", [1, 2, 3, 4])
@pytest.mark.parametrize("trig", ["none", "sin+cos", "u"])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_sparse_sindy_rollout_matches_the_model(order: int, trig: str, dtype) -> None:
    # K = 1100 spans two full kernel blocks and a partial one; z0 is one state expanded, as
    # MPPI passes it; the actions are a strided view.
    model = _trig_model(order, trig, init_scale=0.05)
    if trig == "u":  # make sure terms with trig of a control stay active
        with torch.no_grad():
            for j, name in enumerate(("sin(u0)", "cos(u1)", "z2 u1 cos(u0)",
                                      "z0 sin(4 u1)", "cos(0.5 z2)")):
                model.psi[model.names.index(name), j % 3] = 0.05
    model.prune(0.02)
    model = model.to(dtype)
    step = SindyKernelStep(model)
    gen = torch.Generator().manual_seed(1)
    z0 = 0.3 * torch.randn(1, 3, generator=gen, dtype=dtype).expand(1100, -1)
    actions = 0.3 * torch.randn(1100, 2, 7, generator=gen, dtype=dtype).transpose(1, 2)
    actions = actions.transpose(1, 2).contiguous().transpose(1, 2)  # (K, H, nu), strided
    with torch.no_grad():
        want = model.rollout(z0, actions)
    got = step.rollout(z0, actions)
    assert got.shape == (1100, 8, 3) and got.dtype == dtype and torch.isfinite(want).all()
    tol = 1e-5 if dtype == torch.float32 else 1e-10
    torch.testing.assert_close(got, want, rtol=tol, atol=tol)


def test_sparse_sindy_step_sine_is_accurate_far_from_zero() -> None:
    # The kernel computes its own sine (range reduction + polynomial): check it on |z| <= 200.
    model = SindyDynamics(2, 1, order=1, seed=0, include_sine=True, include_cosine=True)
    model = model.double()
    step = SindyKernelStep(model)
    z = torch.linspace(-200, 200, 40000, dtype=torch.float64).reshape(-1, 2)
    u = torch.zeros(z.shape[0], 1, dtype=torch.float64)
    with torch.no_grad():
        torch.testing.assert_close(step(z, u), model.step(z, u), rtol=0, atol=1e-12)


def test_sparse_sindy_step_propagates_nan_and_inf() -> None:
    model = SindyDynamics(3, 2, order=2, seed=0, init_scale=0.1, include_sine=True)
    step = SindyKernelStep(model)
    z = torch.tensor([[math.nan, 0.0, 0.0], [math.inf, 0.0, 0.0], [1e30, 1e30, 0.0],
                      [0.1, 0.2, 0.3]])
    out = step(z, torch.zeros(4, 2))
    assert not torch.isfinite(out[:3]).all(dim=1).any()  # every diverged row stays non-finite
    assert torch.isfinite(out[3]).all()


def test_diverging_sindy_samples_are_discarded_by_mppi() -> None:
    # z0' = z0 + z0² + u0 explodes to inf within the horizon when the pushes drive z0 up
    # (u0 > 0); MPPI counts and ignores those samples and returns a finite, in-box action.
    model = SindyDynamics(2, 1, order=2, seed=0, include_sine=False)
    names = model.library.names
    with torch.no_grad():
        model.psi.zero_()
        model.psi[names.index("z0^2"), 0] = 1.0
        model.psi[names.index("u0"), 0] = 1.0
    mppi = mppi_of(latent_step(model), torch.zeros(2), nu=1, K=256, H=10, sigma=0.5, low=-1.0,
                   high=1.0, seed=0)
    u, info = mppi.command(torch.zeros(2))
    assert 0 < info.discarded < 256
    assert torch.isinf(mppi.costs).sum() == info.discarded
    assert torch.isfinite(u).all() and -1 <= float(u[0]) <= 0  # pushes z0 down, not up


def test_latent_cost_is_the_same_for_any_memory_layout() -> None:
    cost = LatentCost(torch.tensor([0.5, -1.0, 2.0]), Q=(1.0, 2.0, 0.5))
    feature_major = torch.randn(4, 3, 6)  # (H, nz, K) memory, as the fused rollout writes it
    z = feature_major.transpose(1, 2)  # (H, K, nz) view, last dimension strided
    torch.testing.assert_close(cost(z), cost(z.contiguous()))
    assert cost(z).shape == (4, 6)


def _face_model(circle: tuple[int, int] | None, dtype: torch.dtype) -> SindyDynamics:
    """A pruned face-library SINDy model on a pose latent (x, y, cos 4θ, sin 4θ), nu = 3."""
    model = SindyConfig(order=1, library="face", include_sine=False, init_scale=0.02).build(
        NZ, NU, circle=circle)
    model.prune(0.01)
    return model.to(dtype)


def _pose_batch(K: int, H: int, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
    """z0 (K, 4) with (z2, z3) on the unit circle, random pushes (K, H, 3)."""
    gen = torch.Generator().manual_seed(4)
    angle = 2 * math.pi * torch.rand(K, generator=gen, dtype=dtype)
    z0 = torch.stack([0.1 * torch.randn(K, generator=gen, dtype=dtype) + 0.5,
                      0.1 * torch.randn(K, generator=gen, dtype=dtype), angle.cos(),
                      angle.sin()], -1)
    low, high = torch.tensor(PUSH_LOW, dtype=dtype), torch.tensor(PUSH_HIGH, dtype=dtype)
    return z0, low + (high - low) * torch.rand(K, H, NU, generator=gen, dtype=dtype)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("circle", [(2, 3), None])
def test_the_fused_rollout_projects_as_the_model_does(circle, dtype) -> None:
    """K = 1100 (two full kernel blocks and a partial one), 20 pushes: with a circle every
    predicted (z2, z3) lies on it and the kernel equals the torch model's projected rollout
    to rounding; without one both stay unprojected (the pair leaves the circle)."""
    model = _face_model(circle, dtype)
    step = SindyKernelStep(model)
    assert step.circle == circle
    z0, actions = _pose_batch(1100, 20, dtype)
    with torch.no_grad():
        want = model.rollout(z0, actions)
    got = step.rollout(z0, actions)
    assert torch.isfinite(want).all()
    tol = 1e-5 if dtype == torch.float32 else 1e-10
    torch.testing.assert_close(got, want, rtol=tol, atol=tol)
    torch.testing.assert_close(step(z0, actions[:, 0]), want[:, 1], rtol=tol, atol=tol)
    off = (got[:, 1:, 2:].norm(dim=-1) - 1).abs().max()
    if circle is None:
        assert off > 1e-2, float(off)
    else:
        assert off < (1e-6 if dtype == torch.float32 else 1e-14), float(off)


@pytest.mark.parametrize("case", ["sindy1", "sindy2-sparse", "linear", "mlp"])
def test_every_control_step_of_a_pose_latent_stays_on_the_circle(case: str) -> None:
    """latent_step of any model built with a circle predicts MPPI's horizon on it, like the
    model's own rollout."""
    model = build(case)
    if case.startswith("sindy"):
        dense = SindyDynamics(NZ, NU, order=int(case[5]), seed=0, init_scale=0.05,
                              circle=(2, 3))
        dense.prune(0.04)
        model = dense.compile_sparse() if case.endswith("-sparse") else dense
    else:
        params = model.state_dict()
        model = make_dynamics(case, **model.hparams(), circle=(2, 3))
        model.load_state_dict(params)
    step = latent_step(model)
    z0, actions = _pose_batch(64, 10, torch.float32)
    with torch.no_grad():
        want = model.rollout(z0, actions)
        if hasattr(step, "rollout"):
            got = step.rollout(z0, actions)
        else:
            z, got = z0, [z0]
            for t in range(actions.shape[1]):
                z = step(z, actions[:, t])
                got.append(z)
            got = torch.stack(got, 1)
    norms = got[:, 1:, 2:].norm(dim=-1)
    torch.testing.assert_close(norms, torch.ones_like(norms), rtol=0, atol=1e-6)
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-5)


def test_the_check_catches_a_kernel_that_skips_the_projection(monkeypatch) -> None:
    from latent_sindy.control import sindy_step

    real = sindy_step._kernel()

    def unprojected(*args):  # the kernel with ca = cb = -1: no projection
        args = list(args)
        args[13] = args[14] = -1
        real(*args)

    SindyKernelStep(_face_model((2, 3), torch.float32))  # the real kernel passes the check
    monkeypatch.setattr(sindy_step, "_kernel", lambda: unprojected)
    SindyKernelStep(_face_model(None, torch.float32))  # nothing to project: still agrees
    with pytest.raises(RuntimeError, match="circle projection"):
        SindyKernelStep(_face_model((2, 3), torch.float32))


def test_sparse_sindy_step_rejects_other_models() -> None:
    with pytest.raises(TypeError, match="SINDy"):
        SindyKernelStep(make_dynamics("linear", 2, 1))


# ---------------------------------------------------------------- costs and configuration


def test_goal_vector_means_latent_cost_with_config_q() -> None:
    goal = torch.tensor([1.0, -1.0])
    a = mppi_of(integrator, goal, **config(Q=(2.0, 0.5)))
    b = mppi_of(integrator, LatentCost(goal, (2.0, 0.5)), **config())
    torch.testing.assert_close(a.command(torch.zeros(2))[0], b.command(torch.zeros(2))[0])


def test_latent_cost_scalar_diagonal_and_full() -> None:
    gen = torch.Generator().manual_seed(0)
    z, goal = torch.randn(7, 3, generator=gen), torch.randn(3, generator=gen)
    d = z - goal
    torch.testing.assert_close(LatentCost(goal, 2.0)(z), 2 * (d * d).sum(1))
    q = torch.tensor([1.0, 0.0, 3.0])
    torch.testing.assert_close(LatentCost(goal, q)(z), (d * d * q).sum(1))
    M = torch.tensor([[2.0, 0.5, 0.0], [0.5, 1.0, 0.0], [0.0, 0.0, 1.0]])
    torch.testing.assert_close(LatentCost(goal, M)(z), torch.einsum("ki,ij,kj->k", d, M, d))
    with pytest.raises(UserError, match="Q must be"):
        LatentCost(goal, torch.ones(4))
    with pytest.raises(UserError, match=">= 0"):
        LatentCost(goal, -1.0)


def test_image_cost_decodes_each_sample() -> None:
    gen = torch.Generator().manual_seed(0)
    W = torch.randn(16, 3, generator=gen)

    def decoder(z: torch.Tensor) -> torch.Tensor:
        return (z @ W.T).reshape(-1, 1, 4, 4)  # (K, 1, 4, 4) "images"

    goal_image = torch.randn(1, 4, 4, generator=gen)
    z = torch.randn(5, 3, generator=gen)
    want = ((decoder(z) - goal_image) ** 2).flatten(1).sum(1)
    torch.testing.assert_close(ImageCost(decoder, goal_image)(z), want)
    torch.testing.assert_close(ImageCost(decoder, goal_image, weight=0.5)(z), 0.5 * want)
    with pytest.raises(UserError, match="does not match"):
        ImageCost(decoder, torch.zeros(1, 5, 5))(z)


@pytest.mark.parametrize(
    ("overrides", "field"),
    [
        ({"K": 0}, "samples"),
        ({"H": 2.5}, "horizon"),
        ({"sigma": -0.1}, "sigma"),
        ({"sigma": (0.1, 0.2, 0.3)}, "sigma"),
        ({"sigma": 1e80}, "sigma"),
        ({"lambda_": 0.0}, "lambda"),
        ({"Q": -1.0}, "Q"),
        ({"terminal_weight": math.nan}, "terminal_weight"),
        ({"low": (0.5, 0.0), "high": (0.0, 1.0)}, "low <= high"),
        ({"low": math.nan}, "low"),
        ({"u_init": (2.0, 0.0)}, "u_init"),
        ({"shift": "roll"}, "shift"),
        ({"dtype": torch.int64}, "dtype"),
    ],
)
def test_config_rejects_bad_values(overrides: dict, field: str) -> None:
    with pytest.raises(UserError, match=field):
        mppi_of(integrator, torch.zeros(2), **config(**overrides))


def test_unbounded_config_and_float64() -> None:
    cfg = dict(nu=2, K=32, H=3, sigma=(0.1, 0.2), dtype=torch.float64)
    mppi = mppi_of(integrator, torch.tensor([5.0, 5.0], dtype=torch.float64), **cfg)
    u, _ = mppi.command(torch.zeros(2, dtype=torch.float64))
    assert u.dtype == torch.float64 and torch.isfinite(u).all()


def test_sparse_sindy_step_serves_mppi_and_plain_calls() -> None:
    # Its reused buffers are made outside inference mode, so the same step object works for
    # MPPI (inference mode) and afterwards under no_grad or with autograd on.
    model = SindyDynamics(NZ, NU, order=2, seed=0, init_scale=0.05)
    model.prune(0.04)
    step = latent_step(model)
    mppi_of(step, torch.zeros(NZ), nu=NU, K=8, H=2).command(torch.ones(NZ))
    z, u = torch.randn(8, NZ), torch.randn(8, NU)
    with torch.no_grad():
        torch.testing.assert_close(step(z, u), model.step(z, u))
    torch.testing.assert_close(step(z, u), model.step(z, u).detach())


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("sense", [1, -1])
def test_sparse_sindy_step_computes_the_face_variables_as_the_model(dtype, sense) -> None:
    # The frame library's face variables (a, n) come from atan2 of the orientation features
    # and a wrap, inside the kernel; also as arguments of cos(n), sin(n), over a rollout with
    # the unit-circle projection.
    from latent_sindy.worlds.push.library import frame_library

    model = SindyDynamics(4, 3, library_spec=frame_library(sense=sense, angle_offset=0.7),
                          seed=2, init_scale=0.05, circle=(2, 3)).to(dtype)
    model.prune(0.03)
    step = SindyKernelStep(model)
    assert any("a" in name.split() or "cos(n)" in name for name in step._sparse.names)
    gen = torch.Generator().manual_seed(4)
    z0 = torch.randn(700, 4, generator=gen, dtype=dtype)
    actions = torch.randn(700, 6, 3, generator=gen, dtype=dtype) * 2
    with torch.no_grad():
        want = model.rollout(z0, actions)
    tol = 1e-4 if dtype == torch.float32 else 1e-9
    torch.testing.assert_close(step.rollout(z0, actions), want, rtol=tol, atol=tol)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_sparse_sindy_step_turns_the_pair_as_the_model(dtype) -> None:
    # A turning model: z2's update is the angle by which (z2, z3) turns; the kernel turns and
    # projects the pair as the model does, over a rollout.
    from latent_sindy.worlds.push.library import frame_library

    model = SindyDynamics(4, 3, library_spec=frame_library(), seed=3, init_scale=0.2,
                          circle=(2, 3), turn=True).to(dtype)
    model.prune(0.1)
    assert not model.mask[:, 3].any() and model.mask[:, 2].any()
    step = SindyKernelStep(model)
    gen = torch.Generator().manual_seed(5)
    z0 = torch.randn(600, 4, generator=gen, dtype=dtype)
    actions = torch.randn(600, 5, 3, generator=gen, dtype=dtype)
    with torch.no_grad():
        want = model.rollout(z0, actions)
    tol = 1e-4 if dtype == torch.float32 else 1e-9
    torch.testing.assert_close(step.rollout(z0, actions), want, rtol=tol, atol=tol)
