"""The pushing world behaves like a pushed block and its camera shows it."""

from __future__ import annotations

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest

import latent_sindy  # noqa: F401  (registers the environment)
from latent_sindy.envs import ENV_ID, PAPER_GOAL, PAPER_START
from latent_sindy.envs.panda_push import PandaPushEnv


def push_from(env, start, action):
    obs0, _ = env.reset(seed=0, options={"start": start, "goal": (0.7, 0.0, 0.0)})
    obs1, _, _, _, info = env.step(np.array(action, dtype=np.float32))
    return info["pose"], obs0, obs1, info


def in_push_frame(start, end, direction):
    """Forward and lateral displacement along a push direction (rad)."""
    d = np.asarray(end[:2]) - np.asarray(start[:2])
    c, s = math.cos(direction), math.sin(direction)
    return d[0] * c + d[1] * s, -d[0] * s + d[1] * c


@pytest.mark.parametrize("theta", [0.0, 0.7, -1.2])
def test_centred_push_moves_block_forward_by_push_length(env, theta):
    start = (0.5, 0.05, theta)
    end, _, _, info = push_from(env, start, (0.0, 0.0, 1.0))
    forward, lateral = in_push_frame(start, end, theta)
    assert info["push_executed"]
    assert 0.08 < forward < 0.12  # ell = 1 is 0.1 m
    assert abs(lateral) < 0.015
    assert abs(end[2] - theta) < 0.1


def test_half_push_moves_about_half_as_far(env):
    start = (0.5, 0.0, 0.0)
    end, _, _, _ = push_from(env, start, (0.0, 0.0, 0.5))
    forward, _ = in_push_frame(start, end, 0.0)
    assert 0.035 < forward < 0.065


def test_off_centre_pushes_rotate_in_opposite_directions(env):
    start = (0.5, 0.0, 0.3)
    left, _, _, _ = push_from(env, start, (0.8, 0.0, 1.0))
    right, _, _, _ = push_from(env, start, (-0.8, 0.0, 1.0))
    # contact at +y of the block frame turns it clockwise (negative theta), and vice versa
    assert left[2] - 0.3 < -0.2
    assert right[2] - 0.3 > 0.2


def test_angled_push_slides_along_the_face(env):
    start = (0.5, 0.0, 0.0)
    end, _, _, _ = push_from(env, start, (0.0, 0.6, 1.0))
    d = end[:2] - np.array(start[:2])
    # finger-block friction is low (0.1): the pusher slides along the face, so the block
    # goes mostly along the face normal (+x), drifting a little towards the push (+y)
    assert d[0] > 0.05
    assert 0.0 < d[1] < d[0]


def test_zero_length_push_leaves_block_in_place(env):
    start = (0.55, -0.1, 0.4)
    end, obs0, obs1, _ = push_from(env, start, (0.3, -0.4, 0.0))
    assert np.allclose(end, start, atol=1e-3)
    assert np.array_equal(obs0, obs1)


def test_block_motion_shows_in_the_image(env):
    start = (0.45, 0.0, 0.0)
    end, obs0, obs1, _ = push_from(env, start, (0.0, 0.0, 1.0))
    assert not np.array_equal(obs0, obs1)

    def centroid(obs):  # the block is the dark blob on the light table
        img = obs[0].astype(float)
        return np.argwhere(img < img.mean() - 20).mean(axis=0)

    moved = centroid(obs1) - centroid(obs0)
    world = env.world
    expected = world.world_to_pixel((*end[:2], 0.05)) - world.world_to_pixel((*start[:2], 0.05))
    assert np.linalg.norm(moved) > 2.0  # 0.1 m is about 4 pixels
    cos = moved @ expected / (np.linalg.norm(moved) * np.linalg.norm(expected))
    assert cos > 0.9
    assert np.linalg.norm(moved - expected) < 1.0


def test_observation_equals_full_scene_render(env):
    env.reset(seed=3)
    env.step(np.array([0.2, 0.3, 0.8], dtype=np.float32))
    assert np.array_equal(env.observe(), env.world.observe_full_scene())


def test_goal_image_shows_block_at_goal_without_moving_it(env):
    env.reset(options={"task": "paper"})
    goal_img = env.goal_observation()
    assert np.allclose(env.world.block_pose(), PAPER_START, atol=1e-6)
    env.reset(options={"start": PAPER_GOAL, "goal": PAPER_GOAL})
    assert np.array_equal(goal_img, env.observe())


def test_paper_task_and_info(env):
    obs, info = env.reset(options={"task": "paper"})
    assert obs.shape == (1, 32, 32) and obs.dtype == np.uint8
    assert np.allclose(info["pose"], PAPER_START, atol=1e-6)
    assert info["distance"] == pytest.approx(0.3, abs=1e-6)
    assert not info["is_success"] and info["in_bounds"]


def test_success_criteria_course_and_strict(env):
    _, info = env.reset(options={"start": (0.65, 0.0, 0.5), "goal": (0.7, 0.0, 0.0)})
    assert info["is_success"]  # within 0.1 m, orientation ignored
    assert not info["is_success_strict"]  # 0.05 m and ~29 degrees off
    _, info = env.reset(options={"start": (0.71, 0.005, 0.05), "goal": (0.7, 0.0, 0.0)})
    assert info["is_success_strict"]


def test_leaving_the_workspace_terminates(env):
    env.reset(options={"start": (0.5, 0.36, math.pi / 2), "goal": (0.7, 0.0, 0.0)})
    _, _, terminated, _, info = env.step(np.array([0.0, 0.0, 1.0], dtype=np.float32))
    assert info["pose"][1] > 0.4 and not info["in_bounds"]
    assert terminated


def test_same_seed_same_trajectory():
    def run(env):
        obs, _ = env.reset(seed=11)
        out = [obs]
        rng = np.random.default_rng(5)
        for _ in range(3):
            obs, *_ = env.step(rng.uniform(env.action_space.low, env.action_space.high))
            out.append(obs)
        return np.stack(out), env.world.block_pose()

    a, b = PandaPushEnv(), PandaPushEnv()
    imgs_a, pose_a = run(a)
    imgs_b, pose_b = run(b)
    imgs_a2, pose_a2 = run(a)  # the same environment again, after other pushes
    assert np.array_equal(imgs_a, imgs_b) and np.array_equal(pose_a, pose_b)
    assert np.array_equal(imgs_a, imgs_a2) and np.array_equal(pose_a, pose_a2)
    a.close()
    b.close()


def test_sampled_poses_lie_in_workspace(env):
    lo, hi = np.array(env.config.workspace_low), np.array(env.config.workspace_high)
    for s in range(5):
        _, info = env.reset(seed=s)
        assert np.all(info["pose"] >= lo - 1e-6) and np.all(info["pose"] <= hi + 1e-6)
        assert np.all(info["goal"] >= lo) and np.all(info["goal"] <= hi)


@pytest.mark.parametrize("action", [[np.nan, 0, 0.5], [0, 0, 1.5], [0, 2.0, 0.5], [0, 0]])
def test_bad_actions_are_refused(env, action):
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(np.array(action, dtype=np.float32))


def test_rgb_observation_and_render():
    e = gym.make(ENV_ID, render_mode="rgb_array", channels=3)
    obs, _ = e.reset(seed=1, options={"task": "paper"})
    assert obs.shape == (3, 32, 32)
    frame = e.render()
    assert frame.shape == (256, 256, 3) and frame.dtype == np.uint8
    # the goal marker (green) shows in the render but not in the observation
    green = (frame[..., 1] > 150) & (frame[..., 0] < 100)
    assert green.sum() > 50
    assert not ((obs[1] > 150) & (obs[0] < 100)).any()
    e.close()


def test_gymnasium_check_env():
    from gymnasium.utils.env_checker import check_env

    e = PandaPushEnv()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # advice about asymmetric action boxes
        check_env(e, skip_render_check=True)
    e.close()
