"""The pushing world's plug-in (entry point ``push`` of ``latent_sindy.worlds``).

:data:`WORLD` is the object the core asks about this world: its settings from a data file's or
run's record, its data checks and model settings, and, as a
:class:`~latent_sindy.control.world.World`, the closed loop's questions (environment, tasks,
goal image, state, success criteria). The simulator loads only when an environment is made.

Its study (``latent-sindy reproduce``, the default world's) enters through its
``reproduce`` hook like every world's: the paper's Table I and what we add to it
(:mod:`latent_sindy.worlds.push.study`), on a named world (:data:`~.config.ENV_PRESETS`:
``--world paper`` runs the study in the paper's world).

    from latent_sindy.plugins import get_world
    world = get_world("push")              # or PushWorld(PushEnvConfig.named("paper"))
    results = run_closed_loop(world, ImagePolicy(planner), episodes=10, max_steps=20)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np

from latent_sindy.control.mppi import MPPIConfig
from latent_sindy.control.world import Task
from latent_sindy.errors import UserError
from latent_sindy.worlds.push import data as _data
from latent_sindy.worlds.push import library as _library  # noqa: F401  (registers the libraries)
from latent_sindy.worlds.push.config import ENV_PRESETS, WORLD_ABOUT, PushEnvConfig
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

    # ------------------------------------------------------ latent-sindy reproduce
    @property
    def about(self) -> str:
        """A line on its study for ``reproduce --help``, with its named worlds."""
        named = "; ".join(f"{name} ({WORLD_ABOUT[name]})" for name in ENV_PRESETS)
        return ("the paper's study: Table I beside ours, SINDy orders 1-4, the linear (E2C) "
                "and MLP baselines and more on the same data, closed-loop control in latent "
                f"and image space, on a named pushing world: {named}")

    #: The named worlds its study runs on, ``reproduce --world NAME`` (symmetric: this
    #: world's default).
    named_worlds = ENV_PRESETS

    @property
    def scales(self) -> dict[str, str]:
        """``reproduce --scale`` names of this world's study, with what each runs."""
        from latent_sindy.worlds.push.study.scales import SCALE_ABOUT

        return SCALE_ABOUT

    @property
    def study_flags(self) -> type:
        """The push study's own options: flags of ``reproduce`` (push is the default world)."""
        from latent_sindy.worlds.push.study.config import PushStudyOptions

        return PushStudyOptions

    @property
    def study_options(self) -> tuple[str, ...]:
        """The options its study takes: where its jobs run, and :attr:`study_flags`."""
        return ("workers", "executor", "ray_address", "gpus",
                *(f.name for f in fields(self.study_flags)))

    def reproduce(self, scale: str, out: Path, seeds: tuple[int, ...] | None = None,
                  device: str = "auto", threads: int = 1,
                  say: Callable[[str], None] = print, workers: int = 2,
                  executor: str = "local", ray_address: str | None = None, gpus: float = 0.0,
                  **options: Any) -> Any:
        """The push study at ``scale`` in ``out`` (finished pieces reused) on this world's
        named world, ``workers`` jobs at a time on the ``executor``, with the
        :attr:`study_flags` ``options``: a :class:`~latent_sindy.world_study.WorldStudy`
        (Table I, every number, the study's page). It trains on the CPU (on Ray: ``gpus``)."""
        from latent_sindy.worlds.push.study.config import PushStudyConfig
        from latent_sindy.worlds.push.study.pipeline import push_study

        if device == "cuda":
            raise UserError("--device cuda: the push study trains on the CPU (on Ray: "
                            "--executor ray --gpus N): drop --device")
        named = self.config.world_name
        if named is None or PushEnvConfig.named(named) != self.config:
            raise UserError(f"--world-config: the push study runs a named world as it is "
                            f"(--world {', '.join(ENV_PRESETS)}; --image-size for the size of "
                            "its images)")
        config = PushStudyConfig(scale=scale, out=out, seeds=tuple(seeds or (0,)), world=named,
                                 workers=workers, threads=threads, executor=executor,
                                 ray_address=ray_address, gpus=gpus, **options)
        return push_study(config, say)

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
