"""The gym world: any Gymnasium environment with ``rgb_array`` frames (``GymConfig.id``,
Pendulum-v1 by default) as a :class:`~latent_sindy.control.world.World`: random-action data
with the environment's own rewards and its observation as the true state, and the model-based
loop (:func:`latent_sindy.model_based.model_based`) planned against a learned reward. It has no
goal pose: a closed loop toward a goal image refuses it. Importing this module does not
import gymnasium.

    from latent_sindy.worlds.gym import GymConfig, GymWorld
    data = GymWorld(GymConfig(id="Pendulum-v1", size=64)).collect(10, 200, seed=0)

    latent-sindy collect --world gym --world-config id=Pendulum-v1 size=64 ...
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np

from latent_sindy.configs import from_json, to_json
from latent_sindy.control.collect import collect_random
from latent_sindy.control.world import Task
from latent_sindy.data.sequence import SequenceData
from latent_sindy.errors import UserError
from latent_sindy.worlds.gym.config import GymConfig

__all__ = ["GymWorld", "describe"]


@dataclass(frozen=True)
class _Description:
    """What an environment says of its actions and state (read once per setting)."""

    action_low: tuple[float, ...]
    action_high: tuple[float, ...]
    state_names: tuple[str, ...]
    dt: float | None


@cache
def describe(config: GymConfig) -> _Description:
    """The environment made, reset and rendered once (so a missing renderer is said here)."""
    from latent_sindy.worlds.gym.env import GymPixelEnv

    env = GymPixelEnv(config)
    try:
        env.reset(seed=0)
        return _Description(tuple(env.action_low.tolist()), tuple(env.action_high.tolist()),
                            tuple(f"obs{i}" for i in range(len(env.state()))), env.dt)
    finally:
        env.close()


class GymWorld:
    """A Gymnasium environment seen by its renderer, frames stacked as channels."""

    name = "gym"

    def __init__(self, config: GymConfig | None = None) -> None:
        self.config = config or GymConfig()

    @property
    def action_low(self) -> tuple[float, ...]:
        return describe(self.config).action_low

    @property
    def action_high(self) -> tuple[float, ...]:
        return describe(self.config).action_high

    @property
    def action_names(self) -> tuple[str, ...]:
        return tuple(f"u{i}" for i in range(len(self.action_low)))

    # ------------------------------------------------------ what the core asks of its data
    @staticmethod
    def config_from_record(record: dict[str, Any], where: str) -> GymConfig:
        if "gym" not in record:
            raise UserError(f"{where}: the gym world's record lacks its settings ('gym')")
        return from_json(GymConfig, record["gym"], f"{where}: gym")

    @classmethod
    def check_data(cls, data: SequenceData) -> None:
        """UserError unless ``data`` has the frames its record's settings make."""
        cfg = cls.config_from_record(data.record, data.source)
        shape = (cfg.channels, cfg.size, cfg.size)
        if data.frame_shape != shape:
            raise UserError(f"{data.source}: gym data of {cfg.id} need frames {shape}, got "
                            f"{data.frame_shape}")

    def collect(self, sequences: int, steps: int, seed: int = 0) -> SequenceData:
        """Uniform random actions from the environment's own seeded resets: images, actions,
        its rewards (summed over each action's repeat), its observations as states, and the
        record."""
        about = describe(self.config)
        data = collect_random(self, sequences, steps, seed)
        return data.replace(state_names=about.state_names,
                            state_periods=(None,) * len(about.state_names), dt=about.dt,
                            world=self.name,
                            record={"gym": to_json(self.config),
                                    "collection": {"sequences": sequences, "steps": steps,
                                                   "seed": seed, "actions": "uniform"}},
                            source=f"<random actions in gym {self.config.id}, seed {seed}>")

    # ------------------------------------------------------ the world interface
    def make_env(self) -> Any:
        from latent_sindy.worlds.gym.env import GymPixelEnv

        return GymPixelEnv(self.config)

    def sample_task(self, rng: np.random.Generator) -> Task:
        """A start of the environment's own distribution, named by the seed its reset
        takes; no goal state (the world is scored by its reward)."""
        return Task(start=np.array([int(rng.integers(2**31 - 1))], np.float64),
                    goal=np.zeros(0))

    def reset(self, env: Any, task: Task, seed: int) -> np.ndarray:
        return env.reset(seed=int(task.start[0]))[0]

    def image(self, observation: Any) -> np.ndarray:
        return observation

    def goal_image(self, env: Any, task: Task) -> np.ndarray:
        raise self._no_goal()

    def state(self, env: Any) -> np.ndarray:
        return env.state()

    def success(self, state: np.ndarray, goal: np.ndarray) -> dict[str, bool]:
        raise self._no_goal()

    def _no_goal(self) -> UserError:
        return UserError(f"gym {self.config.id} is scored by its reward, not by a goal pose: "
                         "plan against a learned reward (latent_sindy.model_based, or "
                         "latent-sindy reproduce --world gym), not toward a goal image")
