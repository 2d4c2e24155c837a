"""The controlled pendulum: Pendulum-v1's physics step for step, the camera's two frames, the
world interface and its data, the sparse regression recovering the discretised physics, and
a swing-up by MPPI on the true dynamics (the task is achievable)."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from latent_sindy.control.episodes import run_closed_loop, run_episode
from latent_sindy.control.world import Task, World
from latent_sindy.data import read_sequences, write_sequences
from latent_sindy.errors import UserError
from latent_sindy.plugins import get_world
from latent_sindy.sindy import Polynomial, SindyLibrary
from latent_sindy.sindy.fit import fit_state_data
from latent_sindy.worlds.pendulum import (
    WORLD,
    PendulumConfig,
    PendulumWorld,
    physics,
    swing_up_success,
    upright,
    upright_fraction,
)
from latent_sindy.worlds.pendulum.render import observe, rods
from latent_sindy.worlds.pendulum.swing_up import StateMPPI, run_swing_up


def test_the_physics_are_gymnasiums_pendulum_step_for_step():
    gym = pytest.importorskip("gymnasium")
    from latent_sindy.worlds.pendulum.env import PendulumImageEnv

    ref = gym.make("Pendulum-v1").unwrapped
    ref.reset(seed=0)
    ours = PendulumImageEnv(PendulumConfig(image_size=16))
    ours.reset(seed=0, options={"start": ref.state})
    rng = np.random.default_rng(0)
    rates = []
    for u in rng.uniform(-3, 3, 300):  # torques beyond the box are clipped by both
        ours.state = np.array([physics.wrap_angle(ref.state[0]), ref.state[1]], np.float64)
        _, r_ref, *_ = ref.step(np.array([u], np.float32))
        _, r_ours, *_ = ours.step(np.array([u], np.float32))
        # (gymnasium multiplies the float32 torque in float32: 1e-8 apart)
        assert physics.wrap_angle(ours.state[0] - ref.state[0]) == pytest.approx(0, abs=1e-6)
        assert ours.state[1] == pytest.approx(ref.state[1], abs=1e-6)
        assert r_ours == pytest.approx(r_ref, abs=1e-6)
        rates.append(ours.state[1])
    assert max(np.abs(rates)) == 8.0  # the clip was met and agreed on


def test_one_step_is_the_discretised_physics_and_the_rate_clips_at_8():
    theta, rate, u = np.array([0.3, 2.0, 1.0]), np.array([0.5, -1.0, 7.9]), np.array([1, -2, 2])
    new_theta, new_rate = physics.step(theta, rate, u)
    expected = rate + 0.75 * np.sin(theta) + 0.15 * u
    np.testing.assert_allclose(new_rate[:2], expected[:2])
    assert expected[2] > 8 and new_rate[2] == 8.0
    np.testing.assert_allclose(new_theta, physics.wrap_angle(theta + new_rate * 0.05))
    x = physics.features(np.stack([theta, rate], 1))  # (3, 3)
    x_next = physics.feature_step(torch.tensor(x), torch.tensor(u, dtype=torch.float64)[:, None])
    np.testing.assert_allclose(x_next.numpy(), physics.features(np.stack([new_theta, new_rate],
                                                                          1)), atol=1e-12)


def test_the_rod_points_up_at_zero_and_turns_counter_clockwise():
    up, left, down = rods(np.array([0.0, math.pi / 2, math.pi]), 48)
    assert up[:20].sum() > 50 * up[28:].sum()  # bright above the pivot only
    assert left[:, :20].sum() > 50 * left[:, 28:].sum()
    np.testing.assert_array_equal(down, up[::-1])


def test_the_rod_is_anti_aliased():
    """Edge pixels take intermediate values, and the rod's brightness hardly changes as it
    turns (a jagged rod's would jump with the pixels it happens to hit)."""
    frames = rods(np.linspace(0, 2 * math.pi, 37), 48).astype(float)
    grey = (frames > 0) & (frames < 255)
    assert grey.sum() > 0.3 * (frames == 255).sum()
    totals = frames.sum(axis=(1, 2))
    assert totals.std() < 0.02 * totals.mean()


def test_two_frames_show_the_rate_and_follow_each_other():
    obs = observe(1.0, 0.0, 32)
    np.testing.assert_array_equal(obs[0], obs[1])  # at rest both frames agree
    assert np.any(observe(1.0, 3.0, 32)[0] != observe(1.0, 3.0, 32)[1])
    env = WORLD.make_env()
    prev, _ = env.reset(seed=0)
    for u in np.random.default_rng(1).uniform(-2, 2, 20):
        obs, *_ = env.step(np.array([u], np.float32))
        assert obs.shape == (2, 48, 48) and obs.dtype == np.uint8
        # the frame a step ago is the previous observation's current frame
        assert np.abs(obs[0].astype(int) - prev[1].astype(int)).max() <= 1
        prev = obs


def test_the_world_interface_and_its_tasks():
    world = get_world("pendulum")
    assert world is WORLD and isinstance(world, World)
    assert world.action_low == (-2.0,) and world.action_high == (2.0,)
    rng = np.random.default_rng(0)
    starts = np.stack([world.sample_task(rng).start for _ in range(50)])
    assert np.all(np.abs(physics.wrap_angle(starts[:, 0] - math.pi)) <= 0.1)
    assert np.all(np.abs(starts[:, 1]) <= 0.1)
    anywhere = PendulumWorld(PendulumConfig(start="random"))
    starts = np.stack([anywhere.sample_task(rng).start for _ in range(200)])
    assert starts[:, 0].min() < -2.5 and starts[:, 0].max() > 2.5
    task = world.sample_task(rng)
    np.testing.assert_array_equal(task.goal, [0.0, 0.0])
    env = world.make_env()
    goal = world.goal_image(env, task)
    np.testing.assert_array_equal(goal, observe(0.0, 0.0, 48))
    np.testing.assert_array_equal(world.reset(env, task, seed=0), observe(*task.start, 48))
    assert world.success(np.array([math.radians(9), 3.0]), task.goal) == {"upright": True}
    assert world.success(np.array([math.radians(11), 0.0]), task.goal) == {"upright": False}
    assert world.success(np.array([2 * math.pi - 0.1, 0.0]), task.goal) == {"upright": True}


def test_the_generic_closed_loop_runs_in_the_pendulum():
    """Without torque a hanging pendulum stays hanging; near upright it counts at once."""

    class Still:
        def reset(self, goal, seed=None):
            assert goal.image.shape == (2, 48, 48)

        def act(self, observation):
            return np.zeros(1, np.float32)

    (episode,) = run_closed_loop(WORLD, Still(), episodes=1, max_steps=30, seed=0)
    assert episode.steps == 30 and episode.reached == {"upright": None}
    assert abs(physics.wrap_angle(episode.final_state[0] - math.pi)) < 0.3
    env = WORLD.make_env()
    near = run_episode(WORLD, env, Still(), Task(np.array([0.05, 0.0]), np.zeros(2)), 5, 0)
    assert near.reached == {"upright": 0} and near.steps == 0


def test_episode_criteria():
    states = np.zeros((100, 2))
    states[:50, 0] = math.pi
    assert upright_fraction(states) == 0.5 and swing_up_success(states, last=20)
    states[90, 0] = math.radians(10.5)
    assert not swing_up_success(states, last=20) and upright_fraction(states) == 0.49
    assert upright(np.array([math.radians(10), 0.0]))
    with pytest.raises(UserError):
        swing_up_success(states[:10], last=20)
    with pytest.raises(UserError):
        upright_fraction(np.zeros((5, 3)))


def test_random_data_hold_images_of_the_states_and_the_physics():
    world = PendulumWorld(PendulumConfig(start="random", image_size=24))
    data = world.collect(sequences=5, steps=6, seed=3)
    assert data.images.shape == (5, 7, 2, 24, 24) and data.actions.shape == (5, 6, 1)
    assert data.world == "pendulum" and data.dt == 0.05 and data.action_names == ("torque",)
    assert data.state_names == ("θ", "θ_dot") and data.state_periods == (2 * math.pi, None)
    s = data.states.astype(np.float64)
    theta, rate = physics.step(s[:, :-1, 0], s[:, :-1, 1], data.actions[..., 0])
    np.testing.assert_allclose(physics.wrap_angle(theta - s[:, 1:, 0]), 0, atol=1e-5)
    np.testing.assert_allclose(rate, s[:, 1:, 1], atol=1e-5)
    assert np.abs(observe(s[..., 0], s[..., 1], 24).astype(int) - data.images).max() <= 1
    again = world.collect(sequences=5, steps=6, seed=3)
    assert again.fingerprint() == data.fingerprint()
    assert world.collect(sequences=5, steps=6, seed=4).fingerprint() != data.fingerprint()


def test_the_data_round_trip_through_a_file_with_their_world(tmp_path):
    data = PendulumWorld(PendulumConfig(image_size=16)).collect(sequences=3, steps=2, seed=0)
    write_sequences(tmp_path / "pendulum.h5", data)
    back = read_sequences(tmp_path / "pendulum.h5")
    assert back.world_config == PendulumConfig(image_size=16)
    np.testing.assert_array_equal(back.images, data.images)
    wrong = data.replace(record={"pendulum": {"image_size": 24}})
    write_sequences(tmp_path / "wrong.h5", wrong)
    with pytest.raises(UserError, match=r"frames \(2, 24, 24\)"):
        read_sequences(tmp_path / "wrong.h5")


def test_sparse_regression_recovers_the_discretised_physics():
    """STLSQ on random-torque data, state features (cos θ, sin θ, θ̇), a library of all
    monomials of (z, u) up to order 2: the rate's step is 0.75 sin θ + 0.15 u and nothing
    else (steps that hit the rate's clip left out)."""
    world = PendulumWorld(PendulumConfig(start="random", image_size=8))
    data = world.collect(sequences=40, steps=20, seed=0)
    x = physics.features(data.states.astype(np.float64))  # (N, T+1, 3)
    z, z_next = x[:, :-1].reshape(-1, 3), x[:, 1:].reshape(-1, 3)
    u = data.actions.reshape(-1, 1).astype(np.float64)
    keep = np.abs(z_next[:, 2]) < physics.MAX_SPEED
    library = SindyLibrary(Polynomial("z,u", 2), n_state=3, n_control=1)
    fit = fit_state_data(library, *(torch.tensor(a[keep]) for a in (z, u, z_next)))
    rate = {library.names[i]: float(fit.coef_[i, 2]) for i in np.flatnonzero(fit.mask_[:, 2])}
    assert set(rate) == {"z1", "u0"}, rate  # z1 = sin θ, u0 = torque
    assert rate["z1"] == pytest.approx(0.75, rel=0.02)
    assert rate["u0"] == pytest.approx(0.15, rel=0.02)


def test_mppi_on_the_true_dynamics_swings_the_pendulum_up(one_torch_thread):
    """The oracle (true state, true dynamics) swings up from hanging and stays upright over
    the last 20 of 100 steps: the task and its criteria are achievable."""
    results = run_swing_up(WORLD, StateMPPI(), episodes=3, steps=100, seed=0)
    assert all(r.success for r in results), [r.upright_fraction for r in results]
    assert all(r.states.shape == (101, 2) and r.actions.shape == (100, 1) for r in results)
    assert all(np.abs(r.actions).max() <= 2 for r in results)


def test_the_pendulum_example_runs_end_to_end():
    script = Path(__file__).resolve().parents[1] / "examples" / "pendulum.py"
    out = subprocess.run([sys.executable, str(script), "--sequences", "12", "--epochs", "1",
                          "--image-size", "16", "--steps", "3"], capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "torque" in out.stdout and "swing-up from θ" in out.stdout
