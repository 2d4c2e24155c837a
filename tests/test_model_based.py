"""Planning against a learned reward: the reward head learns a reward of the state, MPPI with
the reward cost prefers the actions that earn more, and the model-based loop (seed episodes,
fit, planned episodes, refit) appends its episodes, resumes its folder and repeats itself
for a seed; on a tiny synthetic world, and once on the DeepMind Control cartpole."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from latent_sindy import LatentSINDy, SequenceData
from latent_sindy.control import MPPI, MPPIConfig, RewardCost
from latent_sindy.control.collect import collect_random
from latent_sindy.data import concatenate
from latent_sindy.errors import UserError
from latent_sindy.model_based import ModelBasedConfig, model_based
from latent_sindy.models import ModelConfig
from latent_sindy.models.autoencoder import AutoencoderConfig
from latent_sindy.models.dynamics import SindyConfig
from latent_sindy.models.latent_model import LatentModel
from latent_sindy.training import TrainConfig
from rail_world import H, Rail, W

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def model(head: int = 32) -> ModelConfig:
    return ModelConfig(dynamics=SindyConfig(order=1, include_sine=False),
                       observation=AutoencoderConfig(latent_dim=2, encoder_kind="mlp",
                                                     decoder_kind="mlp"), reward_head=head)


def estimator(seed: int = 0) -> LatentSINDy:
    return LatentSINDy(model=model(), settings=TrainConfig(lr=3e-3), seed=seed)


def test_the_reward_head_learns_a_reward_of_the_state():
    world = Rail()
    data = collect_random(world, sequences=30, steps=5, seed=0)
    est = estimator().fit(data, epochs=80, batch_size=20)
    test = collect_random(world, sequences=10, steps=5, seed=7)
    x = est.normalizer_.normalize(test.images[:, :-1]).flatten(0, 1)
    u = torch.as_tensor(test.actions).flatten(0, 1)
    with torch.no_grad():
        r = est.model_.reward_head(est.model_.encode(x), u).numpy()
    truth = test.rewards.reshape(-1)
    r2 = 1 - np.sum((r - truth) ** 2) / np.sum((truth - truth.mean()) ** 2)
    assert r2 > 0.9, r2
    assert est.metrics_[-1]["train/reward"] < est.metrics_[0]["train/reward"]


def test_a_model_without_a_head_is_built_and_trained_as_before():
    """The head is built last: the other weights draw the same numbers with or without it,
    and without rewards or a head the loss has a zero reward term."""
    plain, headed = (model(head=0).resolve(1, (H, W), 1), model().resolve(1, (H, W), 1))
    torch.manual_seed(0)
    a = LatentModel(plain).state_dict()
    torch.manual_seed(0)
    b = LatentModel(headed).state_dict()
    assert set(b) - set(a) == {k for k in b if k.startswith("reward_head.")}
    assert all(torch.equal(a[k], b[k]) for k in a)
    x, u = torch.zeros(2, 4, 1, H, W), torch.zeros(2, 3, 1)
    assert float(LatentModel(plain).loss(x, u)["reward"]) == 0.0


def test_a_reward_head_needs_rewards():
    data = collect_random(Rail(), sequences=4, steps=3, seed=0).replace(rewards=None)
    with pytest.raises(UserError, match="no rewards"):
        estimator().fit(data, epochs=1)


def test_planning_toward_the_reward_needs_a_head():
    data = collect_random(Rail(), sequences=4, steps=3, seed=0)
    plain = LatentSINDy(model=model(head=0), seed=0).fit(data, epochs=1)
    with pytest.raises(UserError, match="no reward head"):
        plain.planner(objective="reward")
    planner = estimator().fit(data, epochs=1).planner(objective="reward")
    assert planner.act(data.images[0, 0]).shape == (1,)  # no goal image needed
    with pytest.raises(UserError, match="no goal"):
        planner.act(data.images[0, 0], data.images[0, 1])


def test_the_reward_cost_makes_mppi_prefer_the_actions_that_earn_more():
    """z' = z + u, r̂(z, u) = z + u: the plan's first action goes to the top of the box;
    with r̂ = −(z + u) to the bottom."""
    cfg = MPPIConfig(samples=200, horizon=5, sigma=0.5, lambda_=0.1)
    for sign in (1.0, -1.0):
        def reward(z, u, sign=sign):
            return sign * (z + u).sum(-1)

        mppi = MPPI(lambda z, u: z + u, RewardCost(reward), cfg, low=(-1.0,), high=(1.0,),
                    seed=0)
        for _ in range(5):
            action, info = mppi.command(torch.zeros(1))
        assert sign * float(action) > 0.8, (sign, action, info)


def test_the_reward_cost_keeps_plans_inside_the_support_it_is_given():
    """r̂(z, u) = z + u rewards climbing; a support up to 0.5 (weight 10) holds the plan's
    first action near 0.5 where, without it, the plan climbs at full speed."""
    cfg = MPPIConfig(samples=400, horizon=5, sigma=0.5, lambda_=0.1)
    firsts = {}
    for weight in (0.0, 10.0):
        cost = RewardCost(lambda z, u: (z + u).sum(-1),
                          (torch.tensor([-1.0]), torch.tensor([0.5])), weight)
        mppi = MPPI(lambda z, u: z + u, cost, cfg, low=(-1.0,), high=(1.0,), seed=0)
        for _ in range(5):
            action, _ = mppi.command(torch.zeros(1))
        firsts[weight] = float(action)
    assert firsts[0.0] > 0.8 and 0.3 < firsts[10.0] < 0.7, firsts
    for bad in ({"support": (torch.zeros(1), -torch.ones(1)), "weight": 1.0},
                {"support": None, "weight": -1.0}):
        with pytest.raises(UserError):
            RewardCost(lambda z, u: z.sum(-1), **bad)


def test_concatenate_keeps_labels_and_refuses_parts_that_differ():
    world = Rail()
    a, b = collect_random(world, 3, 2, seed=0), collect_random(world, 4, 2, seed=1)
    both = concatenate([a, b])
    assert both.n == 7 and both.rewards.shape == (7, 2)
    np.testing.assert_array_equal(both.split_ids, np.r_[a.split_ids, b.split_ids])
    np.testing.assert_array_equal(both.images[3:], b.images)
    with pytest.raises(UserError, match="rewards"):
        concatenate([a, b.replace(rewards=None)])
    with pytest.raises(UserError, match="steps"):
        concatenate([a, collect_random(world, 3, 3, seed=0)])


LOOP = ModelBasedConfig(seed_episodes=3, iterations=2, episode_steps=6, validation_every=3,
                        mppi=MPPIConfig(samples=40, horizon=4, sigma=0.3, lambda_=0.5))


def test_the_loop_appends_planned_episodes_resumes_and_repeats(tmp_path):
    world, fit = Rail(), {"epochs": 30, "batch_size": 8}
    whole = model_based(world, estimator, LOOP, out=tmp_path / "whole", fit_settings=fit)
    assert whole.data.n == 5 and whole.data.rewards.shape == (5, 6)
    log = whole.log
    assert [e["kind"] for e in log["episodes"]] == ["random"] * 3 + ["planned"] * 2
    assert [e["env_steps"] for e in log["episodes"]] == [6, 12, 18, 24, 30]
    assert log["done"] == 2 and len(log["iterations"]) == 2
    np.testing.assert_allclose(whole.returns, whole.data.rewards.sum(1), rtol=1e-6)
    assert json.loads((tmp_path / "whole" / "log.json").read_text()) == log
    # Killed after iteration 1 (its folder written), then run again to the end.
    first = model_based(world, estimator, ModelBasedConfig(**{**LOOP.__dict__,
                                                              "iterations": 1}),
                        out=tmp_path / "resumed", fit_settings=fit)
    assert first.data.n == 4
    resumed = model_based(world, estimator, LOOP, out=tmp_path / "resumed", fit_settings=fit)
    assert resumed.returns == whole.returns
    np.testing.assert_array_equal(resumed.data.images, whole.data.images)
    # Done: a rerun fits nothing; other settings are refused.
    again = model_based(world, estimator, LOOP, out=tmp_path / "resumed", fit_settings=fit)
    assert again.estimator is None and again.returns == whole.returns
    with pytest.raises(UserError, match="explore"):
        model_based(world, estimator, ModelBasedConfig(**{**LOOP.__dict__, "explore": 0.5}),
                    out=tmp_path / "resumed")
    # In memory, the same seed gives the same returns.
    assert model_based(world, estimator, LOOP, fit_settings=fit).returns == whole.returns


def test_planned_episodes_earn_more_than_random_ones():
    world = Rail()
    cfg = ModelBasedConfig(seed_episodes=20, iterations=1, episodes_per_iteration=4,
                           episode_steps=5, validation_every=5, explore=0.1,
                           mppi=MPPIConfig(samples=100, horizon=4, sigma=0.5, lambda_=0.3))
    result = model_based(world, estimator, cfg, fit_settings={"epochs": 80, "batch_size": 20})
    kinds = np.array([e["kind"] for e in result.log["episodes"]])
    returns = np.array(result.returns)
    assert returns[kinds == "planned"].mean() > returns[kinds == "random"].mean() + 0.5, returns


def test_the_loop_in_the_deepmind_control_cartpole(tmp_path):
    pytest.importorskip("dm_control")
    from latent_sindy.worlds.dmc.config import DmcConfig
    from latent_sindy.worlds.dmc.plugin import DmcWorld

    world = DmcWorld(DmcConfig(task="cartpole-swingup", size=16, frames=1))
    cfg = ModelBasedConfig(seed_episodes=3, iterations=1, episode_steps=4, validation_every=3,
                           steps_per_action=8,
                           mppi=MPPIConfig(samples=20, horizon=3, sigma=0.3, lambda_=1.0))
    result = model_based(world, lambda i: LatentSINDy(
        model=ModelConfig(dynamics=SindyConfig(order=1, include_sine=False),
                          observation=AutoencoderConfig(latent_dim=3, encoder_kind="mlp",
                                                        decoder_kind="mlp"), reward_head=16),
        seed=i), cfg, out=tmp_path / "mbrl", fit_settings={"epochs": 2})
    assert result.data.images.shape == (4, 5, 3, 16, 16)
    assert result.log["episodes"][-1]["env_steps"] == 4 * 4 * 8
    assert all(0 <= r <= 4 * 8 for r in result.returns)
    assert isinstance(result.data, SequenceData)


def test_test_episodes_are_planned_without_noise_and_kept_out_of_the_data():
    world, fit = Rail(), {"epochs": 30, "batch_size": 8}
    plain = model_based(world, estimator, LOOP, fit_settings=fit)
    cfg = ModelBasedConfig(**{**LOOP.__dict__, "eval_episodes": 2})
    tested = model_based(world, estimator, cfg, fit_settings=fit)
    assert tested.returns == plain.returns and tested.data.n == plain.data.n
    its = tested.log["iterations"]
    assert [len(it["evaluation"]) for it in its] == [2, 2]
    assert [it["fit_env_steps"] for it in its] == [18, 24]
    assert all(np.isfinite(it["evaluation"]).all() for it in its)
    # Iteration 1's fit sees only the seed episodes, so its test returns do not depend on
    # the training episodes' exploration noise: they have none.
    noisier = model_based(world, estimator, ModelBasedConfig(
        **{**cfg.__dict__, "explore": 0.9, "iterations": 1}), fit_settings=fit)
    assert noisier.log["iterations"][0]["evaluation"] == its[0]["evaluation"]
    assert noisier.returns[-1] != tested.returns[3]


def test_random_actions_held_for_several_steps_and_one_step_as_before():
    world = Rail()
    once = collect_random(world, 3, 12, seed=0)
    assert np.array_equal(once.actions, collect_random(world, 3, 12, seed=0, hold=1).actions)
    held = collect_random(world, 3, 12, seed=0, hold=4).actions  # (3, 12, nu)
    blocks = held.reshape(3, 3, 4, -1)
    assert np.array_equal(blocks, np.repeat(blocks[:, :, :1], 4, axis=2))
    assert not np.array_equal(blocks[:, 0, 0], blocks[:, 1, 0])  # a new draw each block
    with pytest.raises(UserError, match="hold=0"):
        collect_random(world, 1, 2, seed=0, hold=0)
    with pytest.raises(UserError, match="seed_hold"):
        ModelBasedConfig(seed_hold=0)


def test_a_read_latent_loop_logs_what_its_reader_found(tmp_path):
    from latent_sindy.models.geodesic_reader import GeodesicReader
    from latent_sindy.read_latent import ReadLatent, ReadLatentConfig

    notes: list[str] = []

    class Notes:
        def start(self, total, initial): ...
        def update(self, epoch, metrics): ...
        def note(self, text): notes.append(text)
        def close(self): ...

    cfg = ModelBasedConfig(seed_episodes=6, iterations=1, episodes_per_iteration=1,
                           episode_steps=6, validation_every=5, warm_updates=0,
                           mppi=MPPIConfig(samples=20, horizon=3))
    result = model_based(Rail(), lambda i: ReadLatent(
        GeodesicReader(frames=1, dim=1, landmarks=30, neighbours=5),
        ReadLatentConfig(updates=20), seed=i), cfg, out=tmp_path / "loop", progress=Notes())
    latent = result.log["iterations"][0]["latent"]
    assert latent["reader"]["reader"] == "geodesic" and latent["reader"]["dim"] == 1
    assert latent["coordinates"] == ["g0", "g0'"] and 0 < latent["seen_share"] <= 1
    assert json.loads((tmp_path / "loop" / "log.json").read_text())["iterations"][0][
        "latent"] == latent
    assert any(n.startswith("iteration 1: latent g0, g0': 1 geodesic coordinate") for n in notes)
