"""The textured world (``PushEnvConfig.named("textured")``): the symmetric world's physics seen
over a wood-grain table, in a light drawn per episode, with a distractor nothing touches."""

from __future__ import annotations

import dataclasses

import h5py
import numpy as np
import pytest

from latent_sindy.cli import main
from latent_sindy.configs import to_json
from latent_sindy.data import read_sequences
from latent_sindy.worlds.push._bullet import BulletClient, quiet_c_output
from latent_sindy.worlds.push._bullet import pybullet as pb
from latent_sindy.worlds.push.collect import CollectionPlan, same_plan
from latent_sindy.worlds.push.config import BLOCK_SIZE, ENV_PRESETS, PushEnvConfig
from latent_sindy.worlds.push.data import push_config
from latent_sindy.worlds.push.panda_push import PandaPushEnv
from latent_sindy.worlds.push.scene import (
    BLOCK_RGBA,
    TABLE_CENTRE,
    TABLE_HALF,
    TABLE_RGBA,
    CameraView,
    draw_look,
    place,
)

TEXTURED = PushEnvConfig.named("textured")
START, GOAL = (0.5, 0.05, 0.3), (0.7, 0.0, 0.0)
NEW_FIELDS = ("table_look", "lighting", "distractor")


def far_from_block(cam, pose, rows: int = 26) -> np.ndarray:
    """(S, S) bool: pixels at least 4 pixels from the block's centre, above the distractor's
    strip (row 26 on)."""
    r, c = cam.world_to_pixel((pose[0], pose[1], BLOCK_SIZE[2]))
    rr, cc = np.mgrid[:cam.size, :cam.size]
    return (np.hypot(rr - r, cc - c) >= 4) & (rr < rows)


@pytest.fixture(scope="module")
def worlds():
    sym, tex = PandaPushEnv(PushEnvConfig.named("symmetric")), PandaPushEnv(TEXTURED)
    yield sym, tex
    sym.close()
    tex.close()


def test_the_textured_world_is_the_symmetric_one_seen_otherwise():
    sym = PushEnvConfig.named("symmetric")
    assert TEXTURED.world_name == "textured" and sym.world_name == "symmetric"
    assert dataclasses.replace(TEXTURED, table_look="plain", lighting="fixed",
                               distractor=False) == sym
    for name in ("symmetric", "paper", "marked"):  # the new options are off elsewhere
        cfg = ENV_PRESETS[name]
        assert (cfg.table_look, cfg.lighting, cfg.distractor) == ("plain", "fixed", False)
        assert not cfg.varies_by_episode
    with pytest.raises(ValueError, match=r"table_look='wood'.*plain, textured"):
        PushEnvConfig(table_look="wood")
    with pytest.raises(ValueError, match=r"lighting='dim'.*fixed, varied"):
        PushEnvConfig(lighting="dim")


def test_same_seed_and_actions_push_alike_but_the_pictures_differ(worlds):
    sym, tex = worlds
    actions = np.array([[0.3, 2.0, 0.9], [-0.5, -0.4, 0.7]], dtype=np.float32)
    obs_s, info_s = sym.reset(seed=11)
    obs_t, info_t = tex.reset(seed=11)
    pairs = [(obs_s, obs_t, info_s["pose"], info_t["pose"])]
    for a in actions:
        obs_s, _, _, _, info_s = sym.step(a)
        obs_t, _, _, _, info_t = tex.step(a)
        assert info_s["push_executed"] and info_t["push_executed"]
        pairs.append((obs_s, obs_t, info_s["pose"], info_t["pose"]))
    assert np.abs(pairs[-1][2] - pairs[0][2])[:2].max() > 0.02  # the pushes moved the block
    for img_s, img_t, pose_s, pose_t in pairs:
        assert np.array_equal(pose_s, pose_t)  # physics unchanged, to the last bit
        bg = far_from_block(sym.world.camera, pose_s)
        assert len(np.unique(img_s[0][bg])) == 1  # the plain table: one grey
        assert (img_t[0][bg] != img_s[0][bg]).mean() > 0.9
        assert img_t[0][bg].std() > 5  # planks, seams and knots show at 32x32


def test_lighting_differs_between_episodes_and_repeats_with_the_seed(worlds):
    _, tex = worlds
    options = {"start": START, "goal": GOAL}
    a, _ = tex.reset(seed=1, options=options)
    goal_a = tex.goal_observation()
    again, _ = tex.reset(seed=1, options=options)
    assert np.array_equal(a, again) and np.array_equal(goal_a, tex.goal_observation())
    b, _ = tex.reset(seed=2, options=options)
    assert not np.array_equal(goal_a, tex.goal_observation())
    bg = far_from_block(tex.world.camera, START)
    assert abs(a[0][bg].mean() - b[0][bg].mean()) > 10  # a brighter light on the same table
    assert draw_look(TEXTURED, 1) == draw_look(TEXTURED, 1) != draw_look(TEXTURED, 2)
    # with the light fixed, two episodes see the same table
    still = PandaPushEnv(dataclasses.replace(TEXTURED, lighting="fixed", distractor=False))
    try:
        c, _ = still.reset(seed=1, options=options)
        d, _ = still.reset(seed=2, options=options)
    finally:
        still.close()
    assert np.array_equal(c, d)


def test_the_goal_image_is_seen_in_the_episodes_light(worlds):
    _, tex = worlds
    tex.reset(seed=4, options={"start": GOAL, "goal": GOAL})
    assert np.array_equal(tex.goal_observation(), tex.observe())


def test_the_distractor_stands_beyond_the_block_and_moves_per_episode():
    cfg = dataclasses.replace(PushEnvConfig.named("symmetric"), distractor=True)
    plain, shown = CameraView(PushEnvConfig.named("symmetric")), CameraView(cfg)
    try:
        images = []
        for seed in (0, 1):
            shown.set_look(draw_look(cfg, seed))
            img, ref = shown.observe(START)[0], plain.observe(START)[0]
            rows = np.nonzero((img != ref).any(1))[0]
            assert rows.size and rows.min() >= 26  # only in its strip, below the block's
            assert img.min() < ref.min()  # dark
            images.append(img)
        assert not np.array_equal(*images)
        assert shown.client.getCollisionShapeData(shown.distractor, -1) == ()  # untouchable
    finally:
        plain.close()
        shown.close()


def _reference_scene(pose) -> np.ndarray:
    """The plain world's picture built here from the documented parts, by hand: what the
    existing worlds must keep showing."""
    with quiet_c_output():
        c = BulletClient(connection_mode=pb.DIRECT)
    try:
        c.createMultiBody(0, -1, c.createVisualShape(pb.GEOM_BOX, halfExtents=TABLE_HALF,
                                                     rgbaColor=TABLE_RGBA),
                          basePosition=TABLE_CENTRE)
        half = [s / 2 for s in BLOCK_SIZE]
        block = c.createMultiBody(1, -1, c.createVisualShape(pb.GEOM_BOX, halfExtents=half,
                                                             rgbaColor=BLOCK_RGBA))
        place(c, block, pose)
        cam = CameraView(PushEnvConfig()).camera
        _, _, rgba, _, _ = c.getCameraImage(32, 32, cam.view, cam.projection,
                                            renderer=pb.ER_TINY_RENDERER, shadow=0,
                                            flags=pb.ER_NO_SEGMENTATION_MASK)
        return np.asarray(rgba, dtype=np.uint8).reshape(32, 32, 4)[..., :3]
    finally:
        c.disconnect()


def test_the_existing_worlds_look_and_draw_as_before(env):
    view = CameraView(PushEnvConfig.named("symmetric", channels=3))
    try:
        for pose in (START, (0.62, -0.2, -1.1)):
            assert np.array_equal(view.observe(pose).transpose(1, 2, 0), _reference_scene(pose))
    finally:
        view.close()
    # no look drawn: the seed's generator gave the two poses and nothing else
    env.reset(seed=9)
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(9)))
    cfg = env.config
    rng.uniform(cfg.workspace_low, cfg.workspace_high, size=(2, 3))
    assert np.array_equal(env.sample_pose(), rng.uniform(cfg.workspace_low, cfg.workspace_high))


def test_plans_recorded_before_the_new_options_still_match():
    plan = CollectionPlan(trajectories=4, steps=2)
    old = to_json(plan)
    old["env"] = {k: v for k, v in old["env"].items() if k not in NEW_FIELDS}
    assert same_plan(old, plan)
    assert not same_plan(old, dataclasses.replace(plan, env=TEXTURED))
    assert not same_plan({**old, "env": {**old["env"], "push": "paper"}}, plan)


def test_collect_writes_the_textured_world(tmp_path, capsys):
    out = tmp_path / "tex.h5"
    args = ["collect", "--out", str(out), "--trajectories", "2", "--steps", "1", "--workers",
            "1", "--no-progress", "--val-fraction", "0", "--test-fraction", "0",
            "--table-look", "textured", "--lighting", "varied", "--distractor"]
    assert main(args) == 0
    data = read_sequences(out)
    env = push_config(data)
    assert env == TEXTURED and env.world_name == "textured"
    assert {k: data.record["env_config"][k] for k in NEW_FIELDS} == {
        "table_look": "textured", "lighting": "varied", "distractor": True}
    first = data.images[:, 0, 0]  # (2, S, S): each trajectory's first picture
    cam = CameraView(env).camera
    for img, pose in zip(first, data.states[:, 0], strict=True):
        assert img[far_from_block(cam, pose)].std() > 5  # the texture shows
    both = far_from_block(cam, data.states[0, 0]) & far_from_block(cam, data.states[1, 0])
    assert abs(float(first[0][both].mean()) - float(first[1][both].mean())) > 1  # two lights
    capsys.readouterr()
    assert main(args) == 0 and "already complete" in capsys.readouterr().out
    with h5py.File(out) as f:  # the record names the world's settings
        assert '"table_look": "textured"' in f.attrs["world_record"]
