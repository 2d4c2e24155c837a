"""Warm-started refits in the model-based loop, on the synthetic rail world: the first
iteration fits from scratch as before, later ones continue the last model and optimiser for
a fixed budget of updates with the first fit's normaliser; a run killed at any point after
an iteration resumes to the uninterrupted run's returns and weights; the same settings side
by side for three dynamics share their seed episodes."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from latent_sindy import LatentSINDy
from latent_sindy.control import MPPIConfig
from latent_sindy.errors import UserError
from latent_sindy.model_based import ModelBasedConfig, model_based
from latent_sindy.model_based.compare import compare_models
from latent_sindy.model_based.warm_start import load_state
from latent_sindy.models import ModelConfig
from latent_sindy.models.autoencoder import AutoencoderConfig
from latent_sindy.models.dynamics import DYNAMICS_KINDS, SindyConfig
from latent_sindy.training import TrainConfig
from rail_world import Rail

pytestmark = pytest.mark.usefixtures("one_torch_thread")

FIT = {"epochs": 12, "batch_size": 8}
LOOP = ModelBasedConfig(seed_episodes=3, iterations=3, episode_steps=5, validation_every=3,
                        warm_updates=10,
                        mppi=MPPIConfig(samples=30, horizon=3, sigma=0.3, lambda_=0.5))


def make(dynamics=None):
    dyn = dynamics or SindyConfig(order=1, include_sine=False)

    def estimator(iteration: int) -> LatentSINDy:
        return LatentSINDy(model=ModelConfig(
            dynamics=dyn, observation=AutoencoderConfig(latent_dim=2, encoder_kind="mlp",
                                                        decoder_kind="mlp"), reward_head=16),
            settings=TrainConfig(lr=3e-3), seed=iteration)

    return estimator


def weights(result):
    return {k: v.clone() for k, v in result.estimator.model_.state_dict().items()}


def test_warm_refits_continue_the_last_model_for_the_budget(tmp_path):
    result = model_based(Rail(), make(), LOOP, out=tmp_path / "run", fit_settings=FIT)
    its = result.log["iterations"]
    # the first fit from scratch (12 epochs); then 10 updates, rounded up to whole epochs
    updates = [it["updates"] for it in its]
    assert updates[0] >= 12 and all(10 <= u < 20 for u in updates[1:]), updates
    assert all(it["active_terms"] is not None and it["equations"] for it in its)
    assert len(result.estimator.metrics_) < 10  # the last fit's own epochs
    # the first fit's normaliser stays, though the data grew
    first = model_based(Rail(), make(), dataclasses.replace(LOOP, iterations=1),
                        fit_settings=FIT)
    assert (result.estimator.normalizer_.to_dict() == first.estimator.normalizer_.to_dict())
    # the first iteration is the fit from scratch of before
    cold = model_based(Rail(), make(), dataclasses.replace(LOOP, iterations=1,
                                                           warm_updates=0), fit_settings=FIT)
    assert cold.returns == first.returns
    # only the last iteration's model stays in the folder, weights only
    assert sorted(p.name for p in (tmp_path / "run").glob("model_*.pt")) == ["model_3.pt"]
    state = load_state(tmp_path / "run" / "model_3.pt", 3)
    for k, v in weights(result).items():
        assert torch.equal(state.model[k], v), k
    with pytest.raises(UserError, match="damaged"):
        load_state(tmp_path / "run" / "model_3.pt", 2)


def test_warm_runs_resume_exactly_and_repeat_for_a_seed(tmp_path):
    world = Rail()
    whole = model_based(world, make(), LOOP, out=tmp_path / "whole", fit_settings=FIT)
    again = model_based(world, make(), LOOP, fit_settings=FIT)
    assert again.returns == whole.returns
    for k, v in weights(whole).items():
        assert torch.equal(weights(again)[k], v), k
    # stopped after iteration 1, then after 2 (as a kill -9 after its log), then finished
    out = tmp_path / "resumed"
    for n in (1, 2):
        model_based(world, make(), dataclasses.replace(LOOP, iterations=n), out=out,
                    fit_settings=FIT)
    # a kill before the log was written: a newer model the log does not count is ignored
    torch.save({"format": "junk"}, out / "model_3.pt")
    resumed = model_based(world, make(), LOOP, out=out, fit_settings=FIT)
    assert resumed.returns == whole.returns
    for k, v in weights(whole).items():
        assert torch.equal(weights(resumed)[k], v), k
    log = json.loads((out / "log.json").read_text())
    def fitted(its):
        return [(it["updates"], it["active_terms"], it["equations"]) for it in its]

    assert fitted(log["iterations"]) == fitted(whole.log["iterations"])
    # the warm budget is a setting of the run: another is refused
    with pytest.raises(UserError, match="warm_updates"):
        model_based(world, make(), dataclasses.replace(LOOP, warm_updates=20), out=out)


def test_a_missing_model_stops_a_warm_resume(tmp_path):
    out = tmp_path / "run"
    model_based(Rail(), make(), dataclasses.replace(LOOP, iterations=1), out=out,
                fit_settings=FIT)
    (out / "model_1.pt").unlink()
    with pytest.raises(UserError, match=r"model_1\.pt"):
        model_based(Rail(), make(), LOOP, out=out, fit_settings=FIT)


def test_three_dynamics_run_side_by_side_on_the_same_seed_episodes(tmp_path):
    makers = {"sindy": make(), "linear": make(DYNAMICS_KINDS["linear"]()),
              "mlp": make(DYNAMICS_KINDS["mlp"]())}
    cfg = dataclasses.replace(LOOP, iterations=1)
    results = compare_models(Rail(), makers, cfg, out=tmp_path, fit_settings=FIT)
    assert list(results) == ["sindy", "linear", "mlp"]
    seeds = [r.data.subset(np.arange(3)) for r in results.values()]
    for s in seeds[1:]:
        np.testing.assert_array_equal(s.images, seeds[0].images)
        np.testing.assert_array_equal(s.actions, seeds[0].actions)
    assert all(r.data.n == 4 for r in results.values())
    assert results["mlp"].log["iterations"][0]["active_terms"] is None
    assert all((tmp_path / name / "log.json").is_file() for name in makers)
