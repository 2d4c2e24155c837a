"""Rewards travel with the data: one per action, checked, kept by subsets, written and read
back; files and data without them read and print as before rewards existed; random-action
collection records what the environment's step returned."""

from __future__ import annotations

import hashlib

import h5py
import numpy as np
import pytest

from latent_sindy.control.collect import collect_random
from latent_sindy.data import SequenceData, read_sequences, write_sequences
from latent_sindy.errors import UserError


def make(rewards=None, n=6, steps=3) -> SequenceData:
    rng = np.random.default_rng(0)
    return SequenceData(rng.integers(0, 255, (n, steps + 1, 1, 8, 8), dtype=np.uint8),
                        rng.uniform(-1, 1, (n, steps, 1)).astype(np.float32),
                        action_low=[-1], action_high=[1], rewards=rewards)


def test_rewards_are_one_finite_number_per_action():
    r = np.arange(18, dtype=np.float32).reshape(6, 3)
    data = make(r)
    np.testing.assert_array_equal(data.split("train").rewards, r[data.split_ids == 0])
    with pytest.raises(UserError, match=r"rewards must be .* shape \(6, 3\)"):
        make(np.zeros((6, 4)))
    with pytest.raises(UserError, match="rewards must be a floating-point"):
        make(np.zeros((6, 3), np.int64))
    bad = r.copy()
    bad[2, 1] = np.nan
    with pytest.raises(UserError, match="rewards of sequence 2 contain NaN"):
        make(bad)


def test_rewards_round_trip_and_files_without_them_load(tmp_path):
    r = np.linspace(-1, 2, 18).reshape(6, 3)
    write_sequences(tmp_path / "r.h5", make(r))
    back = read_sequences(tmp_path / "r.h5")
    np.testing.assert_allclose(back.rewards, r, rtol=1e-6)
    assert back.rewards.dtype == np.float32
    write_sequences(tmp_path / "none.h5", make())
    with h5py.File(tmp_path / "none.h5") as f:
        assert "rewards" not in f
    assert read_sequences(tmp_path / "none.h5").rewards is None


def test_data_without_rewards_print_as_before_rewards_existed():
    data = make()
    h = hashlib.sha256()  # the extras' fingerprint as it was written before rewards
    for name in ("images_dot", "images_ddot", "executed"):
        h.update(f"{name}:".encode())
    assert data.extras_fingerprint() == h.hexdigest()
    assert make(np.ones((6, 3))).extras_fingerprint() != data.extras_fingerprint()
    assert make(np.ones((6, 3))).fingerprint() == data.fingerprint()


def test_random_collection_records_the_environments_rewards():
    from latent_sindy.worlds.pendulum.plugin import PendulumWorld

    data = PendulumWorld().collect(sequences=3, steps=4, seed=0)
    theta, rate = data.states[:, :-1, 0], data.states[:, :-1, 1]  # Pendulum-v1: the state
    # each action was taken in
    wrapped = np.remainder(theta + np.pi, 2 * np.pi) - np.pi
    expected = -(wrapped ** 2 + 0.1 * rate ** 2 + 0.001 * data.actions[..., 0] ** 2)
    assert data.rewards.shape == (3, 4)
    np.testing.assert_allclose(data.rewards, expected, rtol=1e-4, atol=1e-4)


class _NoReward:
    """A world whose environment returns no number as its reward."""

    name, action_low, action_high, action_names = "silent", (-1.0,), (1.0,), ("u",)

    class Env:
        def step(self, u):
            return np.zeros((1, 4, 4), np.uint8), None, False, False, {}

    def make_env(self):
        return self.Env()

    def sample_task(self, rng):
        from latent_sindy.control.world import Task

        return Task(np.zeros(1), np.zeros(1))

    def reset(self, env, task, seed):
        return np.zeros((1, 4, 4), np.uint8)

    def image(self, observation):
        return observation

    def state(self, env):
        return np.zeros(1)


def test_an_environment_without_rewards_gives_data_without_them():
    assert collect_random(_NoReward(), sequences=2, steps=2).rewards is None
