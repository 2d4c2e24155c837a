"""Shared fixtures: a pushing environment and small synthetic trajectory sets."""

from __future__ import annotations

import pytest

from latent_sindy.data import SequenceData
from synthetic import make_trajectories


@pytest.fixture(scope="module")
def env():
    from latent_sindy.worlds.push.panda_push import PandaPushEnv

    e = PandaPushEnv()
    yield e
    e.close()


@pytest.fixture(scope="module")
def one_torch_thread():
    """Run a module's tests on one torch thread (fast and repeatable on a shared 2-core box)."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture
def trajectories() -> SequenceData:
    return make_trajectories()
