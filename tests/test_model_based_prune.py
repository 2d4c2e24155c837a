"""The model-based loop's fixed batches and its pruning across refits, on the synthetic rail
world: every fit takes the loop's batch size however much data there is, a refit on more data
than its budget does exactly its budget of updates, a SINDy model's active terms fall refit
after refit down to the floor, a resumed run prunes as the uninterrupted one did, and a
folder of a run from before these settings is refused by name."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest
import torch

from latent_sindy import LatentSINDy
from latent_sindy.control import MPPIConfig
from latent_sindy.errors import UserError
from latent_sindy.model_based import ModelBasedConfig, model_based
from latent_sindy.models import ModelConfig
from latent_sindy.models.autoencoder import AutoencoderConfig
from latent_sindy.models.dynamics import SindyConfig
from latent_sindy.training import TrainConfig
from rail_world import Rail

pytestmark = pytest.mark.usefixtures("one_torch_thread")

FIT = {"epochs": 4, "window": 2}  # windows of 2 actions: batches of windows
LOOP = ModelBasedConfig(seed_episodes=3, iterations=4, episode_steps=6, validation_every=3,
                        warm_updates=3, batch_size=4, prune_rate=0.3, prune_to=10,
                        mppi=MPPIConfig(samples=20, horizon=2, sigma=0.3, lambda_=0.5))


def make(iteration: int) -> LatentSINDy:
    return LatentSINDy(model=ModelConfig(
        dynamics=SindyConfig(order=2, include_sine=True),
        observation=AutoencoderConfig(latent_dim=3, encoder_kind="mlp", decoder_kind="mlp"),
        reward_head=8), settings=TrainConfig(lr=3e-3, prune_every=0), seed=iteration)


def weights(result) -> dict[str, torch.Tensor]:
    return {k: v.clone() for k, v in result.estimator.model_.state_dict().items()}


def test_the_batch_stays_fixed_and_a_refit_does_its_budget_as_data_grow(tmp_path):
    result = model_based(Rail(), make, LOOP, out=tmp_path / "run", fit_settings=FIT)
    its = result.log["iterations"]
    assert [it["batch_size"] for it in its] == [4] * 4
    # the first fit: 4 epochs of 10 training windows; then the training windows grow (15,
    # 20, 20) and each refit is its budget, 3 batches of 4 drawn from all of them
    assert its[0]["updates"] == 4 * math.ceil(10 / 4)
    assert [it["updates"] for it in its[1:]] == [3, 3, 3]
    # where the data hold fewer windows than the budget: whole epochs, rounded up
    small = model_based(Rail(), make, dataclasses.replace(LOOP, iterations=2,
                                                          warm_updates=5), fit_settings=FIT)
    assert small.log["iterations"][1]["updates"] == 2 * math.ceil(15 / 4)
    # the fit settings' batch size wins over the loop's
    own = model_based(Rail(), make, dataclasses.replace(LOOP, iterations=1),
                      fit_settings=FIT | {"batch_size": 5})
    assert own.log["iterations"][0]["batch_size"] == 5


def test_active_terms_fall_refit_after_refit_to_the_floor_and_resume_alike(tmp_path):
    whole = model_based(Rail(), make, LOOP, out=tmp_path / "whole", fit_settings=FIT)
    its = whole.log["iterations"]
    active = [it["active_terms"] for it in its]
    assert its[0]["pruned"] == 0 and active[0] == 3 * 18  # 18 terms a state, none pruned yet
    for before, it in zip(active, its[1:], strict=False):  # 30% a refit, not below 10
        assert it["active_terms"] <= max(10, math.ceil(before * 0.7)), active
        assert it["pruned"] == before - it["active_terms"] > 0, active
    assert active[-1] < active[0] / 2
    assert whole.estimator.model_.dynamics.n_active() == active[-1]
    # killed after iteration 2, resumed: the same masks, weights and returns
    out = tmp_path / "resumed"
    model_based(Rail(), make, dataclasses.replace(LOOP, iterations=2), out=out,
                fit_settings=FIT)
    resumed = model_based(Rail(), make, LOOP, out=out, fit_settings=FIT)
    assert resumed.returns == whole.returns
    assert [it["active_terms"] for it in resumed.log["iterations"]] == active
    for k, v in weights(whole).items():
        assert torch.equal(weights(resumed)[k], v), k
    # no pruning between refits: the terms stay
    kept = model_based(Rail(), make, dataclasses.replace(LOOP, prune_rate=0.0),
                       fit_settings=FIT)
    assert [it["active_terms"] for it in kept.log["iterations"]] == [active[0]] * 4


def test_settings_are_checked_and_an_older_run_is_refused_by_name(tmp_path):
    for bad in ({"batch_size": 0}, {"prune_rate": 1.0}, {"prune_to": -1}):
        with pytest.raises(UserError, match=next(iter(bad))):
            dataclasses.replace(LOOP, **bad)
    out = tmp_path / "run"
    model_based(Rail(), make, dataclasses.replace(LOOP, iterations=1), out=out,
                fit_settings=FIT)
    log = json.loads((out / "log.json").read_text())
    for key in ("batch_size", "prune_rate", "prune_to"):  # as a run of before wrote it
        del log["settings"][key]
    (out / "log.json").write_text(json.dumps(log))
    with pytest.raises(UserError, match="batch_size, prune_rate, prune_to"):
        model_based(Rail(), make, LOOP, out=out, fit_settings=FIT)
