"""`PendulumImageEnv`: gymnasium's Pendulum-v1 seen through a small camera.

The physics are Pendulum-v1's (:mod:`.physics`, the same numbers step for step); the
observation is a (2, S, S) uint8 image, the rod a step ago and now (:mod:`.render`). The
reward is Pendulum-v1's, −(θ² + 0.1 θ̇² + 0.001 u²) with θ wrapped; this project's planners
do not read it. Episodes never end by themselves (wrap in ``TimeLimit`` for a horizon).

    env = PendulumImageEnv(PendulumConfig(start="random"))
    obs, info = env.reset(seed=0)                        # or options={"start": (θ, θ̇)}
    obs, reward, terminated, truncated, info = env.step(np.array([2.0], np.float32))
    info["state"]                                        # (θ, θ̇), θ in [−π, π)
"""

from __future__ import annotations

from typing import ClassVar

import gymnasium as gym
import numpy as np

import latent_sindy.worlds.pendulum.physics as physics
from latent_sindy.worlds.pendulum.config import PendulumConfig
from latent_sindy.worlds.pendulum.render import observe

__all__ = ["PendulumImageEnv", "sample_start"]


def sample_start(config: PendulumConfig, rng: np.random.Generator) -> np.ndarray:
    """A start state (θ, θ̇) of the kind ``config.start`` names, drawn with ``rng``."""
    if config.start == "hanging":
        p = config.perturbation
        theta, rate = np.pi + rng.uniform(-p, p), rng.uniform(-p, p)
    else:
        theta, rate = rng.uniform(-np.pi, np.pi), rng.uniform(-1.0, 1.0)
    return np.array([physics.wrap_angle(theta), rate])


class PendulumImageEnv(gym.Env):
    """A torque-driven pendulum to swing up and balance, seen as two stacked frames."""

    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(self, config: PendulumConfig | None = None) -> None:
        self.config = config or PendulumConfig()
        s = self.config.image_size
        self.observation_space = gym.spaces.Box(0, 255, (2, s, s), np.uint8)
        self.action_space = gym.spaces.Box(-physics.MAX_TORQUE, physics.MAX_TORQUE, (1,),
                                           np.float32)
        self.state = np.array([np.pi, 0.0])  # (θ, θ̇)

    def observation(self, state: np.ndarray | None = None) -> np.ndarray:
        """The image (2, S, S) uint8 of ``state`` (default: the current one)."""
        theta, rate = self.state if state is None else np.asarray(state, np.float64)
        return observe(theta, rate, self.config.image_size)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode at ``options["start"]`` (θ, θ̇), or at a start drawn from the
        seed as the config's ``start`` says."""
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - {"start"}
        if unknown:
            raise ValueError(f"unknown reset options {sorted(unknown)}: use start")
        if options.get("start") is not None:
            start = np.asarray(options["start"], np.float64)
            if start.shape != (2,) or not np.all(np.isfinite(start)):
                raise ValueError(f"start {options['start']!r}: give a finite (θ, θ̇)")
            start = np.array([physics.wrap_angle(start[0]),
                              np.clip(start[1], -physics.MAX_SPEED, physics.MAX_SPEED)])
        else:
            start = sample_start(self.config, self.np_random)
        self.state = start
        return self.observation(), {"state": self.state.copy()}

    def step(self, action: np.ndarray):
        u = float(np.clip(np.asarray(action, np.float64).reshape(-1)[0],
                          -physics.MAX_TORQUE, physics.MAX_TORQUE))
        theta, rate = self.state
        reward = -(physics.wrap_angle(theta) ** 2 + 0.1 * rate ** 2 + 0.001 * u ** 2)
        self.state = np.array(physics.step(theta, rate, u), np.float64)
        return self.observation(), float(reward), False, False, {"state": self.state.copy()}

    def render(self) -> np.ndarray:
        """The current frame, 4× larger, as RGB (for people)."""
        frame = observe(*self.state, 4 * self.config.image_size)[1]
        return np.repeat(frame[..., None], 3, axis=-1)
