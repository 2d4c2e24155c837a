"""Swing-up episodes: a fixed number of steps from a task's start, scored by the time spent
upright (E2C's measure) and by whether the pendulum stays upright to the end.

They run through the project's one closed loop (``run_closed_loop`` of
:mod:`latent_sindy.control.episodes`, the criteria only recorded), which shows a policy the
image and the true state (``act(observation)``); an image planner reads the image
(:class:`ImagePolicy` around ``LatentSINDy.planner()``), the oracle :class:`StateMPPI` reads
the state and plans with the true dynamics, to show what the task asks is achievable.

    results = run_swing_up(world, StateMPPI(), episodes=10, steps=100, seed=0)
    np.mean([r.success for r in results]), np.mean([r.upright_fraction for r in results])
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

import latent_sindy.worlds.pendulum.physics as physics
from latent_sindy.control.episodes import ImagePolicy, Observation, Policy, run_closed_loop
from latent_sindy.control.mppi import MPPI, MPPIConfig
from latent_sindy.control.world import Task
from latent_sindy.errors import UserError
from latent_sindy.worlds.pendulum.criteria import swing_up_success, upright_fraction
from latent_sindy.worlds.pendulum.world import PendulumWorld

__all__ = ["ImagePolicy", "StateMPPI", "SwingUp", "run_swing_up"]


@dataclass
class SwingUp:
    """One episode: its task, states (steps + 1, 2) from the start, actions (steps, 1), the
    fraction of the states after each action that are upright, and swing-up success."""

    task: Task
    states: np.ndarray
    actions: np.ndarray
    upright_fraction: float
    success: bool


def upright_cost(x: torch.Tensor, rate_weight: float = 0.1) -> torch.Tensor:
    """Pendulum-v1's cost of features x (..., 3): θ² + ``rate_weight`` θ̇², θ wrapped.

    Not the quadratic cost to the upright features, (cos θ − 1)² + sin² θ = 2(1 − cos θ):
    that one is flat at the bottom, so MPPI's samples from hanging all cost nearly alike
    and the plan never starts swinging (measured: no swing-up in 10 episodes)."""
    return torch.atan2(x[..., 1], x[..., 0]).square() + rate_weight * x[..., 2].square()


class StateMPPI:
    """The oracle: MPPI on the true state's features (cos θ, sin θ, θ̇), with Pendulum-v1's
    cost θ² + 0.1 θ̇² (:func:`upright_cost`), through the true dynamics or through
    ``dynamics(x (K, 3), u (K, 1)) -> (K, 3)`` (a state SINDy's step)."""

    def __init__(self, mppi: MPPIConfig | None = None,
                 dynamics: Callable[[torch.Tensor, torch.Tensor], torch.Tensor] | None = None
                 ) -> None:
        self.config = mppi or PendulumWorld().planner()
        self.mppi = MPPI(dynamics or physics.feature_step, upright_cost, self.config,
                         (-physics.MAX_TORQUE,), (physics.MAX_TORQUE,))

    def reset(self, goal: Observation, seed: int | None = None) -> None:
        self.mppi.reset(seed)

    def act(self, observation: Observation) -> np.ndarray:
        x = torch.tensor(physics.features(observation.state), dtype=torch.float32)  # (3,)
        return self.mppi.command(x)[0].numpy()


def run_swing_up(world: PendulumWorld, policy: Policy, episodes: int = 10,
                 steps: int = 100, seed: int = 0, last: int = 20) -> list[SwingUp]:
    """``episodes`` episodes of exactly ``steps`` actions on tasks the world samples with
    ``seed``; success: upright over each of the ``last`` steps."""
    if not 1 <= last <= steps:
        raise UserError(f"run_swing_up: last {last} must lie in 1..steps ({steps})")
    results = []
    for episode in run_closed_loop(world, policy, episodes, steps, seed, stop=False):
        xs = np.stack(episode.states)
        results.append(SwingUp(episode.task, xs, np.asarray(episode.actions, np.float32),
                               upright_fraction(xs[1:]), swing_up_success(xs[1:], last)))
    return results
