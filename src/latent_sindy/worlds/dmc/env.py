"""A task of the DeepMind Control suite as a gymnasium environment of stacked camera frames.

One ``step(action)`` repeats the action ``action_repeat`` control steps of the suite, sums
the task's rewards over them, renders one frame and returns the last ``frames`` frames
stacked as channels (oldest first; after a reset the first frame fills the stack). The
episode never times out (the caller decides its length); ``terminated`` is the suite's own
end of an episode, where a task has one. The true state is the physics state (MuJoCo's
positions, velocities and actuator activations).

    env = DmcPixelEnv(DmcConfig(task="cartpole-swingup", size=32))
    image, _ = env.reset(seed=0)                        # (6, 32, 32) uint8
    image, reward, terminated, truncated, info = env.step(np.array([0.5], np.float32))
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import gymnasium as gym
import numpy as np

from latent_sindy.errors import UserError
from latent_sindy.worlds.dmc.config import DmcConfig
from latent_sindy.worlds.dmc.suite import load

__all__ = ["DmcPixelEnv", "physics_names"]

_GRAY = np.array([0.2989, 0.587, 0.114])


def physics_names(physics: Any) -> tuple[tuple[str, ...], tuple[float | None, ...]]:
    """Names of the physics state's entries (a joint's position by its name, its velocity
    with ``_dot``, activations ``act<i>``) and their periods (2π for the position of a hinge
    without limits, None for the others)."""
    model = physics.model
    qpos = list(physics.named.data.qpos.axes.row.names)
    qvel = list(physics.named.data.qvel.axes.row.names)
    if len(qpos) != model.nq:  # joints of several coordinates named only once
        qpos = [f"qpos{i}" for i in range(model.nq)]
    if len(qvel) != model.nv:
        qvel = [f"qvel{i}" for i in range(model.nv)]
    periods: list[float | None] = [None] * model.nq
    for j in range(model.njnt):
        if model.jnt_type[j] == 3 and not model.jnt_limited[j]:  # mjJNT_HINGE
            periods[model.jnt_qposadr[j]] = 2 * math.pi
    size = len(physics.get_state())
    extra = size - model.nq - model.nv
    names = (*qpos, *(f"{n}_dot" for n in qvel), *(f"act{i}" for i in range(extra)))
    return names, (*periods, *(None,) * (model.nv + extra))


class DmcPixelEnv(gym.Env):
    """A suite task seen by its camera: observations (frames × C, S, S) uint8."""

    def __init__(self, config: DmcConfig) -> None:
        self.config = config
        self.dm = load(config)
        spec = self.dm.action_spec()
        self.action_low = np.asarray(spec.minimum, np.float64).reshape(spec.shape)
        self.action_high = np.asarray(spec.maximum, np.float64).reshape(spec.shape)
        s = config.size
        self.observation_space = gym.spaces.Box(0, 255, (config.channels, s, s), np.uint8)
        self.action_space = gym.spaces.Box(self.action_low.astype(np.float32),
                                           self.action_high.astype(np.float32))
        self._frames: deque[np.ndarray] = deque(maxlen=config.frames)
        self._ended = True  # until the first reset

    @property
    def physics(self) -> Any:
        return self.dm.physics

    @property
    def dt(self) -> float:
        """Seconds between two observations (control step × action repeat)."""
        return float(self.dm.control_timestep()) * self.config.action_repeat

    def render_frame(self) -> np.ndarray:
        """The camera's picture now: (C, S, S) uint8, C = 3 colours or 1 gray."""
        s = self.config.size
        rgb = self.physics.render(height=s, width=s, camera_id=self.config.camera)
        if self.config.gray:
            return np.round(rgb @ _GRAY).clip(0, 255).astype(np.uint8)[None]
        return np.ascontiguousarray(rgb.transpose(2, 0, 1))

    def observation(self) -> np.ndarray:
        return np.concatenate(list(self._frames), axis=0)

    def restack(self) -> np.ndarray:
        """Fill the stack with the frame of the physics as it is now (after a reset or a
        state set by hand); the observation."""
        frame = self.render_frame()
        for _ in range(self.config.frames):
            self._frames.append(frame)
        return self.observation()

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """A start drawn by the task's own ``initialize_episode`` (seeded by ``seed``)."""
        super().reset(seed=seed)
        if seed is not None:
            self.dm.task.random.seed(seed)
        self.dm.reset()
        self._ended = False
        return self.restack(), {"state": self.state()}

    def step(self, action: np.ndarray):
        if self._ended:
            raise UserError(f"dmc task {self.config.task} ended its episode: reset the "
                            "environment before stepping again")
        u = np.clip(np.asarray(action, np.float64).reshape(self.action_low.shape),
                    self.action_low, self.action_high)
        reward = 0.0
        for _ in range(self.config.action_repeat):
            step = self.dm.step(u)
            reward += float(step.reward or 0.0)
            if step.last():  # the task's own end (a time limit never comes: it is infinite)
                self._ended = True
                break
        self._frames.append(self.render_frame())
        return self.observation(), reward, self._ended, False, {"state": self.state()}

    def picture_of(self, state: np.ndarray) -> np.ndarray:
        """The observation the camera would give with the physics at ``state`` (every
        stacked frame the same), the environment left as it was."""
        now = self.state()
        frames = self._frames.copy()
        try:
            with self.physics.reset_context():
                self.physics.set_state(np.asarray(state, np.float64))
            return self.restack()
        finally:
            with self.physics.reset_context():
                self.physics.set_state(now)
            self._frames = frames

    def state(self) -> np.ndarray:
        return np.asarray(self.physics.get_state(), np.float64).copy()

    def close(self) -> None:
        self.dm.close()
