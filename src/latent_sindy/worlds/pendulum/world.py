"""The controlled pendulum as a :class:`~latent_sindy.control.world.World`: swing up from
hanging (or from anywhere) to upright at rest, seen through two stacked 48×48 frames; its data
checks and random-torque collection. Its plug-in (:mod:`.plugin`) adds the world's study.
Gymnasium loads only when an environment is made.

    world = PendulumWorld(PendulumConfig(start="random"))
    data = world.collect(sequences=100, steps=10, seed=0)
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

import latent_sindy.worlds.pendulum.physics as physics
from latent_sindy.configs import from_json, to_json
from latent_sindy.control.collect import collect_random
from latent_sindy.control.mppi import MPPIConfig
from latent_sindy.control.world import Task
from latent_sindy.data.sequence import SequenceData
from latent_sindy.errors import UserError
from latent_sindy.worlds.pendulum.config import PendulumConfig
from latent_sindy.worlds.pendulum.criteria import UPRIGHT_DEG
from latent_sindy.worlds.pendulum.render import observe

__all__ = ["STATE_NAMES", "UPRIGHT", "PendulumWorld"]

STATE_NAMES = ("θ", "θ_dot")
UPRIGHT = np.array([0.0, 0.0])  # the goal: upright at rest


class PendulumWorld:
    """The torque-driven pendulum (Pendulum-v1's physics) seen by a camera."""

    name = "pendulum"
    action_low = (-physics.MAX_TORQUE,)
    action_high = (physics.MAX_TORQUE,)
    action_names = ("torque",)

    def __init__(self, config: PendulumConfig | None = None) -> None:
        self.config = config or PendulumConfig()

    # ------------------------------------------------------ what the core asks of its data
    @staticmethod
    def config_from_record(record: dict[str, Any], where: str) -> PendulumConfig:
        if "pendulum" not in record:
            raise UserError(f"{where}: the pendulum's record lacks its settings ('pendulum')")
        return from_json(PendulumConfig, record["pendulum"], f"{where}: pendulum")

    @classmethod
    def check_data(cls, data: SequenceData) -> None:
        """UserError unless ``data`` has this world's frames (2, S, S) and one torque."""
        cfg = cls.config_from_record(data.record, data.source)
        s = cfg.image_size
        if data.frame_shape != (2, s, s) or data.action_names != cls.action_names:
            raise UserError(f"{data.source}: pendulum data need frames (2, {s}, {s}) and one "
                            f"action 'torque', got frames {data.frame_shape} and actions "
                            f"{data.action_names}")

    def collect(self, sequences: int, steps: int, seed: int = 0) -> SequenceData:
        """Random torques from the box, from starts of this world's tasks: images, actions,
        states (θ, θ̇) and the world's record."""
        data = collect_random(self, sequences, steps, seed)
        return data.replace(state_names=STATE_NAMES, state_periods=(2 * math.pi, None),
                            dt=physics.DT, world=self.name,
                            record={"pendulum": to_json(self.config),
                                    "collection": {"sequences": sequences, "steps": steps,
                                                   "seed": seed, "actions": "uniform"}},
                            source=f"<random torques in the pendulum, seed {seed}>")

    # ------------------------------------------------------ the world interface
    def planner(self) -> MPPIConfig:
        """Settings of MPPI for the swing-up (measured with the true dynamics)."""
        return MPPIConfig(samples=500, horizon=30, sigma=1.0, lambda_=1.0)

    def make_env(self) -> Any:
        from latent_sindy.worlds.pendulum.env import PendulumImageEnv

        return PendulumImageEnv(self.config)

    def sample_task(self, rng: np.random.Generator) -> Task:
        from latent_sindy.worlds.pendulum.env import sample_start

        return Task(start=sample_start(self.config, rng), goal=UPRIGHT.copy())

    def reset(self, env: Any, task: Task, seed: int) -> np.ndarray:
        return env.reset(seed=seed, options={"start": task.start})[0]

    def image(self, observation: Any) -> np.ndarray:
        return observation

    def goal_image(self, env: Any, task: Task) -> np.ndarray:
        theta, rate = np.asarray(task.goal, np.float64)
        return observe(theta, rate, self.config.image_size)

    def state(self, env: Any) -> np.ndarray:
        return env.state.copy()

    def success(self, state: np.ndarray, goal: np.ndarray) -> dict[str, bool]:
        """"upright": θ within 10° of the goal's angle (the rate is not asked)."""
        error = physics.wrap_angle(float(state[0]) - float(goal[0]))
        return {"upright": bool(abs(error) <= math.radians(UPRIGHT_DEG))}
