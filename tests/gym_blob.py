"""A tiny Gymnasium environment for the gym world's tests, registered on import (so
``gym.make("gym_blob:BlobTest-v0")`` finds it in any process): a blob on a plane moved by a
2-D action, its frames drawn with numpy, its reward minus the squared distance to the centre.
Variants: a Discrete action space, and a renderer that is not installed."""

from __future__ import annotations

from typing import ClassVar

import gymnasium as gym
import numpy as np

STEP = 0.2  # how far a unit action moves the blob
LIMIT = 30  # the registered time limit


class Blob(gym.Env):
    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(self, render_mode: str | None = None, side: int = 40,
                 discrete: bool = False, renderer: bool = True) -> None:
        self.render_mode, self.side, self.renderer = render_mode, side, renderer
        self.action_space = (gym.spaces.Discrete(3) if discrete
                             else gym.spaces.Box(-1.0, 1.0, (2,), np.float32))
        self.observation_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.pos = np.zeros(2)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.pos = self.np_random.uniform(-0.8, 0.8, 2)
        return self.pos.astype(np.float32), {}

    def step(self, action):
        a = np.clip(np.asarray(action, np.float64).reshape(2), -1, 1)
        self.pos = np.clip(self.pos + STEP * a, -1, 1)
        return self.pos.astype(np.float32), -float(np.sum(self.pos**2)), False, False, {}

    def render(self):
        if not self.renderer:
            raise gym.error.DependencyNotInstalled(
                'pygame is not installed, run `pip install "gymnasium[classic_control]"`')
        if self.render_mode != "rgb_array":
            return None
        g = np.linspace(-1, 1, self.side)
        x, y = np.meshgrid(g, -g)
        blob = np.exp(-((x - self.pos[0]) ** 2 + (y - self.pos[1]) ** 2) / 0.03)
        frame = np.full((self.side, self.side, 3), 30, np.uint8)
        frame[..., 0] = np.round(30 + 225 * blob).astype(np.uint8)
        return frame


gym.register("BlobTest-v0", entry_point=Blob, max_episode_steps=LIMIT)
gym.register("BlobDiscrete-v0", entry_point=Blob, kwargs={"discrete": True})
gym.register("BlobNoRenderer-v0", entry_point=Blob, kwargs={"renderer": False})
