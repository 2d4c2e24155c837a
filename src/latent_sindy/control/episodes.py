"""The closed loop over any world (:class:`~latent_sindy.control.world.World`): reset into a
task, show the planner the goal image, act on every image until a criterion is met.

    results = run_closed_loop(world, planner, episodes=10, max_steps=20, seed=0)
    summary = success_rates(results)          # criterion -> share of episodes that met it
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from latent_sindy.control.world import Task, World

__all__ = ["Episode", "Policy", "run_closed_loop", "run_episode", "success_rates"]


class Policy(Protocol):
    def reset(self, goal_image: np.ndarray, seed: int | None = None) -> None: ...

    def act(self, image: np.ndarray) -> np.ndarray: ...


@dataclass
class Episode:
    """One episode: its task, the steps taken, and the first step each criterion was met
    (None: never)."""

    task: Task
    steps: int
    reached: dict[str, int | None]
    actions: list[list[float]] = field(default_factory=list)
    final_state: Any = None


def run_episode(world: World, env: Any, policy: Policy, task: Task, max_steps: int,
                seed: int, until: str | None = None) -> Episode:
    """One closed-loop episode; stops when criterion ``until`` (default: every criterion) is
    met or after ``max_steps`` actions."""
    image = world.reset(env, task, seed)
    policy.reset(world.goal_image(env, task), seed)
    met = world.success(world.state(env), task.goal)
    reached = {k: (0 if v else None) for k, v in met.items()}
    actions: list[list[float]] = []

    def done() -> bool:
        return all(v is not None for k, v in reached.items() if until in (None, k))

    steps = 0
    while steps < max_steps and not done():
        u = np.asarray(policy.act(image), dtype=np.float32)
        actions.append(u.tolist())
        obs, _, terminated, truncated, _ = env.step(u)
        image, steps = world.image(obs), steps + 1
        for k, v in world.success(world.state(env), task.goal).items():
            if v and reached.get(k) is None:
                reached[k] = steps
        if terminated or truncated:
            break
    return Episode(task, steps, reached, actions, world.state(env))


def run_closed_loop(world: World, policy: Policy, episodes: int, max_steps: int,
                    seed: int = 0, until: str | None = None) -> list[Episode]:
    """``episodes`` episodes on tasks the world samples with ``seed``."""
    env = world.make_env()
    try:
        rng = np.random.default_rng(seed)
        return [run_episode(world, env, policy, world.sample_task(rng), max_steps,
                            seed * 1000 + i, until) for i in range(episodes)]
    finally:
        close = getattr(env, "close", None)
        if close is not None:
            close()


def success_rates(results: list[Episode]) -> dict[str, float]:
    """Per criterion, the share of episodes that met it."""
    names = sorted({k for r in results for k in r.reached})
    return {k: float(np.mean([r.reached.get(k) is not None for r in results])) for k in names}
