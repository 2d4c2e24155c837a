"""The estimator's defaults on data nobody tuned them to: the batch size follows the data's
size, and pruning is scale-free (a term's share of its state's update, not |Ψ|), so a small
action term that moves the latent is kept however small its coefficient."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from latent_sindy.data import SequenceData
from latent_sindy.errors import UserError
from latent_sindy.models.dynamics.continuous import ContinuousSindyConfig
from latent_sindy.models.dynamics.sindy import SindyDynamics
from latent_sindy.models.latent_model import ModelConfig
from latent_sindy.training.config import AUTO_BATCH, TrainConfig, resolve_prune
from latent_sindy.training.fit_loop import prune, share_scale
from latent_sindy.training.prepare import settle_settings


def _data(n: int, steps: int) -> SequenceData:
    images = np.zeros((n, steps + 1, 1, 4, 4), np.uint8)
    return SequenceData(images, np.zeros((n, steps, 1), np.float32), [-1], [1])


@pytest.mark.parametrize("n, steps, window", [(10, 8, 1), (60, 8, 1), (200, 8, 1),
                                              (200, 8, 3), (5000, 20, 1)])
def test_the_batch_size_gives_every_epoch_about_16_updates(n, steps, window) -> None:
    data = _data(n, steps)
    cfg = settle_settings(TrainConfig(window=window), data)
    windows = data.split("train").n * (steps - window + 1)
    updates = math.ceil(windows / cfg.batch_size)
    low, high = AUTO_BATCH
    assert low <= cfg.batch_size <= high
    assert updates >= 16 or cfg.batch_size == low   # small data: batches of the least size
    assert updates <= 17 or cfg.batch_size == high  # large data: batches of the most


def test_a_given_batch_size_is_kept() -> None:
    assert settle_settings(TrainConfig(batch_size=7), _data(60, 8)).batch_size == 7


def _identity_model(dyn: SindyDynamics) -> SimpleNamespace:
    return SimpleNamespace(encode=lambda x: x, dynamics=dyn)


def _small_action_model() -> tuple[SimpleNamespace, torch.Tensor, torch.Tensor]:
    """z[t+1] = z + 5e-4 u with u of unit size: the action moves z by ~5e-4 a step, all of its
    update; z's own term (1e-5 z) moves it by a fiftieth of that."""
    dyn = SindyDynamics(1, 1, order=1, include_sine=False, seed=0)
    names = list(dyn.library.names)
    coef = torch.zeros_like(dyn.psi)
    coef[names.index("u0"), 0] = 5e-4
    coef[names.index("z0"), 0] = 1e-5
    dyn.set_coefficients(coef)
    g = torch.Generator().manual_seed(0)
    x = torch.randn(8, 5, 1, generator=g)      # 8 sequences of 5 latents (the "frames")
    u = torch.randn(8, 4, 1, generator=g)
    return _identity_model(dyn), x, u


def test_relative_pruning_keeps_a_small_action_term_that_moves_the_state() -> None:
    model, x, u = _small_action_model()
    opt = torch.optim.AdamW([model.dynamics.psi])
    prune(model, opt, 0.05, share_scale(model, x, u))
    kept = dict(zip(model.dynamics.library.names, model.dynamics.mask[:, 0].tolist(),
                    strict=True))
    assert kept["u0"] and not kept["z0"]  # u kept; z, a fiftieth of the update, pruned


def test_absolute_pruning_kills_the_same_action_term() -> None:
    model, _, _ = _small_action_model()
    prune(model, torch.optim.AdamW([model.dynamics.psi]), 1e-3)
    assert not model.dynamics.mask.any()


def test_the_share_does_not_depend_on_the_scale_of_the_latent() -> None:
    model, x, u = _small_action_model()
    base = share_scale(model, x, u) * model.dynamics.coefficients().abs()
    model.dynamics.set_coefficients(model.dynamics.coefficients() * 1000)
    scaled = share_scale(model, x, u) * model.dynamics.coefficients().abs()
    assert torch.allclose(base, scaled, rtol=1e-4)


def test_continuous_time_prunes_absolute_and_refuses_relative() -> None:
    continuous = ModelConfig(dynamics=ContinuousSindyConfig())
    assert resolve_prune(TrainConfig(model=continuous)) == "absolute"
    assert resolve_prune(TrainConfig()) == "relative"
    with pytest.raises(UserError, match="--prune relative"):
        TrainConfig(model=continuous, prune="relative")
    with pytest.raises(UserError, match="--prune"):
        TrainConfig(prune="sometimes")


# ------------------------------------------------------------------ several starts
def _images_data(seed: int = 0, side: int = 8) -> SequenceData:
    rng = np.random.default_rng(seed)
    images = rng.integers(0, 256, (12, 4, 1, side, side), dtype=np.uint8)
    actions = rng.uniform(-1, 1, (12, 3, 2)).astype(np.float32)
    return SequenceData(images, actions, [-1, -1], [1, 1])


SMALL = {"encoder": "mlp", "decoder": "mlp", "order": 1, "include_sine": False}


def _states_equal(a: torch.nn.Module, b: torch.nn.Module) -> None:
    sa, sb = a.state_dict(), b.state_dict()
    assert sa.keys() == sb.keys()
    for k in sa:
        assert torch.equal(sa[k], sb[k]), k


def test_the_start_of_lowest_objective_continues_as_if_it_were_the_only_one() -> None:
    from latent_sindy import LatentSINDy

    data = _images_data()
    several = LatentSINDy(2, seed=0, **SMALL).fit(data, epochs=4, starts=3, start_epochs=2)
    info = several.kept_["start"]
    assert info["objectives"][info["chosen"]] == min(info["objectives"])
    assert info["seeds"][0] == 0 and len(set(info["seeds"])) == 3
    alone = LatentSINDy(2, seed=info["seeds"][info["chosen"]], **SMALL).fit(
        data, epochs=4, starts=1)
    _states_equal(several.model_, alone.model_)
    assert [r["train/total"] for r in several.metrics_] == [
        r["train/total"] for r in alone.metrics_]


def test_one_start_is_the_seeds_run_and_several_choose_differently() -> None:
    from latent_sindy import LatentSINDy

    data = _images_data()
    one = LatentSINDy(2, seed=0, **SMALL).fit(data, epochs=3, starts=1)
    assert "start" not in one.kept_
    objectives = LatentSINDy(2, seed=0, **SMALL).fit(
        data, epochs=3, starts=4, start_epochs=1).kept_["start"]["objectives"]
    assert len(set(objectives)) == 4  # the starts are different models


def test_a_run_folder_with_several_starts_resumes_to_the_same_model(tmp_path) -> None:
    from latent_sindy import LatentSINDy

    data = _images_data()
    kw = {"starts": 3, "start_epochs": 2}
    whole = LatentSINDy(2, seed=0, **SMALL).fit(data, epochs=5, out=tmp_path / "whole", **kw)
    LatentSINDy(2, seed=0, **SMALL).fit(data, epochs=2, out=tmp_path / "cut", **kw)
    resumed = LatentSINDy(2, seed=0, **SMALL).fit(data, epochs=5, out=tmp_path / "cut",
                                                  resume=True, **kw)
    _states_equal(whole.model_, resumed.model_)
    assert resumed.kept_["start"] == whole.kept_["start"]
    assert len(resumed.metrics_) == 5


def test_start_settings_are_checked() -> None:
    with pytest.raises(UserError, match="--starts 0"):
        TrainConfig(starts=0)
    with pytest.raises(UserError, match="--start-epochs 0"):
        TrainConfig(start_epochs=0)


def test_an_autonomous_model_prunes_relative_and_predicts() -> None:
    from latent_sindy import LatentSINDy

    rng = np.random.default_rng(0)
    data = SequenceData(rng.integers(0, 256, (10, 4, 1, 8, 8), dtype=np.uint8))
    est = LatentSINDy(2, seed=0, **SMALL).fit(data, epochs=2, prune_every=1, starts=1)
    assert est.predict(data.images[:3, 0], np.zeros((3, 0))).shape == (3, 1, 8, 8)
    assert np.isfinite(est.score(data))


def test_a_model_that_lost_every_term_says_so_in_one_line(capsys, tmp_path) -> None:
    from latent_sindy import LatentSINDy
    from latent_sindy.api import AllTermsPruned
    from latent_sindy.equations import equations_report

    data = _images_data()
    kw = {"epochs": 2, "prune_below": 1e9, "prune_every": 1, "starts": 1}
    with pytest.warns(AllTermsPruned, match="every SINDy term was pruned"):
        est = LatentSINDy(2, seed=0, **SMALL).fit(data, **kw)
    est.print()
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and "nothing moves" in out[0]
    with pytest.warns(AllTermsPruned):
        LatentSINDy(2, seed=0, **SMALL).fit(data, out=tmp_path / "run", **kw)
    report = equations_report(tmp_path / "run", export=False)
    assert "every SINDy term was pruned" in report and "z0[t+1]" not in report


def test_a_model_with_terms_prints_its_equations(capsys) -> None:
    from latent_sindy import LatentSINDy

    est = LatentSINDy(2, seed=0, **SMALL).fit(_images_data(), epochs=1, starts=1)
    est.print()
    assert capsys.readouterr().out.count("[t+1] =") == 2


# ------------------------------------------------------------------ pysindy's conventions
def test_coefficients_are_states_by_terms_named_by_get_feature_names() -> None:
    from latent_sindy import LatentSINDy

    est = LatentSINDy(2, seed=0, **SMALL).fit(_images_data(), epochs=1, starts=1)
    coef, names = est.coefficients(), est.get_feature_names()
    assert coef.shape == (2, len(names)) and "u1" in names
    psi = est.model_.dynamics.coefficients().detach().numpy()
    np.testing.assert_array_equal(coef, psi.T)
    linear = LatentSINDy(2, dynamics="linear", seed=0, **{k: SMALL[k] for k in ("encoder",
                         "decoder")}).fit(_images_data(), epochs=1, starts=1)
    assert linear.coefficients().shape == (2, len(linear.get_feature_names()))


def test_simulate_on_a_batch_equals_one_image_at_a_time() -> None:
    from latent_sindy import LatentSINDy

    data = _images_data()
    est = LatentSINDy(2, seed=0, **SMALL).fit(data, epochs=1, starts=1)
    z, frames = est.simulate(data.images[:3, 0], data.actions[:3])
    assert z.shape == (3, 4, 2) and frames.shape == (3, 4, 1, 8, 8)
    for i in range(3):
        zi, fi = est.simulate(data.images[i, 0], data.actions[i])
        np.testing.assert_allclose(z[i], zi, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(frames[i], fi, rtol=1e-4, atol=1e-3)


def test_refinement_begins_at_the_same_epoch_whether_or_not_starts_are_probed() -> None:
    """--refine-epochs reaching into the probe: the chosen start refines from the same epoch
    as the run it continues (its model equals that seed's single start)."""
    from latent_sindy import LatentSINDy

    data = _images_data()
    kw = {"epochs": 4, "refine_epochs": 3, "prune_every": 1}
    several = LatentSINDy(2, seed=0, **SMALL).fit(data, starts=2, start_epochs=2, **kw)
    info = several.kept_["start"]
    alone = LatentSINDy(2, seed=info["seeds"][info["chosen"]], **SMALL).fit(
        data, starts=1, **kw)
    _states_equal(several.model_, alone.model_)


@pytest.mark.parametrize("encoder", ["mlp", "moments"])
def test_every_start_trains_as_its_seeds_single_run(encoder: str) -> None:
    """Each candidate (the data's tensors built once, each model given its statistics and,
    with a fixed encoder, its regression start) reaches the objective its seed alone does."""
    from latent_sindy import LatentSINDy

    data = _images_data(side=16)
    kw = {**SMALL, "encoder": encoder}
    info = LatentSINDy(2 if encoder == "mlp" else 4, seed=0, **kw).fit(
        data, epochs=2, starts=3, start_epochs=2).kept_["start"]
    for seed, objective in zip(info["seeds"], info["objectives"], strict=True):
        alone = LatentSINDy(2 if encoder == "mlp" else 4, seed=seed, **kw).fit(
            data, epochs=2, starts=1)
        assert alone.metrics_[-1]["val/objective"] == objective
