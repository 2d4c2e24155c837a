"""The DeepMind Control world (``--world dmc``): stacked camera frames of any suite task, the
task's reward summed over each action's repeat, the physics state, and a clear error where
the ``dmc`` extra is not installed. Tiny scale: a few 32-pixel sequences of a few steps."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from latent_sindy.data import read_sequences, write_sequences
from latent_sindy.errors import UserError
from latent_sindy.worlds.dmc.config import DmcConfig
from latent_sindy.worlds.dmc.plugin import DmcWorld

SMALL = DmcConfig(task="cartpole-swingup", size=32)


@pytest.fixture(scope="module")
def dmc():
    pytest.importorskip("dm_control")


@pytest.fixture(scope="module")
def data(dmc):
    return DmcWorld(SMALL).collect(sequences=3, steps=4, seed=0)


def test_random_data_of_a_task(data):
    assert data.images.shape == (3, 5, 6, 32, 32) and data.images.dtype == np.uint8
    assert data.actions.shape == (3, 4, 1) and np.all(np.abs(data.actions) <= 1)
    assert data.action_names == ("slide",) and data.world == "dmc"
    assert data.states.shape == (3, 5, 4)
    assert data.state_names == ("slider", "hinge_1", "slider_dot", "hinge_1_dot")
    assert data.state_periods == (None, 2 * np.pi, None, None)  # the pole turns freely
    assert data.dt == pytest.approx(0.01 * 8)  # cartpole: PlaNet's repeat of 8
    # the suite's reward is in [0, 1] per control step: at most 8 per action
    assert data.rewards.shape == (3, 4) and np.all((data.rewards >= 0) & (data.rewards <= 8))
    assert data.world_config == SMALL
    # frames stacked oldest first: a frame's older half is the previous frame's newer half
    np.testing.assert_array_equal(data.images[:, 1:, :3], data.images[:, :-1, 3:])


def test_the_same_seed_gives_the_same_data_and_another_seed_other_data(data):
    again = DmcWorld(SMALL).collect(sequences=3, steps=4, seed=0)
    assert again.fingerprint() == data.fingerprint()
    np.testing.assert_array_equal(again.rewards, data.rewards)
    other = DmcWorld(SMALL).collect(sequences=3, steps=4, seed=1)
    assert not np.array_equal(other.images, data.images)


def test_the_frames_follow_the_actions(dmc):
    world = DmcWorld(SMALL)
    env = world.make_env()
    task = world.sample_task(np.random.default_rng(0))
    ends = []
    for push in (-1.0, 1.0):
        first = world.reset(env, task, seed=0)
        for _ in range(3):
            image, *_ = env.step(np.array([push], np.float32))
        ends.append((first, image, world.state(env)[0]))
    np.testing.assert_array_equal(ends[0][0], ends[1][0])  # the same start
    assert ends[0][2] < ends[0][0].dtype.type(0) < ends[1][2]  # the cart went both ways
    assert np.abs(ends[0][1].astype(int) - ends[1][1]).max() > 50  # and the camera saw it


def test_an_action_repeat_sums_the_rewards_of_its_control_steps(dmc):
    from latent_sindy.worlds.dmc.env import DmcPixelEnv

    once = DmcPixelEnv(DmcConfig(task="pendulum-swingup", size=16, frames=1, action_repeat=3))
    each = DmcPixelEnv(DmcConfig(task="pendulum-swingup", size=16, frames=1, action_repeat=1))
    # start near upright, where the reward (1 within 8° of it, else 0) is earned
    for env in (once, each):
        env.reset(seed=5)
        with env.physics.reset_context():
            env.physics.set_state(np.array([0.1, 0.4]))
    us = np.random.default_rng(0).uniform(-1, 1, 4)
    total = [once.step(np.array([u]))[1] for u in us]
    parts = [each.step(np.array([u]))[1] for u in np.repeat(us, 3)]
    np.testing.assert_allclose(total, np.add.reduceat(parts, [0, 3, 6, 9]))
    assert max(total) > 1  # more than one control step can earn: a sum, not the last one
    np.testing.assert_allclose(once.state(), each.state())
    assert once.dt == pytest.approx(3 * each.dt)


def test_the_files_of_the_world_round_trip(data, tmp_path):
    write_sequences(tmp_path / "d.h5", data)
    back = read_sequences(tmp_path / "d.h5")
    assert back.fingerprint() == data.fingerprint()
    np.testing.assert_array_equal(back.rewards, data.rewards)
    assert back.extras_fingerprint() == data.extras_fingerprint()
    assert (back.world_config, back.state_periods, back.dt) == (SMALL, data.state_periods,
                                                                 data.dt)


def test_the_cartpole_goal_is_upright_and_other_tasks_have_no_goal_image(dmc):
    world = DmcWorld(SMALL)
    env = world.make_env()
    task = world.sample_task(np.random.default_rng(0))
    start = world.reset(env, task, seed=0)
    state = world.state(env)
    goal = world.goal_image(env, task)
    assert goal.shape == start.shape and not np.array_equal(goal, start)
    np.testing.assert_array_equal(world.state(env), state)  # the env is where it was
    np.testing.assert_array_equal(env.observation(), start)
    assert world.success(task.goal, task.goal) == {"upright": True}
    assert world.success(state, task.goal) == {"upright": False}  # swing-up starts hanging
    reacher = DmcWorld(DmcConfig(task="reacher-easy", size=16))
    with pytest.raises(UserError, match="scored by its reward"):
        reacher.goal_image(reacher.make_env(), reacher.sample_task(np.random.default_rng(0)))


def test_a_task_the_suite_lacks_is_refused_with_the_valid_names(dmc):
    with pytest.raises(UserError, match=r"not in the DeepMind Control suite.*cartpole-swingup"):
        DmcWorld(DmcConfig(task="cartpole-swingdown")).make_env()
    with pytest.raises(UserError, match="DOMAIN-TASK"):
        DmcConfig(task="cartpole")


def test_the_command_line_collects_the_task_it_is_given(dmc, tmp_path):
    out = tmp_path / "p.h5"
    r = subprocess.run([sys.executable, "-m", "latent_sindy.cli", "collect", "--world", "dmc",
                        "--world-config", "task=pendulum-swingup", "size=16", "frames=1",
                        "--trajectories", "3", "--steps", "2", "--out", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    data = read_sequences(out)
    assert data.images.shape == (3, 3, 3, 16, 16) and data.rewards.shape == (3, 2)
    assert data.world_config == DmcConfig(task="pendulum-swingup", size=16, frames=1)
    assert data.world_config.action_repeat == 4


def test_without_dm_control_every_use_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "dm_control", None)  # import dm_control fails
    world = DmcWorld(DmcConfig(task="cartpole-balance_sparse", size=24))
    for use in (world.make_env, lambda: world.collect(2, 2, 0), lambda: world.action_low):
        with pytest.raises(UserError, match=r"install latent-sindy\[dmc\]"):
            use()


def test_the_plug_in_loads_without_importing_dm_control():
    code = ("import sys; from latent_sindy.plugins import get_world, load_plugins; "
            "assert 'dmc' in load_plugins(); w = get_world('dmc'); "
            "assert w.config.task == 'cartpole-swingup' and w.config.action_repeat == 8; "
            "assert 'dm_control' not in sys.modules and 'mujoco' not in sys.modules")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
