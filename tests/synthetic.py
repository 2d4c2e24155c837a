"""Small synthetic trajectory sets for tests: valid, random, no simulation involved."""

from __future__ import annotations

import numpy as np

from latent_sindy.data import SequenceData
from latent_sindy.worlds.push.config import ACTION_HIGH, ACTION_LOW, PushEnvConfig
from latent_sindy.worlds.push.data import push_data


def make_trajectories(n: int = 6, steps: int = 4, channels: int = 1, seed: int = 0,
                      split_ids=None) -> SequenceData:
    """Random but valid trajectories, no simulation involved."""
    rng = np.random.default_rng(seed)
    images = rng.integers(100, 240, size=(n, steps + 1, channels, 32, 32), dtype=np.uint8)
    actions = rng.uniform(ACTION_LOW, ACTION_HIGH, size=(n, steps, 3)).astype(np.float32)
    poses = rng.uniform(-0.3, 0.7, size=(n, steps + 1, 3)).astype(np.float32)
    if split_ids is None:
        split_ids = np.arange(n, dtype=np.uint8) % 3
    return push_data(images, actions, poses, np.asarray(split_ids, dtype=np.uint8),
                        PushEnvConfig(channels=channels), seed=seed)
