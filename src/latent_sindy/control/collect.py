"""Random-action data from any world (:class:`~latent_sindy.control.world.World`): the first
data set of a new system, to fit a model on and then plan with.

    data = collect_random(world, sequences=100, steps=10, seed=0)
    model = LatentSINDy(latent_dim=2).fit(data)
"""

from __future__ import annotations

import numpy as np

from latent_sindy.control.world import World
from latent_sindy.data import SequenceData
from latent_sindy.errors import UserError

__all__ = ["collect_random"]


def collect_random(world: World, sequences: int, steps: int, seed: int = 0, hold: int = 1
                   ) -> SequenceData:
    """``sequences`` episodes of ``steps`` actions drawn uniformly from the world's box, each
    held for ``hold`` steps (1: a new one every step), from the starts of tasks the world
    samples; images, actions, true states and the rewards the environment's ``step``
    returned (left out where any of them is not a finite number). Actions held longer push
    a system further from where it rests: independent draws every step mostly cancel."""
    if isinstance(hold, bool) or not isinstance(hold, int) or hold < 1:
        raise UserError(f"collect_random hold={hold!r}: use an integer >= 1 (steps an "
                        "action is held)")
    rng = np.random.default_rng(seed)
    low, high = np.asarray(world.action_low, float), np.asarray(world.action_high, float)
    env = world.make_env()
    images = []
    actions = []
    states = []
    rewards = []
    try:
        for i in range(sequences):
            task = world.sample_task(rng)
            frames = [world.reset(env, task, seed * 100_003 + i)]
            us = []
            xs = [world.state(env)]
            for t in range(steps):
                if t % hold == 0:
                    u = rng.uniform(low, high).astype(np.float32)
                obs, reward, *_ = env.step(u)
                frames.append(world.image(obs))
                rewards.append(reward)
                us.append(u)
                xs.append(world.state(env))
            images.append(np.stack(frames))
            actions.append(np.stack(us))
            states.append(np.stack(xs))
    finally:
        if hasattr(env, "close"):
            env.close()
    return SequenceData(np.stack(images), np.stack(actions), action_low=low, action_high=high,
                        action_names=tuple(world.action_names),
                        states=np.stack(states).astype(np.float32),
                        rewards=_rewards(rewards, sequences, steps), seed=seed,
                        source=f"<random actions in {world.name}>", split_seed=seed)


def _rewards(values: list, sequences: int, steps: int) -> np.ndarray | None:
    """The rewards (N, T) float32, or None where an environment gave something else."""
    if not all(isinstance(r, int | float | np.number) and not isinstance(r, bool)
               for r in values):
        return None
    out = np.asarray(values, np.float64).reshape(sequences, steps)
    return out.astype(np.float32) if np.all(np.isfinite(out)) else None
