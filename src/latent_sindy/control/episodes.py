"""The closed loop every world runs through, its policies' one signature, and the loop over
any world (:class:`~latent_sindy.control.world.World`).

A policy is reset toward a goal and then asked for an action at every step:
``policy.reset(goal, seed)`` and ``policy.act(observation) -> action``, where goal and
observation are an :class:`Observation`: the camera image and, where the world gives it, its
true state (the pushing block's pose, the pendulum's angle and rate). A policy that needs no
goal (a planner of a learned reward) is reset with ``goal=None``. A policy from images
reads ``observation.image`` only; a reference policy on the true state reads
``observation.state``. :class:`ImagePolicy` makes a planner that takes images
(``LatentSINDy.planner()``) such a policy.

:func:`run_loop` is the loop itself: it knows nothing of a world but the episode in progress
(a :class:`Stepper`: is its goal met, and carry out an action). What a step records, and what
success means, stay in the world's code. :func:`run_closed_loop` runs it on the tasks any
world samples:

    results = run_closed_loop(world, ImagePolicy(planner), episodes=10, max_steps=20, seed=0)
    summary = success_rates(results)          # criterion -> share of episodes that met it
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from latent_sindy.control.world import Task, World

__all__ = ["Episode", "ImagePolicy", "Observation", "Policy", "Stepper", "run_closed_loop",
           "run_episode", "run_loop", "success_rates"]


@dataclass(frozen=True)
class Observation:
    """What a policy is shown: the camera image (C, H, W) and, where the world gives it, the
    true state (None where it does not)."""

    image: np.ndarray
    state: Any = None


class Policy(Protocol):
    def reset(self, goal: Observation | None, seed: int | None = None) -> None:
        """Act toward ``goal`` (its image, and state where given; None: a policy of no goal)
        from now on; ``seed`` seeds the episode's draws."""

    def act(self, observation: Observation) -> np.ndarray:
        """The action (nu,) to take now."""


class Stepper(Protocol):
    """An episode in progress, as the loop sees it; the world's code keeps its records."""

    def done(self) -> bool:
        """Whether the episode's goal is met (the loop then stops before acting)."""

    def step(self, action: np.ndarray) -> tuple[Observation, bool]:
        """Carry out ``action``; the observation after it and whether the episode ended
        there (the environment terminated it)."""


def run_loop(policy: Policy, stepper: Stepper, first: Observation, goal: Observation | None,
             max_steps: int, seed: int | None) -> int:
    """The closed loop: reset ``policy`` toward ``goal`` (None: a policy of no goal) with
    ``seed``, then act on each observation from ``first`` on until the stepper's goal is met,
    the episode ends or ``max_steps`` actions were taken. Returns the number of actions
    taken."""
    policy.reset(goal, seed)
    observation = first
    steps = 0
    while steps < max_steps and not stepper.done():
        observation, ended = stepper.step(policy.act(observation))
        steps += 1
        if ended:
            break
    return steps


class ImagePolicy:
    """A planner that takes images (``reset(goal_image, seed)``, ``act(image)``: an
    :class:`~latent_sindy.control.planner.ImagePlanner`, ``LatentSINDy.planner()``) as a
    policy of the loop: it is handed the images only, never the state."""

    def __init__(self, planner: Any) -> None:
        self.planner = planner

    def reset(self, goal: Observation | None, seed: int | None = None) -> None:
        self.planner.reset(None if goal is None else goal.image, seed)

    def act(self, observation: Observation) -> np.ndarray:
        return self.planner.act(observation.image)


@dataclass
class Episode:
    """One episode: its task, the steps taken, the first step each criterion was met
    (None: never), the actions, the final state and the states from the start on."""

    task: Task
    steps: int
    reached: dict[str, int | None]
    actions: list[list[float]] = field(default_factory=list)
    final_state: Any = None
    states: list[Any] = field(default_factory=list)


class _WorldSteps:
    """An episode of a :class:`World`: actions as float32 in the world's box shape, the
    state and the criteria met after each."""

    def __init__(self, world: World, env: Any, task: Task, until: str | None,
                 stop: bool) -> None:
        self.world = world
        self.env = env
        self.task = task
        self.until = until
        self.stop = stop
        self.actions: list[list[float]] = []
        self.states = [world.state(env)]
        met = world.success(self.states[0], task.goal)
        self.reached: dict[str, int | None] = {k: (0 if v else None) for k, v in met.items()}

    def done(self) -> bool:
        return self.stop and all(v is not None for k, v in self.reached.items()
                                 if self.until in (None, k))

    def step(self, action: np.ndarray) -> tuple[Observation, bool]:
        u = np.asarray(action, dtype=np.float32).reshape(len(self.world.action_low))
        self.actions.append(u.tolist())
        obs, _, terminated, truncated, _ = self.env.step(u)
        state = self.world.state(self.env)
        self.states.append(state)
        for k, v in self.world.success(state, self.task.goal).items():
            if v and self.reached.get(k) is None:
                self.reached[k] = len(self.actions)
        return Observation(self.world.image(obs), state), bool(terminated or truncated)


def run_episode(world: World, env: Any, policy: Policy, task: Task, max_steps: int,
                seed: int, until: str | None = None, stop: bool = True) -> Episode:
    """One closed-loop episode; stops when criterion ``until`` (default: every criterion) is
    met or after ``max_steps`` actions (``stop=False``: takes all ``max_steps``, the
    criteria only recorded)."""
    image = world.reset(env, task, seed)
    goal = Observation(world.goal_image(env, task), task.goal)
    steps = _WorldSteps(world, env, task, until, stop)
    n = run_loop(policy, steps, Observation(image, steps.states[0]), goal, max_steps, seed)
    return Episode(task, n, steps.reached, steps.actions, world.state(env), steps.states)


def run_closed_loop(world: World, policy: Policy, episodes: int, max_steps: int,
                    seed: int = 0, until: str | None = None, stop: bool = True
                    ) -> list[Episode]:
    """``episodes`` episodes on tasks the world samples with ``seed``."""
    env = world.make_env()
    try:
        rng = np.random.default_rng(seed)
        return [run_episode(world, env, policy, world.sample_task(rng), max_steps,
                            seed * 1000 + i, until, stop) for i in range(episodes)]
    finally:
        close = getattr(env, "close", None)
        if close is not None:
            close()


def success_rates(results: list[Episode]) -> dict[str, float]:
    """Per criterion, the share of episodes that met it."""
    names = sorted({k for r in results for k in r.reached})
    return {k: float(np.mean([r.reached.get(k) is not None for r in results])) for k in names}
