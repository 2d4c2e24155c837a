"""The pushing world's plug-in (entry point ``push`` of ``latent_sindy.worlds``).

:data:`WORLD` is the object the core asks about this world: its settings from a data file's or
run's record, its data checks and model settings, and, as a
:class:`~latent_sindy.control.world.World`, the closed loop's questions (environment, tasks,
goal image, state, success criteria). The simulator loads only when an environment is made.

    from latent_sindy.plugins import get_world
    world = get_world("push")              # or PushWorld(PushEnvConfig.named("paper"))
    results = run_closed_loop(world, ImagePolicy(planner), episodes=10, max_steps=20)
"""

from __future__ import annotations

from typing import Any

import numpy as np

from latent_sindy.control.mppi import MPPIConfig
from latent_sindy.control.world import Task
from latent_sindy.worlds.push import data as _data
from latent_sindy.worlds.push import library as _library  # noqa: F401  (registers the libraries)
from latent_sindy.worlds.push.config import PushEnvConfig
from latent_sindy.worlds.push.criteria import goal_criteria
from latent_sindy.worlds.push.models import prepare_model as _prepare_model
from latent_sindy.worlds.push.planner import world_planner
from latent_sindy.worlds.push.reach import Reach

__all__ = ["WORLD", "PushWorld"]


class PushWorld:
    """The Panda pushing world ``config`` (the symmetric world by default)."""

    name = "push"
    default = True
    """The CLI's default world: collect, control and reproduce take its settings as flags."""

    def __init__(self, config: PushEnvConfig | None = None) -> None:
        self.config = config or PushEnvConfig()
        self._reach: Reach | None = None

    # ------------------------------------------------------ what the core asks of its data
    @staticmethod
    def config_from_record(record: dict[str, Any], where: str) -> PushEnvConfig:
        return PushEnvConfig.from_record(record.get("env_config"), f"{where}: env_config")

    check_data = staticmethod(_data.check_data)
    prepare_model = staticmethod(_prepare_model)

    @property
    def commands(self) -> dict[str, Any]:
        """The CLI's collect, control and reproduce in this world (loaded when asked for)."""
        from latent_sindy.worlds.push.commands import COMMANDS

        return COMMANDS

    # ------------------------------------------------------ the world interface
    @property
    def action_low(self) -> tuple[float, ...]:
        return self.config.action_low

    @property
    def action_high(self) -> tuple[float, ...]:
        return self.config.action_high

    @property
    def action_names(self) -> tuple[str, ...]:
        return self.config.action_names

    def planner(self) -> MPPIConfig:
        """The planner this world's study uses."""
        return world_planner(self.config)

    def make_env(self) -> Any:
        from latent_sindy.worlds.push.panda_push import PandaPushEnv

        return PandaPushEnv(self.config)

    def sample_task(self, rng: np.random.Generator) -> Task:
        low, high = np.array(self.config.workspace_low), np.array(self.config.workspace_high)
        return Task(start=rng.uniform(low, high), goal=rng.uniform(low, high))

    def reset(self, env: Any, task: Task, seed: int) -> np.ndarray:
        return env.reset(seed=seed, options={"start": task.start, "goal": task.goal})[0]

    def image(self, observation: Any) -> np.ndarray:
        return observation

    def goal_image(self, env: Any, task: Task) -> np.ndarray:
        return env.goal_observation()

    def state(self, env: Any) -> np.ndarray:
        return env.world.block_pose()

    def success(self, state: np.ndarray, goal: np.ndarray) -> dict[str, bool]:
        """The course criterion (position within 0.1 m) and the strict one (2 cm, 10°)."""
        met = goal_criteria(self.config, np.asarray(state), np.asarray(goal))
        return {"course": met["is_success"], "strict": met["is_success_strict"]}

    def feasible(self, states: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """(K,) bool: can the arm start each push ``actions`` (K, nu) with the block at
        ``states`` (K, 3) or (3,)? The world's own IK search in a kinematic copy
        (:class:`~latent_sindy.worlds.push.reach.Reach`, built on the first call)."""
        if self._reach is None:
            self._reach = Reach(self.config)
        return self._reach(states, actions)


WORLD = PushWorld()
