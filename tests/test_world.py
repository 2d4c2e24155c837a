"""A world written through the world interface in a few lines runs the whole loop: random
data, a fitted LatentSINDy, and closed-loop MPPI toward goal images."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from latent_sindy import LatentSINDy
from latent_sindy.control import MPPIConfig
from latent_sindy.control.collect import collect_random
from latent_sindy.control.episodes import ImagePolicy, run_closed_loop, success_rates
from latent_sindy.control.world import Task, World
from latent_sindy.training import TrainConfig

H, W = 20, 24


def blob(p: np.ndarray) -> np.ndarray:
    ys, xs = np.meshgrid(np.linspace(-1, 1, H), np.linspace(-1, 1, W), indexing="ij")
    disc = np.exp(-((xs - p[0]) ** 2 + (ys - p[1]) ** 2) / 0.2)
    return (40 + 215 * disc)[None].astype(np.uint8)


class SliderEnv(gym.Env):
    """A puck on a table pushed by a velocity command, seen from above."""

    observation_space = gym.spaces.Box(0, 255, (1, H, W), np.uint8)
    action_space = gym.spaces.Box(-1, 1, (2,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.p = np.asarray(options["start"], float)
        return blob(self.p), {}

    def step(self, u):
        self.p = np.clip(self.p + 0.2 * np.clip(u, -1, 1), -0.8, 0.8)
        return blob(self.p), 0.0, False, False, {}


class Slider:
    name, action_low, action_high, action_names = "slider", (-1.0, -1.0), (1.0, 1.0), ("vx", "vy")

    def make_env(self):
        return SliderEnv()

    def sample_task(self, rng):
        return Task(start=rng.uniform(-0.7, 0.7, 2), goal=rng.uniform(-0.7, 0.7, 2))

    def reset(self, env, task, seed):
        return env.reset(seed=seed, options={"start": task.start})[0]

    def image(self, observation):
        return observation

    def goal_image(self, env, task):
        return blob(task.goal)

    def state(self, env):
        return env.p.copy()

    def success(self, state, goal):
        d = float(np.linalg.norm(state - goal))
        return {"near": d < 0.25, "at": d < 0.1}


@pytest.fixture(scope="module")
def world():
    return Slider()


def test_the_toy_world_meets_the_interface(world):
    assert isinstance(world, World)


def test_random_data_from_the_world(world):
    data = collect_random(world, sequences=4, steps=3, seed=1)
    assert data.images.shape == (4, 4, 1, H, W) and data.actions.shape == (4, 3, 2)
    assert data.states.shape == (4, 4, 2) and data.action_names == ("vx", "vy")
    np.testing.assert_array_equal(collect_random(world, 4, 3, seed=1).images, data.images)


@pytest.mark.slow  # about 25 s on 2 cores (the tiny study plans closed loops in the suite)
def test_closed_loop_reaches_goals_with_a_fitted_model(world, one_torch_thread):
    data = collect_random(world, sequences=40, steps=6, seed=0)
    model = LatentSINDy(latent_dim=2, order=1, include_sine=False, seed=0,
                        settings=TrainConfig(lr=3e-3)).fit(data, epochs=60, batch_size=12)
    planner = model.planner(MPPIConfig(samples=200, horizon=4, sigma=0.5))
    results = run_closed_loop(world, ImagePolicy(planner), episodes=6, max_steps=15, seed=3)
    rates = success_rates(results)
    start = [np.linalg.norm(r.task.start - r.task.goal) for r in results]
    end = [np.linalg.norm(r.final_state - r.task.goal) for r in results]
    assert np.mean(end) < 0.3 * np.mean(start), (start, end)
    assert rates["near"] >= 5 / 6, rates


def test_the_pushing_world_is_a_world_found_by_name():
    """The Panda world plugs in through the same interface: a zero-length push leaves the block
    where the task started it, and its criteria are the course's and the strict one."""
    from latent_sindy.plugins import get_world

    push = get_world("push")
    assert isinstance(push, World) and push.action_names == ("p", "psi", "ell")

    class Still:
        def reset(self, goal, seed=None):
            assert goal.image.shape == (1, 32, 32)

        def act(self, observation):
            return np.zeros(3, np.float32)

    (episode,) = run_closed_loop(push, Still(), episodes=1, max_steps=2, seed=0)
    assert episode.steps == 2 and set(episode.reached) == {"course", "strict"}
    np.testing.assert_allclose(episode.final_state[:2], episode.task.start[:2], atol=2e-3)
    assert push.success(episode.task.goal, episode.task.goal) == {"course": True, "strict": True}
