"""The DeepMind Control world: a suite task (``DmcConfig.task``, cartpole-swingup by default) as a
:class:`~latent_sindy.control.world.World`: random-action data of any task, with the task's
rewards and the physics state; and, for the tasks whose goal is a pose (the cartpoles and
the pendulum's swing-up: the pole upright, at rest), goal images and success criteria for
closed-loop control. Other tasks are scored by their reward alone: they collect data, and a
closed loop toward a goal image refuses them. Importing this module does not import dm_control.

    from latent_sindy.worlds.dmc.world import DmcWorld
    from latent_sindy.worlds.dmc.config import DmcConfig
    data = DmcWorld(DmcConfig(task="reacher-easy", size=32)).collect(10, 20, seed=0)

    latent-sindy collect --world dmc --world-config task=reacher-easy size=32 ...
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np

from latent_sindy.configs import from_json, to_json
from latent_sindy.control.collect import collect_random
from latent_sindy.control.world import Task
from latent_sindy.data.sequence import SequenceData
from latent_sindy.errors import UserError
from latent_sindy.worlds.dmc.config import DmcConfig

__all__ = ["GOALS", "DmcWorld"]

#: Tasks whose goal is a pose, the all-zero state (pole upright, cart centred, at rest): the
#: index of the pole's angle in the physics state and the largest angle counted as upright
#: (the pendulum's: its sparse reward's own 8°; the cartpole's: the controlled pendulum's 10°).
GOALS = {**{f"cartpole-{t}": (1, 10.0) for t in ("swingup", "swingup_sparse", "balance",
                                                  "balance_sparse")},
         "pendulum-swingup": (0, 8.0)}


@dataclass(frozen=True)
class _Description:
    """What a task's model says of its actions and state (read once per task)."""

    action_low: tuple[float, ...]
    action_high: tuple[float, ...]
    action_names: tuple[str, ...]
    state_names: tuple[str, ...]
    state_periods: tuple[float | None, ...]
    dt: float


@cache
def _describe(config: DmcConfig) -> _Description:
    from latent_sindy.worlds.dmc.env import physics_names
    from latent_sindy.worlds.dmc.suite import load

    env = load(config)
    try:
        spec = env.action_spec()
        model = env.physics.model
        names, periods = physics_names(env.physics)
        return _Description(
            tuple(np.broadcast_to(spec.minimum, spec.shape).astype(float).tolist()),
            tuple(np.broadcast_to(spec.maximum, spec.shape).astype(float).tolist()),
            tuple(model.id2name(i, "actuator") or f"u{i}" for i in range(model.nu)),
            names, periods, float(env.control_timestep()) * config.action_repeat)
    finally:
        env.close()


class DmcWorld:
    """A DeepMind Control suite task seen by its camera, frames stacked as channels."""

    name = "dmc"

    def __init__(self, config: DmcConfig | None = None) -> None:
        self.config = config or DmcConfig()

    @property
    def action_low(self) -> tuple[float, ...]:
        return _describe(self.config).action_low

    @property
    def action_high(self) -> tuple[float, ...]:
        return _describe(self.config).action_high

    @property
    def action_names(self) -> tuple[str, ...]:
        return _describe(self.config).action_names

    # ------------------------------------------------------ what the core asks of its data
    @staticmethod
    def config_from_record(record: dict[str, Any], where: str) -> DmcConfig:
        if "dmc" not in record:
            raise UserError(f"{where}: the dmc world's record lacks its settings ('dmc')")
        return from_json(DmcConfig, record["dmc"], f"{where}: dmc")

    @classmethod
    def check_data(cls, data: SequenceData) -> None:
        """UserError unless ``data`` has the frames its record's settings make."""
        cfg = cls.config_from_record(data.record, data.source)
        shape = (cfg.channels, cfg.size, cfg.size)
        if data.frame_shape != shape:
            raise UserError(f"{data.source}: dmc data of {cfg.task} need frames {shape}, got "
                            f"{data.frame_shape}")

    def collect(self, sequences: int, steps: int, seed: int = 0) -> SequenceData:
        """Uniform random actions from the task's own random starts: images, actions, the
        task's rewards (summed over each action's repeat), physics states and the record."""
        about = _describe(self.config)
        data = collect_random(self, sequences, steps, seed)
        return data.replace(state_names=about.state_names, state_periods=about.state_periods,
                            dt=about.dt, world=self.name,
                            record={"dmc": to_json(self.config),
                                    "collection": {"sequences": sequences, "steps": steps,
                                                   "seed": seed, "actions": "uniform"}},
                            source=f"<random actions in dmc {self.config.task}, seed {seed}>")

    # ------------------------------------------------------ the world interface
    def make_env(self) -> Any:
        from latent_sindy.worlds.dmc.env import DmcPixelEnv

        return DmcPixelEnv(self.config)

    def sample_task(self, rng: np.random.Generator) -> Task:
        """A start of the task's own distribution, named by the seed that draws it (a
        reacher's target, say, is drawn with it); the goal: the all-zero state where the
        task has a goal pose (:data:`GOALS`), else none (an empty state)."""
        seed = int(rng.integers(2**31 - 1))
        size = len(_describe(self.config).state_names) if self.config.task in GOALS else 0
        return Task(start=np.array([seed], np.float64), goal=np.zeros(size))

    def reset(self, env: Any, task: Task, seed: int) -> np.ndarray:
        return env.reset(seed=int(task.start[0]))[0]

    def image(self, observation: Any) -> np.ndarray:
        return observation

    def goal_image(self, env: Any, task: Task) -> np.ndarray:
        self._goal_pose()
        return env.picture_of(task.goal)

    def state(self, env: Any) -> np.ndarray:
        return env.state()

    def success(self, state: np.ndarray, goal: np.ndarray) -> dict[str, bool]:
        """"upright": the pole within the task's angle of vertical (:data:`GOALS`)."""
        index, degrees = self._goal_pose()
        error = math.remainder(float(state[index]) - float(goal[index]), 2 * math.pi)
        return {"upright": bool(abs(error) <= math.radians(degrees))}

    def _goal_pose(self) -> tuple[int, float]:
        if self.config.task not in GOALS:
            raise UserError(f"dmc task {self.config.task} is scored by its reward, not by a "
                            f"goal pose: a closed loop toward a goal image needs one of "
                            f"{', '.join(GOALS)} (data of any task can be collected)")
        return GOALS[self.config.task]

