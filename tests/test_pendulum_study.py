"""The pendulum study: the latent cost that is not flat at the bottom, the state SINDy, the
intervals, and the whole study end to end at a tiny size."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from latent_sindy.control.costs import LatentCost
from latent_sindy.control.episodes import Observation
from latent_sindy.errors import UserError
from latent_sindy.stats import wilson_interval
from latent_sindy.worlds.pendulum import PendulumConfig, PendulumWorld, physics
from latent_sindy.worlds.pendulum.graph_cost import GraphDistanceCost, graph_distances
from latent_sindy.worlds.pendulum.render import observe
from latent_sindy.worlds.pendulum.state_sindy import StateSindy
from latent_sindy.worlds.pendulum.study import (
    LatentSwingUp,
    StudyConfig,
    compare_swing_ups,
    fit_image_model,
)


def circle(phi: np.ndarray) -> np.ndarray:
    return np.stack([np.cos(phi), np.sin(phi)], -1)


def test_graph_distance_is_the_arc_length_along_a_circle_of_codes():
    phi = np.linspace(-math.pi, math.pi, 400, endpoint=False)
    dist = graph_distances(circle(phi), int(np.argmin(np.abs(phi))), neighbours=4)
    np.testing.assert_allclose(dist, np.abs(phi), atol=0.02)


def test_the_graph_cost_is_least_at_the_goal_and_not_flat_at_the_far_side():
    """On codes lying on a loop, the quadratic cost to the goal's code is flat at the far
    side (a step of 0.2 rad changes it by 1 %), the distance along the loop is not (it falls
    by the step): a swing either way from hanging pays at once."""
    rng = np.random.default_rng(0)
    codes = circle(rng.uniform(-math.pi, math.pi, 500))
    goal = torch.tensor([1.0, 0.0])
    cost = GraphDistanceCost(codes, goal, neighbours=12, nodes=500, seed=0)
    probe = torch.tensor(circle(np.array([0.0, 0.3, -0.3, math.pi, math.pi - 0.2,
                                          -math.pi + 0.2])), dtype=torch.float32)
    d = cost.distance(probe)
    assert float(cost(probe[:1])) == pytest.approx(0.0, abs=1e-6)  # least at the goal
    assert bool((cost(probe[1:]) > cost(probe[:1])).all())
    assert float(d[3]) == pytest.approx(math.pi, abs=0.05)
    assert float(d[3] - d[4]) == pytest.approx(0.2, abs=0.05)  # first order at the far side
    assert float(d[3] - d[5]) == pytest.approx(0.2, abs=0.05)  # either way
    quad = LatentCost(goal)(probe)
    assert float(quad[3] - quad[4]) < 0.01 * float(quad[3])  # the quadratic one: flat there
    assert cost(torch.zeros(4, 7, 2)).shape == (4, 7)  # batched over any leading dims


def test_the_graph_cost_refuses_bad_codes():
    with pytest.raises(UserError, match="codes"):
        GraphDistanceCost(np.zeros((3, 2)), np.zeros(2), neighbours=8)
    with pytest.raises(UserError, match="finite"):
        GraphDistanceCost(np.full((20, 2), np.nan), np.zeros(2), neighbours=4)


def test_wilson_intervals():
    assert wilson_interval(0, 10) == pytest.approx((0.0, 0.2775), abs=1e-3)
    assert wilson_interval(10, 10) == pytest.approx((0.7225, 1.0), abs=1e-3)
    lo, hi = wilson_interval(45, 50)
    assert lo < 0.9 < hi
    with pytest.raises(UserError):
        wilson_interval(3, 2)


def test_state_sindy_finds_the_discretised_physics_and_steps_like_it():
    data = PendulumWorld(PendulumConfig(start="random", image_size=8)).collect(60, 12, seed=1)
    model = StateSindy().fit(data)
    eq = model.equations()
    assert eq[2] == "Δθ_dot = +0.75 sin θ +0.15 torque", eq
    x = torch.tensor(physics.features(np.array([[2.0, 1.0], [-0.5, -2.0]])))
    u = torch.tensor([[1.0], [-2.0]], dtype=torch.float64)
    np.testing.assert_allclose(model.step(x, u)[:, 2], physics.feature_step(x, u)[:, 2],
                               atol=1e-3)
    assert 0.5 < model.sparsity() < 1


def test_the_study_runs_end_to_end_and_tabulates_every_model(one_torch_thread):
    cfg = StudyConfig(image_size=16, sequences=12, steps=3, epochs=1, window=2, episodes=2,
                      episode_steps=4, last=2, samples=16, horizon=3, nodes=20,
                      neighbours=4, cost_check=1)
    result = compare_swing_ups(cfg, report=lambda _: None)
    names = [r.name for r in result.rows]
    assert names == ["state SINDy (true state)", "sindy (images)", "mlp (images)",
                     "linear (images)", "sindy (images, centroid latent)",
                     "mlp (images, centroid latent)", "linear (images, centroid latent)"]
    table = result.table()
    for row in result.rows:
        assert len(row.episodes) == 2
        lo, hi = row.success_interval
        assert 0 <= lo <= row.successes / 2 <= hi <= 1
        f, flo, fhi = row.upright
        assert flo <= f <= fhi
        assert row.name in table
    assert table.count("–") >= 8  # two intervals per row
    assert all(len(r.cost_check) == 1 for r in result.rows[1:4])  # the diagnostic ran
    assert "torque" in result.equations()  # the sparse models' equations name the action


def test_the_latent_policy_reads_the_image_only(one_torch_thread):
    cfg = StudyConfig(image_size=16, sequences=8, steps=2, epochs=1, window=1,
                      models=("sindy",), samples=8, horizon=2, nodes=12, neighbours=3)
    data = PendulumWorld(PendulumConfig(start="random", image_size=16)).collect(8, 2, seed=0)
    model = fit_image_model(data, "sindy", cfg)
    policy = LatentSwingUp(model, model.encode(data.images.reshape(-1, 2, 16, 16)), cfg)
    policy.reset(Observation(observe(0.0, 0.0, 16)), seed=0)
    u = policy.act(Observation(observe(math.pi, 0.0, 16)))  # no state to read
    assert u.shape == (1,) and abs(float(u[0])) <= 2


def test_the_tabulated_graph_cost_reads_like_the_exact_one():
    rng = np.random.default_rng(1)
    phi = rng.uniform(-math.pi, math.pi, 400)
    codes = np.c_[circle(phi), 0.1 * rng.standard_normal(400)]  # (400, 3)
    goal = np.array([1.0, 0.0, 0.0])
    exact = GraphDistanceCost(codes, goal, neighbours=10, nodes=400, seed=0)
    table = GraphDistanceCost(codes, goal, neighbours=10, nodes=400, seed=0, grid=40)
    probe = torch.tensor(codes[:50], dtype=torch.float32)
    np.testing.assert_allclose(table.distance(probe), exact.distance(probe), atol=0.1)
    far = torch.tensor([[5.0, 0.0, 0.0]])  # outside the table: grows with the way out
    assert float(table.distance(far)) > float(table.distance(torch.tensor([[1.2, 0, 0]])))
    bad = torch.tensor([[float("nan"), 0.0, 0.0], [float("inf"), 0.0, 0.0]])
    assert torch.isinf(table.distance(bad)).all()  # diverged rollouts cost inf


def test_one_wilson_interval_and_no_rate_without_trials():
    assert all(math.isnan(end) for end in wilson_interval(0, 0))
    with pytest.raises(UserError, match="0 <= successes <= trials"):
        wilson_interval(-1, 4)
