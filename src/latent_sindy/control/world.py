"""The world interface: what closed-loop control needs of a system it acts in.

A world is a small object around a gymnasium environment whose observations are images. It
names its action box, samples tasks (a start and a goal state), resets the environment into a
task, renders the goal as the camera would see it, reads the true state, and says which
success criteria a state meets. Worlds live in their own packages
(``latent_sindy.worlds.<name>``) and are found by name (:mod:`latent_sindy.plugins`); the core
only ever sees this interface.

    class Slider:                                 # a world in a few lines (tests/test_world.py)
        name = "slider"; action_low = (-1.0,); action_high = (1.0,); action_names = ("v",)
        def make_env(self): ...
        def sample_task(self, rng): return Task(start=..., goal=...)
        def reset(self, env, task, seed): return image            # (C, H, W)
        def goal_image(self, env, task): return image
        def state(self, env): return env.unwrapped.x
        def success(self, state, goal): return {"reached": abs(state - goal) < 0.05}

A world may also answer which actions it can carry out: ``feasible(states (K, ns), actions
(K, nu)) -> (K,) bool`` (a robot that cannot reach where an action starts skips it). It is
optional; :func:`feasible` asks a world that has it and takes every action as feasible
otherwise. Closed loops that know the true state use it to replace a planned action the
world would skip.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from latent_sindy.plugins import hook

__all__ = ["Task", "World", "feasible"]


@dataclass(frozen=True)
class Task:
    """One episode's problem: the state it starts in and the state to reach."""

    start: np.ndarray
    goal: np.ndarray


@runtime_checkable
class World(Protocol):
    """A system seen through a camera, as closed-loop control needs it."""

    name: str
    action_low: Sequence[float]
    action_high: Sequence[float]
    action_names: Sequence[str]

    def make_env(self) -> Any:
        """A gymnasium environment whose ``step(action)`` acts in the world."""

    def sample_task(self, rng: np.random.Generator) -> Task:
        """A random task (start and goal state) drawn with ``rng``."""

    def reset(self, env: Any, task: Task, seed: int) -> np.ndarray:
        """Put ``env`` at the task's start; returns the observation image (C, H, W)."""

    def image(self, observation: Any) -> np.ndarray:
        """The camera image (C, H, W) of an observation that ``env.step`` returned."""

    def goal_image(self, env: Any, task: Task) -> np.ndarray:
        """The image (C, H, W) the camera would show with the world at the task's goal."""

    def state(self, env: Any) -> np.ndarray:
        """The true state of ``env`` now (for success criteria and reference rows)."""

    def success(self, state: np.ndarray, goal: np.ndarray) -> dict[str, bool]:
        """Which success criteria ``state`` meets for ``goal`` (criterion name -> met)."""


def feasible(world: World, states: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """(K,) bool: which ``actions`` (K, nu) ``world`` can carry out from ``states`` (K, ns)
    or one state (ns,); all of them for a world without a ``feasible`` method."""
    actions = np.asarray(actions)
    answer = hook(world, "feasible")
    if answer is None:
        return np.ones(len(actions), dtype=bool)
    return np.asarray(answer(states, actions), dtype=bool).reshape(len(actions))
