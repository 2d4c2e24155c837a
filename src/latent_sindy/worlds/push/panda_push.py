"""`PandaPushEnv`: the planar pushing task as a gymnasium environment.

One `step` is one whole push u = [p, angle, ell]; the config's `push` style says what the
angle means and owns the action box (``config.action_low`` .. ``action_high``). The
observation is the 32x32 overhead camera image, uint8, channels first. `info` carries the
block's true pose and the errors to the goal, the orientation error taken modulo the
block's visible symmetry (``config.angle_period``).

    import gymnasium as gym, latent_sindy
    env = gym.make("latent_sindy/PandaPush-v0")              # the default (symmetric) world
    env = gym.make("latent_sindy/PandaPush-v0", push="paper")  # the paper's world
    env = PandaPushEnv(PushEnvConfig.named("textured"))  # each reset's seed draws its look
    obs, info = env.reset(seed=0, options={"task": "paper"})
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
"""

from __future__ import annotations

from typing import Any, ClassVar

import gymnasium as gym
import numpy as np

from latent_sindy.configs import from_json, to_json
from latent_sindy.worlds.push.config import PAPER_GOAL, PAPER_START, PushEnvConfig
from latent_sindy.worlds.push.criteria import goal_criteria
from latent_sindy.worlds.push.registration import register_env
from latent_sindy.worlds.push.scene import draw_look
from latent_sindy.worlds.push.world import PushWorld

_ACTION_SLACK = 1e-4  # float32 round-off at the box's edges is not an error


class PandaPushEnv(gym.Env):
    """A Franka Panda pushes a block on a table towards a goal pose, seen from above.

    Reward is the negative distance (m) from block to goal, for RL users; this project's
    controllers do not use it. `terminated` is true when the block leaves the workspace
    (`bounds_low`..`bounds_high`); success is reported in `info` and does not end the episode.
    """

    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(self, config: PushEnvConfig | None = None, render_mode: str | None = None,
                 **overrides: Any) -> None:
        cfg = config or PushEnvConfig()
        if overrides:
            cfg = from_json(PushEnvConfig, {**to_json(cfg), **overrides}, "environment")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode={render_mode!r}: use None or 'rgb_array'")
        self.config = cfg
        self.render_mode = render_mode
        s = cfg.image_size
        self.observation_space = gym.spaces.Box(0, 255, (cfg.channels, s, s), np.uint8)
        self._a_low = np.array(cfg.action_low, dtype=np.float32)
        self._a_high = np.array(cfg.action_high, dtype=np.float32)
        self.action_space = gym.spaces.Box(self._a_low, self._a_high, dtype=np.float32)
        self._world = PushWorld(cfg)
        self._low = np.array(cfg.workspace_low)
        self._high = np.array(cfg.workspace_high)

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode.

        options: {"task": "paper"} for the paper's start and goal; {"start": (x, y, theta),
        "goal": (x, y, theta)} for explicit poses (either may be left out and is then
        sampled); nothing: both sampled uniformly in the workspace from the seed.
        """
        super().reset(seed=seed)
        options = dict(options or {})
        task = options.pop("task", None)
        if task == "paper":
            options.setdefault("start", PAPER_START)
            options.setdefault("goal", PAPER_GOAL)
        elif task not in (None, "random"):
            raise ValueError(f"task={task!r}: use 'paper' or 'random'")
        unknown = set(options) - {"start", "goal"}
        if unknown:
            raise ValueError(f"unknown reset options {sorted(unknown)}: use task, start, goal")
        start = self._pose(options.get("start"), "start")
        goal = self._pose(options.get("goal"), "goal")
        look = None
        if self.config.varies_by_episode:  # drawn after the poses, which stay as elsewhere
            look = draw_look(self.config, int(self.np_random.integers(2**63)))
        self._world.reset(start, goal, look)
        return self._world.observe(), self._info()

    def step(self, action):
        cfg = self.config
        low, high = self._a_low, self._a_high
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        if a.shape != (cfg.action_dim,) or not np.all(np.isfinite(a)):
            raise ValueError(f"action {action!r} must be {cfg.action_dim} finite numbers "
                             f"[{', '.join(cfg.action_names)}]")
        if np.any(a < low - _ACTION_SLACK) or np.any(a > high + _ACTION_SLACK):
            raise ValueError(
                f"action {a.tolist()} is outside the action box "
                f"[{low.tolist()}, {high.tolist()}]; clip it first")
        a = np.clip(a, low, high)
        self._world.push(*a)  # a push out of the arm's reach is skipped: info["push_executed"]
        info = self._info()
        terminated = not info["in_bounds"]
        return self._world.observe(), -info["distance"], terminated, False, info

    def render(self):
        if self.render_mode == "rgb_array":
            return self._world.render_rgb()
        return None

    def close(self) -> None:
        self._world.close()

    # ------------------------------------------------------------------ extras
    def goal_observation(self) -> np.ndarray:
        """The image the camera would see with the block resting at the goal pose."""
        return self._world.observe(self._world.goal_pose)

    def observe(self, pose=None) -> np.ndarray:
        """The camera image with the block at `pose` (default: its current pose)."""
        return self._world.observe(pose)

    @property
    def world(self) -> PushWorld:
        return self._world

    def sample_pose(self) -> np.ndarray:
        """A pose uniform in the workspace, from the environment's seeded generator."""
        return self.np_random.uniform(self._low, self._high)

    def _pose(self, pose, what: str) -> np.ndarray:
        if pose is None:
            return self.sample_pose()
        p = np.asarray(pose, dtype=float).reshape(-1)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ValueError(f"{what} pose {pose!r} must be 3 finite numbers (x, y, theta)")
        return p

    def _info(self) -> dict:
        cfg = self.config
        pose = self._world.block_pose()
        goal = self._world.goal_pose
        in_bounds = bool(np.all(pose[:2] >= cfg.bounds_low) and np.all(pose[:2] <= cfg.bounds_high))
        return {
            "pose": pose,
            "goal": goal.copy(),
            **goal_criteria(cfg, pose, goal),
            "in_bounds": in_bounds,
            "push_executed": self._world.last_push_executed,
        }

register_env()  # gymnasium.make("latent_sindy/PandaPush-v0") works once this module is loaded
