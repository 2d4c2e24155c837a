"""A tiny synthetic world for the model-based loop's tests: a bead on a rail pushed by a
velocity, seen as a bright blob in a 6x12 image, rewarded by where it ends up."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from latent_sindy.control.world import Task

H, W = 6, 12


def blob(x: float) -> np.ndarray:
    xs = np.linspace(-1, 1, W)
    row = 30 + 220 * np.exp(-((xs - x) ** 2) / 0.08)
    return np.repeat(row[None, None], H, axis=1).astype(np.uint8)  # (1, H, W)


class RailEnv(gym.Env):
    """A bead on a rail pushed by a velocity; the reward is where it ends up, (x + 1) / 2."""

    def reset(self, *, seed=None, options=None):
        self.x = float(options["start"])
        return blob(self.x), {}

    def step(self, u):
        self.x = float(np.clip(self.x + 0.3 * float(np.clip(u[0], -1, 1)), -0.9, 0.9))
        return blob(self.x), (self.x + 1) / 2, False, False, {}


class Rail:
    name, action_low, action_high, action_names = "rail", (-1.0,), (1.0,), ("v",)

    def make_env(self):
        return RailEnv()

    def sample_task(self, rng):
        return Task(start=np.array([rng.uniform(-0.8, 0.8)]), goal=np.array([0.9]))

    def reset(self, env, task, seed):
        return env.reset(seed=seed, options={"start": task.start[0]})[0]

    def image(self, observation):
        return observation

    def goal_image(self, env, task):
        return blob(float(task.goal[0]))

    def state(self, env):
        return np.array([env.x])

    def success(self, state, goal):
        return {"right": bool(state[0] > 0.8)}
