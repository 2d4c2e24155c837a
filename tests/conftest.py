"""Shared fixtures: a pushing environment and small synthetic trajectory sets."""

from __future__ import annotations

import pytest

from latent_sindy.data.store import Trajectories
from synthetic import make_trajectories


@pytest.fixture(scope="module")
def env():
    from latent_sindy.envs.panda_push import PandaPushEnv

    e = PandaPushEnv()
    yield e
    e.close()


@pytest.fixture
def trajectories() -> Trajectories:
    return make_trajectories()
