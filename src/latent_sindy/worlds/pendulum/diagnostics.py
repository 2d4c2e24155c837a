"""Which half of an image planner fails: its cost or its dynamics.

:class:`TrueDynamicsImageCost` plans with MPPI on the *true* dynamics of the state features
but scores every predicted state by a latent cost of the *image* that state shows (the state
rendered, encoded by the model, the cost read from a table over (θ, θ̇)). If this swings up
while the image model's own planner does not, the cost from images is good enough and the
latent dynamics are what fail. It reads the true state, so it is a diagnostic, never a
result from images.

    >>> policy = TrueDynamicsImageCost(model, cost, image_size=16, mppi=MPPIConfig(...))
    >>> run_swing_up(world, policy, episodes=10)
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

import latent_sindy.worlds.pendulum.physics as physics
from latent_sindy.api import LatentSINDy
from latent_sindy.control.episodes import Observation
from latent_sindy.control.mppi import MPPI, MPPIConfig
from latent_sindy.worlds.pendulum.render import observe

__all__ = ["TrueDynamicsImageCost", "state_table"]


@torch.no_grad()
def state_table(model: LatentSINDy, cost: Callable[[torch.Tensor], torch.Tensor],
                image_size: int, angles: int = 73, rates: int = 33) -> torch.Tensor:
    """The latent ``cost`` of the encoded image of every state of a grid: (angles, rates)
    over θ in [−π, π] and θ̇ in [−8, 8]."""
    theta, rate = np.meshgrid(np.linspace(-np.pi, np.pi, angles),
                              np.linspace(-physics.MAX_SPEED, physics.MAX_SPEED, rates),
                              indexing="ij")
    z = torch.as_tensor(model.encode(observe(theta.ravel(), rate.ravel(), image_size)))
    return cost(z).reshape(angles, rates).float()


class TrueDynamicsImageCost:
    """MPPI on the true feature dynamics with a latent cost of each state's image."""

    def __init__(self, model: LatentSINDy, cost: Callable[[torch.Tensor], torch.Tensor],
                 image_size: int, mppi: MPPIConfig) -> None:
        self.table = state_table(model, cost, image_size)  # (A, R)
        self.config = mppi

        def table_cost(x: torch.Tensor) -> torch.Tensor:  # x (..., 3) -> (...)
            a, r = self.table.shape
            theta = torch.atan2(x[..., 1], x[..., 0])
            i = ((theta + np.pi) / (2 * np.pi) * (a - 1)).round().long().clamp(0, a - 1)
            rate = x[..., 2].clamp(-physics.MAX_SPEED, physics.MAX_SPEED)
            j = ((rate / physics.MAX_SPEED + 1) / 2 * (r - 1)).round().long().clamp(0, r - 1)
            return self.table[i, j]

        self.mppi = MPPI(physics.feature_step, table_cost, mppi, (-physics.MAX_TORQUE,),
                         (physics.MAX_TORQUE,))

    def reset(self, goal: Observation, seed: int | None = None) -> None:
        self.mppi.reset(seed)

    def act(self, observation: Observation) -> np.ndarray:
        x = torch.tensor(physics.features(observation.state), dtype=torch.float32)  # (3,)
        return self.mppi.command(x)[0].numpy()
