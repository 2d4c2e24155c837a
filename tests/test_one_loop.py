"""The one closed loop: the same policy, through the same ``act(observation)`` call, acts in
the pushing world and in the pendulum, in the generic loop over a world and in each world's
own runner (the push study's episodes, the pendulum's swing-ups); a policy that reads the
observation's state gets the world's true state."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from latent_sindy.control.episodes import Observation, run_closed_loop
from latent_sindy.plugins import get_world
from latent_sindy.worlds.pendulum import WORLD as PENDULUM
from latent_sindy.worlds.pendulum.render import observe
from latent_sindy.worlds.pendulum.swing_up import run_swing_up


class StateReader:
    """Acts on the true state: no push or torque unless the state's first coordinate is
    positive; keeps every goal and observation it was shown."""

    def __init__(self, nu: int) -> None:
        self.nu, self.goals, self.seen = nu, [], []
        self.last = SimpleNamespace(plan=SimpleNamespace(seconds=0.0, discarded=0),
                                    replaced=False, reach_s=0.0)  # the push runner reads it

    def reset(self, goal: Observation, seed: int | None = None) -> None:
        self.goals.append(goal)

    def act(self, observation: Observation) -> np.ndarray:
        assert isinstance(observation, Observation) and observation.state is not None
        self.seen.append(observation)
        u = np.zeros(self.nu, np.float32)
        if self.nu == 1 and observation.state[0] > 0:
            u[0] = 0.5
        return u


@pytest.fixture(scope="module")
def push():
    return get_world("push")


def test_the_loop_hands_the_pendulum_state_and_its_image(one_torch_thread):
    policy = StateReader(1)
    (episode,) = run_closed_loop(PENDULUM, policy, episodes=1, max_steps=6, seed=1, stop=False)
    assert episode.steps == 6 == len(policy.seen) and len(episode.states) == 7
    for observation, state in zip(policy.seen, episode.states, strict=False):
        np.testing.assert_array_equal(observation.state, state)  # the world's state
        size = PENDULUM.config.image_size
        assert np.abs(observation.image.astype(int)
                      - observe(state[0], state[1], size).astype(int)).max() <= 1
    (goal,) = policy.goals
    np.testing.assert_array_equal(goal.state, episode.task.goal)
    np.testing.assert_array_equal(goal.image, PENDULUM.goal_image(None, episode.task))
    # the torque it chose from the state is the one the world was given
    assert [a[0] for a in episode.actions] == [0.5 if s[0] > 0 else 0.0
                                               for s in episode.states[:-1]]


def test_the_swing_up_runs_the_same_loop():
    policy = StateReader(1)
    (up,) = run_swing_up(PENDULUM, policy, episodes=1, steps=4, seed=2, last=2)
    assert up.states.shape == (5, 2) and up.actions.shape == (4, 1)
    np.testing.assert_array_equal(np.stack([o.state for o in policy.seen]), up.states[:-1])
    assert not math.isnan(up.upright_fraction)


def test_the_same_policy_pushes_with_the_block_pose_as_state(push):
    policy = StateReader(3)
    (episode,) = run_closed_loop(push, policy, episodes=1, max_steps=2, seed=0, stop=False)
    assert episode.steps == 2 == len(policy.seen)
    for observation, state in zip(policy.seen, episode.states, strict=False):
        np.testing.assert_array_equal(observation.state, state)  # the block's pose
        assert observation.image.shape == (1, 32, 32)
    np.testing.assert_allclose(policy.seen[0].state[:2], episode.task.start[:2], atol=2e-3)
    np.testing.assert_array_equal(policy.goals[0].state, episode.task.goal)


def test_the_push_studys_runner_shows_the_policy_the_block_pose(push):
    from latent_sindy.worlds.push.episodes import ControlConfig, run_episode

    policy = StateReader(3)
    env = push.make_env()
    try:
        result = run_episode(env, policy, 0, ControlConfig(task="random", max_steps=2,
                                                           gif_episodes=0))
        pose = push.state(env)
    finally:
        env.close()
    assert result.steps == 2 == len(policy.seen) and result.actions == [[0.0] * 3] * 2
    np.testing.assert_array_equal(policy.seen[0].state, result.start)
    np.testing.assert_array_equal(policy.goals[0].state, result.goal)
    np.testing.assert_allclose(pose[:2], result.start[:2], atol=2e-3)  # no push: it stays
