"""The gym world (``--world gym``): any Gymnasium environment seen through its rgb_array
frames, on a blob environment the test registers (tests/gym_blob.py; no pygame needed):
frames resized and stacked, the environment's own rewards recorded, Box actions only, clear
one-line refusals, and collect → the model-based loop → a planned test episode at toy size."""

from __future__ import annotations

import importlib.util
import json
import sys

import gymnasium as gym
import numpy as np
import pytest

import gym_blob
from latent_sindy.control import MPPIConfig
from latent_sindy.data import read_sequences
from latent_sindy.errors import UserError
from latent_sindy.model_based import ModelBasedConfig, model_based
from latent_sindy.models import ModelConfig
from latent_sindy.models.autoencoder import AutoencoderConfig
from latent_sindy.models.dynamics import SindyConfig
from latent_sindy.worlds.gym import GymConfig, GymWorld

pytestmark = pytest.mark.usefixtures("one_torch_thread")

BLOB = "gym_blob:BlobTest-v0"
SMALL = GymConfig(id=BLOB, size=16)


def _one_line(e: pytest.ExceptionInfo) -> str:
    text = str(e.value)
    assert "\n" not in text, text
    return text


def test_frames_are_resized_stacked_and_the_rewards_are_the_environments():
    world = GymWorld(SMALL)
    data = world.collect(sequences=3, steps=5, seed=0)
    assert data.images.shape == (3, 6, 6, 16, 16) and data.images.dtype == np.uint8
    assert data.world == "gym" and data.world_config == SMALL
    assert data.actions.shape == (3, 5, 2) and np.all(np.abs(data.actions) <= 1)
    assert world.action_low == (-1.0, -1.0) and world.action_high == (1.0, 1.0)
    assert data.states.shape == (3, 6, 2) and data.state_names == ("obs0", "obs1")
    assert data.dt == pytest.approx(1 / 20)  # one frame of the environment's render_fps
    # frames stacked oldest first: a frame's older half is the previous frame's newer half
    np.testing.assert_array_equal(data.images[:, 1:, :3], data.images[:, :-1, 3:])
    # the rewards are the environment's: replayed in gymnasium from the same seeded resets
    rng = np.random.default_rng(0)
    for i in range(3):
        task = world.sample_task(rng)
        for _ in range(5):
            rng.uniform(-1, 1, 2)  # (the actions collect drew; replayed from the data)
        env = gym.make(BLOB)
        obs, _ = env.reset(seed=int(task.start[0]))
        np.testing.assert_array_equal(obs, data.states[i, 0])
        rewards = [env.step(u)[1] for u in data.actions[i]]
        np.testing.assert_allclose(data.rewards[i], rewards, rtol=1e-6)
    # the blob is where the state says: its brightest pixel moves with it
    x = data.images[:, :, 3].reshape(-1, 256).argmax(1) % 16
    assert np.corrcoef(x, data.states[..., 0].reshape(-1))[0, 1] > 0.9
    # the same seed, the same data; gray frames one channel each
    assert world.collect(3, 5, seed=0).fingerprint() == data.fingerprint()
    gray = GymWorld(GymConfig(id=BLOB, size=12, frames=3, gray=True)).collect(1, 2, seed=1)
    assert gray.images.shape == (1, 3, 3, 12, 12)


def test_collect_through_the_cli_reads_back_with_its_settings(tmp_path):
    from latent_sindy.cli import main

    out = tmp_path / "blob.h5"
    assert main(["collect", "--world", "gym", "--world-config", f"id={BLOB}", "size=16",
                 "frames=1", "--trajectories", "2", "--steps", "3", "--out", str(out)]) == 0
    data = read_sequences(out)
    assert data.world == "gym" and data.world_config == GymConfig(id=BLOB, size=16, frames=1)
    assert data.images.shape == (2, 4, 3, 16, 16) and data.rewards.shape == (2, 3)


def test_an_id_gymnasium_cannot_make_is_refused_in_one_line(tmp_path, capsys):
    from latent_sindy.cli import main

    with pytest.raises(UserError) as e:
        GymWorld(GymConfig(id="NoSuchThing-v0")).collect(1, 1)
    assert "NoSuchThing-v0" in _one_line(e) and "Pendulum-v1" in str(e.value)
    assert main(["collect", "--world", "gym", "--world-config", "id=NoSuchThing-v0",
                 "--out", str(tmp_path / "x.h5")]) == 2
    err = capsys.readouterr().err.strip()
    assert "NoSuchThing-v0" in err and len(err.splitlines()) == 1
    with pytest.raises(UserError, match=r"use an integer in 8\.\.512"):
        GymConfig(size=4)


def test_a_discrete_action_space_is_refused():
    with pytest.raises(UserError, match="not a Box") as e:
        GymWorld(GymConfig(id="gym_blob:BlobDiscrete-v0")).action_low  # noqa: B018
    assert "Discrete(3)" in _one_line(e)


def test_a_missing_renderer_names_the_install_command():
    with pytest.raises(UserError) as e:
        GymWorld(GymConfig(id="gym_blob:BlobNoRenderer-v0")).collect(1, 1)
    assert "pip install 'latent-sindy[gym]'" in _one_line(e)


def test_pendulum_without_pygame_names_the_install_command(monkeypatch):
    monkeypatch.setitem(sys.modules, "pygame", None)  # (as if not installed, where it is)
    with pytest.raises(UserError) as e:
        GymWorld(GymConfig(id="Pendulum-v1", size=32)).collect(1, 1)
    assert "pygame" in _one_line(e) and "pip install 'latent-sindy[gym]'" in str(e.value)


@pytest.mark.skipif(importlib.util.find_spec("pygame") is None, reason="needs pygame")
def test_pendulum_frames_and_rewards():
    data = GymWorld(GymConfig(id="Pendulum-v1", size=32)).collect(2, 3, seed=0)
    assert data.images.shape == (2, 4, 6, 32, 32) and data.dt == pytest.approx(0.05)
    assert data.actions.shape == (2, 3, 1) and np.all(np.abs(data.actions) <= 2)
    assert np.all(data.rewards <= 0) and np.all(data.rewards >= -16.3)


def test_a_goal_image_is_refused_the_world_is_scored_by_its_reward():
    world = GymWorld(SMALL)
    env = world.make_env()
    with pytest.raises(UserError, match="scored by its reward"):
        world.goal_image(env, world.sample_task(np.random.default_rng(0)))
    env.close()


def _estimator(iteration: int):
    from latent_sindy import LatentSINDy

    model = ModelConfig(dynamics=SindyConfig(order=1, include_sine=False), reward_head=16,
                        observation=AutoencoderConfig(latent_dim=2, encoder_kind="mlp",
                                                      decoder_kind="mlp"))
    return LatentSINDy(model=model, seed=iteration)


def test_collect_the_model_based_loop_and_a_planned_test_episode(tmp_path):
    world = GymWorld(SMALL)
    cfg = ModelBasedConfig(seed_episodes=3, iterations=1, episode_steps=6, eval_episodes=1,
                           warm_updates=0, mppi=MPPIConfig(samples=32, horizon=3, sigma=0.3,
                                                           lambda_=0.1, shift="repeat"))
    result = model_based(world, _estimator, cfg, out=tmp_path / "loop",
                         fit_settings={"epochs": 3})
    data = result.data
    assert [e["kind"] for e in result.log["episodes"]] == ["random"] * 3 + ["planned"]
    # every action, random or planned with its exploration noise, inside the env's box
    assert np.all(np.abs(data.actions) <= 1)
    # the planned episode's rewards are the environment's for the states it reached
    np.testing.assert_allclose(data.rewards[3], -np.sum(data.states[3, 1:] ** 2, axis=1),
                               rtol=1e-5)
    test = result.log["iterations"][0]["evaluation"]
    assert len(test) == 1 and -2.0 * 6 <= test[0] <= 0.0  # six steps of -(x² + y²)
    assert json.loads((tmp_path / "loop" / "log.json").read_text())["done"] == 1
    # the planner's actions themselves are inside the box
    planner = result.estimator.planner(cfg.mppi, seed=0, objective="reward")
    planner.reset(None, 0)
    u = planner.act(data.images[0, 0])
    assert u.shape == (2,) and np.all(np.abs(u) <= 1)
    # an episode longer than the environment's time limit is refused, saying so
    long = ModelBasedConfig(seed_episodes=1, iterations=0, episode_steps=gym_blob.LIMIT + 1)
    with pytest.raises(UserError, match=f"ended its episode after {gym_blob.LIMIT} actions"):
        model_based(world, _estimator, long)


def test_the_tiny_study_through_the_cli(tmp_path, capfd):
    """The dmc world's model-based study over a gym environment: three dynamics, two loops at
    a time in worker processes (which import the blob's module through its id)."""
    from latent_sindy.cli import main

    out = tmp_path / "study"
    assert main(["reproduce", "--world", "gym", "--world-config", f"id={BLOB}", "--scale",
                 "tiny", "--out", str(out)]) == 0
    err = capfd.readouterr().err
    assert f"gym {BLOB}, tiny scale: 16x16, 1 frame(s)" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["world"] == "gym" and summary["study"]["world"]["id"] == BLOB
    runs = summary["results"]["runs"]
    assert set(runs) == {"sindy/seed0", "linear/seed0", "mlp/seed0"}
    assert all(len(r["returns"]) == 4 and max(r["returns"]) <= 0 for r in runs.values())
    assert summary["results"]["reference"] is None
    table = (out / "table.md").read_text()
    assert "Gymnasium from pixels" in table and "## Last return\n" in table
    assert "published:" not in table  # (no published lines of a user's environment)
    assert "z0[t+1] = z0" in (out / "equations_sindy_seed0.txt").read_text()
    # other settings of the world into the same folder are refused
    assert main(["reproduce", "--world", "gym", "--world-config", f"id={BLOB}", "size=12",
                 "--scale", "tiny", "--out", str(out)]) == 2
    assert "other settings (world)" in capfd.readouterr().err




def test_the_geodesic_latent_learned_from_frames_plans_better_than_random(tmp_path):
    """The scale whose latent is learned from the frames alone (their geodesic coordinates;
    no reader written for the world): SINDy's planned test episode earns more than the
    random seed episodes did on average."""
    from latent_sindy.study.model_based import run_seed, scale_reader
    from latent_sindy.worlds.gym.study import SCALES

    s = SCALES["geodesic-tiny"]
    world = GymWorld(GymConfig(id=BLOB, size=s.size, frames=s.frames))
    log = run_seed(world, s, 0, "sindy", tmp_path, "cpu", 1, lambda _: None,
                   reader=scale_reader(s, s.frames))["log"]
    random = [e["return"] for e in log["episodes"] if e["kind"] == "random"]
    tested = log["iterations"][-1]["evaluation"]
    assert len(random) == 3 and len(tested) == 1
    assert tested[0] > sum(random) / len(random) + 2.0, (random, tested)


def test_the_keypoints_scale_is_the_geodesic_loop_on_keypoints_kept_in_the_study(tmp_path):
    from latent_sindy.models.keypoint_reader import KeypointReader
    from latent_sindy.study.model_based import scale_reader
    from latent_sindy.worlds.gym.study import SCALES

    s, g = SCALES["keypoints"], SCALES["geodesic"]
    # geodesic's loop and planner; only the latent differs
    assert {k: v for k, v in vars(s).items() if k not in ("about", "latent", "latent_dim")} == {
        k: v for k, v in vars(g).items() if k not in ("about", "latent", "latent_dim")}
    reader = scale_reader(s, 2, out=tmp_path)()
    assert isinstance(reader, KeypointReader) and reader.parts == s.latent_dim == 4
    assert reader.store == tmp_path / "readers" and reader.angle is None
