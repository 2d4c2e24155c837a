"""A Gymnasium environment seen through its own ``rgb_array`` frames, as a gymnasium
environment of stacked square frames.

``gym.make(id, render_mode="rgb_array")``; one ``step(action)`` repeats the action
``action_repeat`` steps of the environment, sums its rewards over them, renders one frame
(``env.render()``: (H, W, 3) uint8), resizes it to ``size`` × ``size`` by area (a frame that
is not square is squeezed) and returns the last ``frames`` frames stacked as channels (oldest
first; after a reset the first frame fills the stack). The episode ends where the
environment's does (its own end or its time limit); stepping on after it is refused. The
true state is the environment's observation, flattened.

    env = GymPixelEnv(GymConfig(id="Pendulum-v1", size=32))
    image, _ = env.reset(seed=0)                        # (6, 32, 32) uint8
    image, reward, terminated, truncated, info = env.step(np.array([0.5], np.float32))
"""

from __future__ import annotations

import os
from collections import deque
from typing import Any

import gymnasium as gym
import numpy as np

from latent_sindy.errors import UserError
from latent_sindy.worlds.gym.config import GymConfig

__all__ = ["INSTALL", "GymPixelEnv", "make"]

INSTALL = "pip install 'latent-sindy[gym]'"
_GRAY = np.array([0.2989, 0.587, 0.114])


def _missing(config: GymConfig, e: Exception) -> UserError:
    first = str(e).splitlines()[0] if str(e) else type(e).__name__
    return UserError(f"gym {config.id} cannot render its frames ({first}): {INSTALL} "
                     "(gymnasium[classic-control], i.e. pygame) for the classic-control "
                     "environments; others need the extra gymnasium names")


def make(config: GymConfig) -> Any:
    """``gym.make(config.id, render_mode="rgb_array")``, its action space checked (a Box):
    UserError for an id gymnasium cannot make or an action space that is not a Box. pygame
    (classic control's renderer) draws off screen, without its greeting, unless the user
    chose otherwise (``SDL_VIDEODRIVER``, ``PYGAME_HIDE_SUPPORT_PROMPT``)."""
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    try:
        env = gym.make(config.id, render_mode="rgb_array")
    except gym.error.DependencyNotInstalled as e:
        raise _missing(config, e) from e
    except (gym.error.Error, ModuleNotFoundError) as e:
        first = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise UserError(f"gym id {config.id!r} is not an environment gymnasium can make "
                        f"({first}): use a registered id (e.g. Pendulum-v1), or "
                        "module:Name-v0 to import the module that registers yours") from e
    space = env.action_space
    if not isinstance(space, gym.spaces.Box):
        env.close()
        raise UserError(f"gym {config.id}: its action space is {space}, not a Box: the gym "
                        "world plans continuous actions in a box (Discrete and other spaces "
                        "are not supported)")
    if not (np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high))):
        env.close()
        raise UserError(f"gym {config.id}: its action box {space} is unbounded: the gym "
                        "world samples and plans actions in a bounded box")
    return env


class GymPixelEnv(gym.Env):
    """A Gymnasium environment seen by its renderer: observations (frames × C, S, S) uint8."""

    def __init__(self, config: GymConfig) -> None:
        self.config = config
        self.env = make(config)
        space = self.env.action_space
        self.action_low = np.asarray(space.low, np.float64).reshape(-1)
        self.action_high = np.asarray(space.high, np.float64).reshape(-1)
        s = config.size
        self.observation_space = gym.spaces.Box(0, 255, (config.channels, s, s), np.uint8)
        self.action_space = gym.spaces.Box(self.action_low.astype(np.float32),
                                           self.action_high.astype(np.float32))
        self._frames: deque[np.ndarray] = deque(maxlen=config.frames)
        self._state = np.zeros(0)
        self._ended = True  # until the first reset
        self._steps = 0

    @property
    def dt(self) -> float | None:
        """Seconds between two observations: the environment's ``dt`` (or one frame of its
        ``render_fps``) times the action repeat; None where it says neither."""
        dt = getattr(self.env.unwrapped, "dt", None)
        if not isinstance(dt, int | float) or isinstance(dt, bool) or not dt > 0:
            fps = (self.env.metadata or {}).get("render_fps")
            dt = 1.0 / fps if isinstance(fps, int | float) and fps > 0 else None
        return None if dt is None else float(dt) * self.config.action_repeat

    def render_frame(self) -> np.ndarray:
        """The renderer's picture now, resized: (C, S, S) uint8, C = 3 colours or 1 gray."""
        try:
            rgb = self.env.render()
        except gym.error.DependencyNotInstalled as e:
            raise _missing(self.config, e) from e
        if not (isinstance(rgb, np.ndarray) and rgb.ndim == 3 and rgb.shape[2] in (3, 4)
                and rgb.dtype == np.uint8 and min(rgb.shape[:2]) > 0):
            got = (f"an array {rgb.shape} {rgb.dtype}" if isinstance(rgb, np.ndarray)
                   else type(rgb).__name__)
            raise UserError(f"gym {self.config.id}: render() gave {got}, not an (H, W, 3) "
                            "uint8 frame: the gym world needs render_mode 'rgb_array' "
                            f"(the environment's modes: {self.env.metadata.get('render_modes')})")
        rgb = rgb[..., :3]
        s = self.config.size
        if rgb.shape[:2] != (s, s):
            from PIL import Image

            rgb = np.asarray(Image.fromarray(np.ascontiguousarray(rgb)).resize(
                (s, s), Image.Resampling.BOX))
        if self.config.gray:
            return np.round(rgb @ _GRAY).clip(0, 255).astype(np.uint8)[None]
        return np.ascontiguousarray(rgb.transpose(2, 0, 1))

    def observation(self) -> np.ndarray:
        return np.concatenate(list(self._frames), axis=0)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """The environment's own reset (seeded by ``seed``); the first frame fills the
        stack."""
        super().reset(seed=seed)
        obs, _ = self.env.reset(seed=seed, options=options)
        self._state = self._flat(obs)
        self._ended = False
        self._steps = 0
        frame = self.render_frame()
        for _ in range(self.config.frames):
            self._frames.append(frame)
        return self.observation(), {"state": self.state()}

    def step(self, action: np.ndarray):
        if self._ended:
            raise UserError(f"gym {self.config.id} ended its episode after {self._steps} "
                            "actions (its own end or its time limit): use episodes no longer "
                            "than that, or reset the environment before stepping again")
        space = self.env.action_space
        u = np.clip(np.asarray(action, np.float64).reshape(-1), self.action_low,
                    self.action_high).reshape(space.shape).astype(space.dtype)
        reward = 0.0
        terminated = False
        truncated = False
        for _ in range(self.config.action_repeat):
            obs, r, terminated, truncated, _ = self.env.step(u)
            reward += float(r)
            self._state = self._flat(obs)
            if terminated or truncated:
                self._ended = True
                break
        self._steps += 1
        self._frames.append(self.render_frame())
        return (self.observation(), reward, bool(terminated), bool(truncated),
                {"state": self.state()})

    def _flat(self, obs: Any) -> np.ndarray:
        try:
            return np.asarray(gym.spaces.flatten(self.env.observation_space, obs),
                              np.float64).reshape(-1)
        except (NotImplementedError, TypeError, ValueError):
            return np.zeros(0)

    def state(self) -> np.ndarray:
        """The environment's last observation, flattened (float64)."""
        return self._state.copy()

    def close(self) -> None:
        self.env.close()
