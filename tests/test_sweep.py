"""Sweeps and seed ranges: the variants a sweep makes, the sweep table's statistics against
hand computations, and a tiny sweep end to end (each variant trained with its own setting)."""

from __future__ import annotations

import json
import math

import pytest

from latent_sindy.errors import UserError
from latent_sindy.stats import wilson_interval
from latent_sindy.study.settings import parse_seeds
from latent_sindy.training import RunDir
from latent_sindy.worlds.push.study.catalogue import model_specs
from latent_sindy.worlds.push.study.config import PushStudyConfig, study_specs
from latent_sindy.worlds.push.study.scales import SCALES
from latent_sindy.worlds.push.study.sweeps import Sweep
from latent_sindy.worlds.push.study.table import sweep_rows
from push_study import run_push


@pytest.mark.parametrize(("args", "seeds"), [
    (["0..9"], tuple(range(10))), (["0", "1", "2"], (0, 1, 2)), (["0,2,4"], (0, 2, 4)),
    (["3..5", "9"], (3, 4, 5, 9)), (["7..7"], (7,))])
def test_seed_ranges_and_lists(args, seeds):
    assert parse_seeds(args) == seeds


def test_a_sweep_makes_one_variant_per_value_of_the_models_it_applies_to(tmp_path):
    cfg = PushStudyConfig(scale="tiny", out=tmp_path, models=("sindy2", "linear"),
                          sweep=(Sweep.parse("lambda_pred_x=1e-3,1e-2"),
                                 Sweep.parse("order=1,3")))
    specs = {s.name: s for s in study_specs(cfg)}
    # order applies to SINDy only: linear gets the λ1 variants, sindy2 every combination
    assert list(specs) == ["sindy2.lambda_pred_x=0.001.order=1",
                           "sindy2.lambda_pred_x=0.001.order=3",
                           "sindy2.lambda_pred_x=0.01.order=1", "sindy2.lambda_pred_x=0.01.order=3",
                           "linear.lambda_pred_x=0.001", "linear.lambda_pred_x=0.01"]
    s = specs["sindy2.lambda_pred_x=0.01.order=3"]
    assert s.loss.lambda_pred_x == 0.01 and s.model.dynamics.order == 3
    assert s.label == "SINDy-2, λ1=0.01, order=3"
    assert specs["linear.lambda_pred_x=0.001"].loss.lambda_pred_x == 0.001
    plain = PushStudyConfig(scale="tiny", out=tmp_path)
    assert study_specs(plain) == model_specs(SCALES["tiny"])  # no sweep or --models: as it was


def test_sweep_input_is_checked():
    with pytest.raises(UserError, match="unknown setting 'lr'"):
        Sweep.parse("lr=1,2")
    with pytest.raises(UserError, match="'a' is not a float"):
        Sweep.parse("lambda_l1=a")


def test_sweep_table_means_stds_and_pooled_wilson_interval():
    key = "control/random/latent"

    def seed(rate, episodes, loss):
        return {"loss/test": loss, f"{key}/success_rate": rate, f"{key}/episodes": episodes,
                f"{key}/strict_success_rate": 0.0, "sindy/sparsity": None}

    per_seed = {0: {"a": seed(0.5, 4, 0.1)}, 1: {"a": seed(1.0, 4, 0.3)}}
    [row] = sweep_rows(["a"], {"a": "A"}, per_seed, [0, 1])
    assert row[:3] == ["A", "2", f"0.2000 ± {math.sqrt(0.02):.4f}"]
    assert row[3] == "n/a"  # sparsity of a model without coefficients
    lo, hi = wilson_interval(6, 8)  # 2 + 4 successes of 4 + 4 episodes
    assert row[5] == f"75% ± 35% [{100 * lo:.0f}–{100 * hi:.0f}%, 6/8]"


def test_a_tiny_sweep_trains_each_variant_with_its_value(tmp_path):
    out = tmp_path / "sweep"
    run_push(out, scale="tiny", workers=1, seeds=(0, 1), models=("state_sindy",),
             sweep=(Sweep.parse("lambda_l1=1e-4,1e-2"),))
    names = ["state_sindy.lambda_l1=0.0001", "state_sindy.lambda_l1=0.01"]
    for s in (0, 1):
        for name, lam in zip(names, (1e-4, 1e-2), strict=True):
            assert RunDir(out / "runs" / f"seed{s}" / name).train_config().loss.lambda_l1 == lam
    table = (out / "sweep.md").read_text().splitlines()
    assert [r.split(" | ")[0] for r in table[2:4]] == [
        "| SINDy (face library), state, λ3=0.0001", "| SINDy (face library), state, λ3=0.01"]
    assert all(" | 2 | " in r for r in table[2:4])  # both seeds finished
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["results"]["aggregate"]) == set(names)
    assert summary["config"]["options"]["sweep"] == [{"setting": "lambda_l1",
                                                      "values": [1e-4, 1e-2]}]


def test_the_pruning_cut_is_a_sindy_setting_the_study_trains_with(tmp_path):
    """--sweep prune_below applies to SINDy models only, and the study trains each spec with
    its own pruning cut where it sets one (the moments row), else the scale's."""
    from latent_sindy.worlds.push.study.config import StudyPlan
    from latent_sindy.worlds.push.study.stages import train_config

    cfg = PushStudyConfig(scale="tiny", out=tmp_path, models=("sindy2", "linear"),
                          sweep=(Sweep.parse("prune_below=0.01,0.1"),))
    specs = {s.name: s for s in study_specs(cfg)}
    assert list(specs) == ["sindy2.prune_below=0.01", "sindy2.prune_below=0.1", "linear"]
    plain = PushStudyConfig(scale="tiny", out=tmp_path, models=("sindy2", "sindy_moments"))
    for config in (cfg, plain):
        chosen = study_specs(config)
        plan = StudyPlan(config, chosen, {0: {s.name: tmp_path / s.name for s in chosen}})
        for spec in chosen:
            want = SCALES["tiny"].prune_below if spec.prune_below is None else spec.prune_below
            assert train_config(plan, spec, 0, tmp_path / "d.h5").prune_below == want
    moments = next(s for s in study_specs(plain) if s.name == "sindy_moments")
    assert moments.prune_below != SCALES["tiny"].prune_below
    assert specs["sindy2.prune_below=0.1"].prune_below == 0.1
