"""Which pushes the arm can make: the pushing world's reach answer.

A push is made only when the arm reaches its start behind the contact point
(:meth:`PushWorld.push <latent_sindy.worlds.push.world.PushWorld.push>`); otherwise the arm
does not try and the block stays (``info["push_executed"]`` is false). :class:`Reach` asks
a kinematic copy of the world (no camera, nothing simulated) the same question for a batch
of block poses and actions: the same IK search from the same arm posture, so it answers
what the world would do, in a few milliseconds per push (about 20 ms for one out of reach).
The closed loop uses it to replace a planned push the arm cannot make
(:mod:`latent_sindy.worlds.push.episodes`).

    reach = Reach(PushEnvConfig())
    reach([[0.78, -0.34, 1.77]], [[-0.05, -2.33, 0.4]])   # array([False]): too far
"""

from __future__ import annotations

import numpy as np

from latent_sindy.errors import UserError
from latent_sindy.worlds.push.config import PushEnvConfig

__all__ = ["Reach"]


class Reach:
    """``reach(states (K, 3), actions (K, nu)) -> (K,) bool``: can the arm start each push?

    ``states`` are block poses (x, y, theta); one pose (3,) is shared by every action. The
    copy of the world is built on the first call (about 0.1 s) and kept.
    """

    def __init__(self, config: PushEnvConfig | None = None) -> None:
        self.config = config or PushEnvConfig()
        self._world = None
        self.queries = 0  # pushes asked about, for benchmarks

    def __call__(self, states, actions) -> np.ndarray:
        actions = np.asarray(actions, dtype=float)
        if actions.ndim == 1:
            actions = actions[None]
        states = np.asarray(states, dtype=float)
        if states.ndim == 1:
            states = np.broadcast_to(states, (len(actions), states.shape[0]))
        if (actions.ndim != 2 or actions.shape[1] != self.config.action_dim
                or states.shape != (len(actions), 3)):
            raise UserError(f"reach: states {states.shape} and actions {actions.shape} must be "
                            f"(K, 3) block poses and (K, {self.config.action_dim}) actions")
        if self._world is None:
            from latent_sindy.worlds.push.world import PushWorld

            self._world = PushWorld(self.config)
        low, high = np.array(self.config.action_low), np.array(self.config.action_high)
        actions = np.clip(actions, low, high)  # as the environment clips them
        self.queries += len(actions)
        return np.array([self._world.can_push(a[0], a[1], pose=s)
                         for s, a in zip(states, actions, strict=True)], dtype=bool)

    def close(self) -> None:
        if self._world is not None:
            self._world.close()
            self._world = None
