"""A finished study made up without training: every model of the catalogue (the demo's 17 rows,
their real labels) with plausible measured numbers, and the files the report embeds, so that
the report can be written and measured in seconds."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import imageio.v3 as iio
import numpy as np

from latent_sindy.stats import wilson_interval
from latent_sindy.study.evaluation import aggregate
from latent_sindy.worlds.push.study.config import PushStudyConfig, StudyPlan
from latent_sindy.worlds.push.study.results import CONTROL_METRICS, Baselines, Evaluations, Study


def _control(rng: np.random.Generator, episodes: int) -> dict[str, float]:
    k = int(rng.integers(0, episodes + 1))
    strict = int(rng.integers(0, k + 1))
    m = dict.fromkeys(CONTROL_METRICS, 1.0)
    lo, hi = wilson_interval(k, episodes)
    slo, shi = wilson_interval(strict, episodes)
    m.update(episodes=episodes, success_rate=k / episodes, success_ci_low=lo, success_ci_high=hi,
             strict_success_rate=strict / episodes, strict_ci_low=slo, strict_ci_high=shi,
             plan_ms_mean=float(rng.uniform(2, 40)), discarded_total=0, left_workspace=0)
    return m


def _metrics(spec: Any, rng: np.random.Generator) -> dict[str, float | None]:
    kind = spec.model.dynamics.kind
    m: dict[str, float | None] = {f"loss/{s}": float(rng.uniform(0.05, 1)) for s in
                                  ("train", "val", "test")}
    coefficients = float(rng.integers(100, 5000))
    active = None if kind == "mlp" else (
        coefficients if kind == "linear" else float(rng.integers(5, coefficients // 4)))
    m.update({"sindy/active": active,
              "sindy/coefficients": None if kind == "mlp" else coefficients,
              "sindy/sparsity": 1 - active / coefficients if kind == "sindy" else None,
              "params/dynamics": coefficients if kind != "mlp" else 21136.0,
              "train/seconds": float(rng.uniform(50, 400))})
    err = "state_err" if spec.model.observation.kind == "state" else "pred_err"
    for h in (1, 2, 3):
        m[f"{err}/h{h}"] = float(rng.uniform(0.1, 1)) * h
    m[f"{err}/hmax"] = m[f"{err}/h3"]
    for h in (1, 5, 10):
        m[f"pos_err/h{h}"] = float(rng.uniform(0.5, 4)) * h ** 0.5
    for cond, episodes in (("paper/latent", 5), ("random/latent", 50 if spec.headline else 20)):
        m.update({f"control/{cond}/{k}": v for k, v in _control(rng, episodes).items()})
    m["control/latent/plan_ms_mean"] = m["control/random/latent/plan_ms_mean"]
    m["control/image/plan_ms_mean"] = None
    m["control/discarded_total"] = m["control/nonfinite_actions"] = 0
    return m


def _png(path: Path, width: int, height: int) -> Path:
    iio.imwrite(path, np.tile(np.linspace(0, 255, width, dtype=np.uint8), (height, 1)))
    return path


def fake_study(out: Path, seeds: tuple[int, ...] = (0,),
               models: tuple[str, ...] = ()) -> tuple[Study, dict[str, Any], dict[str, Any]]:
    """(study, files, summary) as :func:`latent_sindy.worlds.push.study.study_report.study_page`
    takes them; the images are written under ``out/inputs``."""
    plan = StudyPlan.of(PushStudyConfig(scale="tiny", out=out, seeds=seeds, models=models))
    rng = np.random.default_rng(0)
    per_seed = {s: {spec.name: _metrics(spec, rng) for spec in plan.specs} for s in seeds}
    stats = {m: aggregate([per_seed[s][m] for s in seeds]) for m in plan.models}
    evaluations = Evaluations({s: {} for s in seeds}, per_seed, stats,
                              {f"{m}/seed{s}": "trained" for m in plan.models for s in seeds}, ())
    study = Study(config=plan.config, specs=plan.specs, runs=plan.runs, evaluations=evaluations,
                  baselines=Baselines({}, {}), timings={"total": 12.0})
    inputs = out / "inputs"
    inputs.mkdir(parents=True, exist_ok=True)
    files = {"control": _png(inputs / "control.png", 1200, 400),
             "loss": _png(inputs / "loss.png", 650, 400),
             "horizon": _png(inputs / "horizon.png", 650, 400),
             "coefficients": {}, "gifs": [], "equations": {}}
    summary = {"data": {"trajectories": 6, "steps": 3, "splits": {"train": 2, "val": 2, "test": 2}},
               "machine": {"cpus": 2, "load_average": [0.5, 0.5, 0.5]},
               **{k: {} for k in ("config", "scale", "seeds", "models", "versions", "timings_s",
                                  "train_status")}}
    return study, files, summary
