"""Names that each meant one of several things were renamed (docs/design.md, "Words"): the
old keywords, attributes, records, flags, sweep names and class names still read as the
new ones, and a finished run or study row is found again under the new names."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import pytest
import torch
import tyro

from latent_sindy import cli
from latent_sindy.configs import from_json, to_json
from latent_sindy.errors import UserError
from latent_sindy.models.dynamics import SindyDynamics
from latent_sindy.sindy.optimizers import STLSQ
from latent_sindy.training import RunDir, TrainConfig
from latent_sindy.training.config import check_fit_settings
from latent_sindy.training.session import Phase

DATA = Path(__file__).parent / "data"
OLD_TRAIN = {"threshold": "prune_below", "threshold_every": "prune_every",
             "sindy_init_threshold": "sindy_init_share"}


# ----------------------------------------------------------------------------- TrainConfig
def test_old_train_settings_read_as_the_new_ones() -> None:
    old = TrainConfig(threshold=0.25, threshold_every=7, sindy_init_threshold=0.125)
    new = TrainConfig(prune_below=0.25, prune_every=7, sindy_init_share=0.125)
    assert old == new
    assert (new.threshold, new.threshold_every, new.sindy_init_threshold) == (0.25, 7, 0.125)
    assert dataclasses.replace(new, threshold=0.5).prune_below == 0.5
    record = json.loads(json.dumps(to_json(new)))
    assert not set(OLD_TRAIN) & set(record) and set(OLD_TRAIN.values()) <= set(record)
    for name, now in OLD_TRAIN.items():  # a config.json written before the renaming
        record[name] = record.pop(now)
    assert from_json(TrainConfig, record, "train") == new
    assert Phase(3, "p", {"threshold_every": 0}).changes == {"prune_every": 0}
    check_fit_settings({"threshold": 1.0, "threshold_every": 2}, None)  # no error
    with pytest.raises(UserError, match="--prune-below -1"):
        TrainConfig(threshold=-1.0)


def test_a_run_recorded_under_the_old_names_is_the_same_run(tmp_path: Path) -> None:
    """A run folder whose config.json has ``threshold``: the study reuses it (the renaming
    adds no difference to the same settings written under the new names)."""
    run = tmp_path / "run"
    shutil.copytree(DATA / "run_v1_sindy", run)
    record = RunDir(run).read_record()
    assert record["train"]["threshold"] == 0.002
    cfg = RunDir(run).train_config()
    assert (cfg.prune_below, cfg.prune_every) == (0.002, 1)
    now = json.loads(json.dumps(record))
    now["train"] = {OLD_TRAIN.get(k, k): v for k, v in now["train"].items()}
    assert RunDir(run).differences(now) == RunDir(run).differences(record)
    assert not any(d.startswith(("prune", "threshold")) for d in RunDir(run).differences(now))
    now["train"]["prune_below"] = 0.5  # a setting that does differ is still seen
    assert any(d.startswith("prune_below (run 0.002, now 0.5)")
               for d in RunDir(run).differences(now))


@pytest.mark.parametrize(("flags", "want"), [
    (["--threshold", "0.25", "--threshold-every", "7", "--sindy-init-threshold", "0.125"],
     (0.25, 7, 0.125)),
    (["--prune-below", "0.25", "--prune-every", "7", "--sindy-init-share", "0.125"],
     (0.25, 7, 0.125)),
])
def test_the_old_train_flags_set_the_new_settings(monkeypatch, flags, want) -> None:
    seen = []
    monkeypatch.setattr(cli.Train, "run", lambda self: seen.append(self.config))
    assert cli.main(["train", *flags]) == 0
    cfg = seen[0]
    assert (cfg.prune_below, cfg.prune_every, cfg.sindy_init_share) == want


# ----------------------------------------------------------------------------- STLSQ
def test_stlsq_threshold_warns_and_is_min_share() -> None:
    g = torch.Generator().manual_seed(0)
    theta = torch.randn(200, 6, generator=g, dtype=torch.float64)
    target = theta[:, :2] * torch.tensor([1.0, 0.02], dtype=torch.float64)
    with pytest.warns(FutureWarning, match=r"min_share.*share of its target's RMS.*"
                                           r"not pysindy's absolute"):
        old = STLSQ(threshold=0.05)
    new = STLSQ(min_share=0.05)
    assert old.min_share == new.min_share == old.threshold == 0.05
    assert repr(old) == repr(new) and "min_share=0.05" in repr(new)
    a, b = old.fit(theta, target), new.fit(theta, target)
    assert torch.equal(a.coef_, b.coef_) and torch.equal(a.mask_, b.mask_)


# ----------------------------------------------------------------------------- classes
def test_the_old_class_and_method_names_are_the_new_ones() -> None:
    from latent_sindy.control import SindyKernelStep, SparseSindyStep
    from latent_sindy.control.sindy_step import SparseSindyStep as step_in_module
    from latent_sindy.models import CompiledSindy, SparseSindyDynamics
    from latent_sindy.models.dynamics.sindy import SparseSindyDynamics as compiled_in_module

    assert SparseSindyStep is SindyKernelStep is step_in_module
    assert SparseSindyDynamics is CompiledSindy is compiled_in_module
    assert CompiledSindy.kind == "sindy-sparse"  # the kind saved records carry
    torch.manual_seed(0)
    a, b = SindyDynamics(2, 1), SindyDynamics(2, 1)
    b.load_state_dict(a.state_dict())
    assert a.threshold(0.05) == b.prune(0.05) and torch.equal(a.mask, b.mask)
    assert isinstance(b.compile_sparse(), CompiledSindy)


# ----------------------------------------------------------------------------- studies
def test_the_push_study_reads_its_old_setting_and_sweep_names(tmp_path: Path) -> None:
    from latent_sindy.worlds.push.study.catalogue import model_specs
    from latent_sindy.worlds.push.study.config import ReproduceConfig, study_specs
    from latent_sindy.worlds.push.study.scales import SCALES
    from latent_sindy.worlds.push.study.sweeps import Sweep, parse_sweeps

    spec = next(s for s in model_specs(SCALES["tiny"]) if s.name == "sindy_moments")
    assert (spec.threshold, spec.init_threshold, spec.cost) == (
        spec.prune_below, spec.init_share, spec.relative_time)
    assert dataclasses.replace(spec, init_threshold=0.3, cost=2.0).init_share == 0.3
    assert SCALES["paper"].threshold_every == SCALES["paper"].prune_every == 300
    # an old sweep name sweeps the setting and names the runs as before (their folders)
    old = ReproduceConfig(scale="tiny", out=tmp_path, models=("sindy2",),
                          sweep=(Sweep.parse("threshold=0.01"),))
    new = ReproduceConfig(scale="tiny", out=tmp_path, models=("sindy2",),
                          sweep=(Sweep.parse("prune_below=0.01"),))
    (a,), (b,) = study_specs(old), study_specs(new)
    assert a.name == "sindy2.threshold=0.01" and b.name == "sindy2.prune_below=0.01"
    assert a.prune_below == b.prune_below == 0.01 and a.label == b.label
    with pytest.raises(UserError, match="name each setting once"):
        parse_sweeps(["threshold=0.1", "prune_below=0.2"])


def test_the_pendulum_studies_read_their_old_names() -> None:
    from latent_sindy.worlds.pendulum.centroid_sindy import CentroidSindy
    from latent_sindy.worlds.pendulum.study import StudyConfig
    from latent_sindy.worlds.pendulum.video_study import SCHEDULES, VideoStudyConfig

    assert CentroidSindy(threshold=0.03).min_share == 0.03
    assert StudyConfig(centroid_threshold=0.02).centroid_min_share == 0.02
    cfg = tyro.cli(StudyConfig, args=["--centroid-threshold", "0.02"])
    assert cfg.centroid_min_share == 0.02
    s = SCHEDULES["scalefree"]
    assert (s.threshold, s.threshold_every) == (s.prune_below, s.prune_every) == (0.1, 25)
    # finished seeds were keyed by the schedule's old names: they are still found
    key = VideoStudyConfig().key()
    assert key["threshold"] == 0.1 and key["threshold_every"] == 25
    assert "prune_below" not in key and "prune_every" not in key
