"""The pushing world behaves like a pushed block and its camera shows it.

Tests of the paper's action u = [p, phi, ell] (phi relative to the block) run in the named
"paper" world; the default world is the symmetric one (see envs/config.py).
"""

from __future__ import annotations

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest

from latent_sindy.configs import to_json
from latent_sindy.errors import UserError
from latent_sindy.worlds.push import PAPER_GOAL, PAPER_START, PushEnvConfig, register_env
from latent_sindy.worlds.push.config import ENV_PRESETS
from latent_sindy.worlds.push.criteria import wrap_angle
from latent_sindy.worlds.push.panda_push import PandaPushEnv


@pytest.fixture(scope="module")
def paper():
    """The paper's world: pushes from the block's -x face, phi relative to the block."""
    e = PandaPushEnv(PushEnvConfig.named("paper"))
    yield e
    e.close()


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
def test_centred_push_moves_block_forward_by_push_length(paper, theta):
    start = (0.5, 0.05, theta)
    end, _, _, info = push_from(paper, start, (0.0, 0.0, 1.0))
    forward, lateral = in_push_frame(start, end, theta)
    assert info["push_executed"]
    assert 0.08 < forward < 0.12  # ell = 1 is 0.1 m
    assert abs(lateral) < 0.015
    assert abs(end[2] - theta) < 0.1


def test_half_push_moves_about_half_as_far(paper):
    start = (0.5, 0.0, 0.0)
    end, _, _, _ = push_from(paper, start, (0.0, 0.0, 0.5))
    forward, _ = in_push_frame(start, end, 0.0)
    assert 0.035 < forward < 0.065


def test_off_centre_pushes_rotate_in_opposite_directions(paper):
    start = (0.5, 0.0, 0.3)
    left, _, _, _ = push_from(paper, start, (0.8, 0.0, 1.0))
    right, _, _, _ = push_from(paper, start, (-0.8, 0.0, 1.0))
    # contact at +y of the block frame turns it clockwise (negative theta), and vice versa
    assert left[2] - 0.3 < -0.2
    assert right[2] - 0.3 > 0.2


def test_angled_push_slides_along_the_face(paper):
    start = (0.5, 0.0, 0.0)
    end, _, _, _ = push_from(paper, start, (0.0, 0.6, 1.0))
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


def test_observation_equals_full_scene_render():
    from latent_sindy.worlds.push.world import PushWorld

    world = PushWorld(arm_visuals=True)  # the arm drawn wherever it is
    try:
        world.reset((0.5, 0.05, 0.3), (0.7, 0.0, 0.0))
        world.push(0.2, 0.3, 0.8)
        assert np.array_equal(world.observe(), world.observe_full_scene())
    finally:
        world.close()


def test_the_arm_without_its_visual_meshes_pushes_the_same_bit_for_bit():
    from latent_sindy.worlds.push.world import PushWorld

    rng = np.random.default_rng(5)
    pushes = np.column_stack([rng.uniform(-1, 1, 6), rng.uniform(-np.pi, np.pi, 6),
                              rng.uniform(0, 1, 6)])
    out = []
    for visuals in (True, False):
        world = PushWorld(PushEnvConfig.named("symmetric"), arm_visuals=visuals)
        try:
            world.reset((0.52, -0.04, 0.4), (0.7, 0.0, 0.0))
            poses = []
            for u in pushes:
                world.push(*u)
                poses.append(world.block_pose())
            out.append((np.array(poses), world.observe(), world.render_rgb()))
        finally:
            world.close()
    (p1, o1, r1), (p2, o2, r2) = out
    assert np.array_equal(p1, p2) and np.array_equal(o1, o2) and np.array_equal(r1, r2)
    assert np.abs(p1[-1] - [0.52, -0.04, 0.4]).max() > 0.01  # the pushes moved the block


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


def test_leaving_the_workspace_terminates(paper):
    paper.reset(options={"start": (0.5, 0.36, math.pi / 2), "goal": (0.7, 0.0, 0.0)})
    _, _, terminated, _, info = paper.step(np.array([0.0, 0.0, 1.0], dtype=np.float32))
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


@pytest.mark.parametrize("action", [[np.nan, 0, 0.5], [0, 0, 1.5], [0, 3.5, 0.5], [0, 0]])
def test_bad_actions_are_refused(env, action):
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(np.array(action, dtype=np.float32))


def test_paper_world_refuses_pushes_beyond_its_box(paper, env):
    for e in (paper, env):
        e.reset(seed=0)
    with pytest.raises(ValueError, match="outside the action box"):
        paper.step(np.array([0, 2.0, 0.5], dtype=np.float32))
    _, _, _, _, info = env.step(np.array([0, 2.0, 0.5], dtype=np.float32))  # psi: any direction
    assert info["push_executed"]


def test_rgb_observation_and_render():
    e = gym.make(register_env(), render_mode="rgb_array", channels=3)
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


# ---------------------------------------------------------------- named worlds and symmetry
def test_each_world_owns_its_action_box():
    for name, cfg in ENV_PRESETS.items():
        e = PandaPushEnv(cfg)
        assert e.action_space.shape == (cfg.action_dim,) == (len(cfg.action_names),), name
        assert np.allclose(e.action_space.low, cfg.action_low), name
        assert np.allclose(e.action_space.high, cfg.action_high), name
        e.close()
    sym, pap = PushEnvConfig(), PushEnvConfig.named("paper")
    assert sym.push == "symmetric" and sym.action_names == ("p", "psi", "ell")
    assert sym.action_high[1] == pytest.approx(math.pi)  # any direction
    assert pap.action_names == ("p", "phi", "ell") and pap.action_high[1] == pytest.approx(
        math.pi / 2)
    assert sym.angle_period == pytest.approx(math.pi / 2)
    assert PushEnvConfig.named("marked").angle_period == pytest.approx(2 * math.pi)


def test_named_worlds_and_records():
    assert PushEnvConfig.named("paper", channels=3).channels == 3
    with pytest.raises(UserError, match="'nope' is not a named world"):
        PushEnvConfig.named("nope")
    with pytest.raises(UserError, match="push='sideways'"):
        PushEnvConfig(push="sideways")
    record = to_json(PushEnvConfig.named("paper"))
    assert PushEnvConfig.from_record(record, "f.h5") == PushEnvConfig.named("paper")
    assert PushEnvConfig.from_record(to_json(PushEnvConfig()), "f.h5") == PushEnvConfig()
    with pytest.raises(UserError, match=r"f\.h5: unknown settings \['colour'\]") as e:
        PushEnvConfig.from_record({**record, "colour": "red"}, "f.h5")
    assert "\n" not in str(e.value)


QUARTER_TURN_CASES = [  # (x, y, theta), action: centred, off-centre, near a face's diagonal
    ((0.5, 0.1, 0.3), (0.0, 0.4, 1.0)),
    ((0.55, -0.15, -1.0), (0.7, 2.5, 0.8)),
    ((0.45, 0.2, 0.6), (-0.6, -1.2, 0.6)),
]


@pytest.mark.parametrize(("pose", "action"), QUARTER_TURN_CASES)
def test_poses_that_look_alike_are_pushed_alike(env, pose, action):
    """theta and theta + pi/2 give the same picture; the same push must then give the same
    next picture (in the paper's world it need not: see the next test)."""
    turned = (pose[0], pose[1], pose[2] + math.pi / 2)
    assert np.array_equal(env.observe(pose), env.observe(turned))
    end_a, _, obs_a, info_a = push_from(env, pose, action)
    end_b, _, obs_b, info_b = push_from(env, turned, action)
    assert info_a["push_executed"] and info_b["push_executed"]
    assert np.linalg.norm(end_a[:2] - pose[:2]) > 0.02  # the block did move
    assert np.array_equal(obs_a, obs_b)
    assert np.allclose(end_a[:2], end_b[:2], atol=1e-3)
    assert abs(wrap_angle(end_a[2] - end_b[2], math.pi / 2)) < 0.01


def test_paper_world_pushes_look_alike_poses_differently(paper):
    pose, action = QUARTER_TURN_CASES[0]
    turned = (pose[0], pose[1], pose[2] + math.pi / 2)
    _, obs0, obs_a, _ = push_from(paper, pose, action)
    _, obs0_b, obs_b, _ = push_from(paper, turned, action)
    assert np.array_equal(obs0, obs0_b) and not np.array_equal(obs_a, obs_b)


@pytest.mark.parametrize("theta", [0.0, 0.5, -1.3])
@pytest.mark.parametrize("direction", [0.0, 2.0, math.pi, -2.4])
def test_symmetric_push_goes_where_psi_points(env, theta, direction):
    """Pushing square onto a face (psi along a face normal, centred) moves the block by the
    push length along psi, whichever side of the block that face is on."""
    k = round((direction - theta) / (math.pi / 2))
    psi = wrap_angle(theta + k * math.pi / 2)  # a face normal near `direction`
    start = (0.52, 0.0, theta)
    end, _, _, info = push_from(env, start, (0.0, psi, 1.0))
    forward, lateral = in_push_frame(start, end, psi)
    assert info["push_executed"]
    assert 0.08 < forward < 0.12 and abs(lateral) < 0.015
    assert abs(wrap_angle(end[2] - theta, math.pi / 2)) < 0.1


# Pushes the arm could not start before the hand could turn round and lean: far from the
# base, pushed back towards it (and one along the far edge).
HARD_PUSHES = [
    ((0.65, -0.326, 0.721), (-0.65, 2.28, 0.54)),
    ((0.675, 0.328, -1.525), (0.73, 3.02, 0.96)),
    ((0.698, 0.197, -0.045), (-0.15, 2.37, 0.09)),
    ((0.67, 0.231, 0.749), (0.42, -3.09, 0.44)),
    ((0.694, 0.258, 1.491), (0.98, -2.74, 0.6)),
]


def test_pushes_in_every_direction_execute(env):
    rng = np.random.default_rng(123)
    cfg = env.config
    sample = [(rng.uniform(cfg.workspace_low, cfg.workspace_high),
               rng.uniform(cfg.action_low, cfg.action_high)) for _ in range(24)]
    executed = []
    for pose, action in HARD_PUSHES + sample:
        env.reset(seed=0, options={"start": pose, "goal": PAPER_GOAL})
        executed.append(env.step(np.asarray(action, dtype=np.float32))[4]["push_executed"])
    assert all(executed[:len(HARD_PUSHES)])
    assert sum(executed) >= len(executed) - 1  # >= 99 % in BENCHMARKS.md; 1 miss allowed here


# Recorded with the world as it was before push styles existed (commit ef20942): the paper
# world must push exactly as it did (bit for bit on the recording machine; the tolerance
# only absorbs other platforms' rounding, which pushing amplifies).
PAPER_GOLDEN = [
    ((0.5, 0.05, 0.7), (0.0, 0.0, 1.0), (0.5817725677500938, 0.1101252278668961, 0.6968855)),
    ((0.5, 0.0, 0.3), (0.8, 0.0, 1.0), (0.5903791032120479, 0.020655161624896876, -0.1914111)),
    ((0.45, -0.2, -1.0), (-0.5, 0.9, 0.6), (0.5163018237969701, -0.20836711112635697, -1.2714522)),
    ((0.6, 0.2, 1.2), (0.3, -1.1, 0.8), (0.6610755508385847, 0.21527385968783289, 1.6822066)),
]


@pytest.mark.parametrize(("start", "action", "expected"), PAPER_GOLDEN)
def test_paper_world_pushes_as_before(paper, env, start, action, expected):
    end, _, _, info = push_from(paper, start, action)
    assert info["push_executed"]
    assert np.allclose(end[:2], expected[:2], atol=2e-3)
    assert abs(end[2] - expected[2]) < 0.02
    sym_end, *_ = push_from(env, start, action)  # the symmetric world reads phi otherwise
    if abs(action[1]) > 0.05 or start[2] != 0.0:
        assert np.linalg.norm(sym_end[:2] - np.array(expected[:2])) > 0.01 or abs(
            wrap_angle(sym_end[2] - expected[2], math.pi / 2)) > 0.05


def test_angle_error_is_taken_modulo_the_visible_symmetry(env):
    goal = (0.6, 0.1, 0.2)
    turned = (0.6, 0.1, 0.2 + math.pi / 2 + 0.05)  # looks like the goal turned by 0.05 rad
    _, info = env.reset(options={"start": turned, "goal": goal})
    assert info["angle_error"] == pytest.approx(0.05, abs=1e-6)
    assert info["is_success_strict"]
    _, info = env.reset(options={"start": (0.6, 0.1, 0.2 + math.pi / 4 + 0.01), "goal": goal})
    assert info["angle_error"] == pytest.approx(-math.pi / 4 + 0.01, abs=1e-6)
    assert not info["is_success_strict"]
    marked = PandaPushEnv(PushEnvConfig.named("marked"))
    _, info = marked.reset(options={"start": turned, "goal": goal})
    assert info["angle_error"] == pytest.approx(math.pi / 2 + 0.05, abs=1e-6)
    assert not info["is_success_strict"]
    marked.close()


def test_wrap_angle_periods():
    assert wrap_angle(3 * math.pi / 4, math.pi / 2) == pytest.approx(math.pi / 4)
    assert wrap_angle(-math.pi / 4, math.pi / 2) == pytest.approx(math.pi / 4)  # (-p/2, p/2]
    assert wrap_angle(-math.pi) == pytest.approx(math.pi)
    assert wrap_angle(1.2 + 4 * math.pi) == pytest.approx(1.2)


def test_marked_block_shows_its_orientation(env):
    marked = PandaPushEnv(PushEnvConfig.named("marked"))
    pose = (0.5, 0.05, 0.3)
    turned = (0.5, 0.05, 0.3 + math.pi / 2)
    half = (0.5, 0.05, 0.3 + math.pi)
    assert not np.array_equal(marked.observe(pose), marked.observe(turned))
    assert not np.array_equal(marked.observe(pose), marked.observe(half))
    assert np.array_equal(env.observe(pose), env.observe(turned))
    # the same block otherwise: same place, same size on the picture
    dark = (marked.observe(pose)[0] < 150).sum()
    assert dark == (env.observe(pose)[0] < 150).sum()
    marked.close()
