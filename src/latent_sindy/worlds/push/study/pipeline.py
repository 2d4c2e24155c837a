"""The push study: the paper's, and what we add to it, in one folder and report.

It collects the data if missing, trains SINDy orders 1-4, the linear (E2C) and the MLP
baselines and a multi-step-trained SINDy on the same data, splits and seeds, evaluates every
model on the same footing (losses on H = 1 windows, prediction error against horizon,
sparsity, closed-loop control with latent and image-space MPPI on the paper task and random
tasks) and writes Table I beside the paper's, the figures and the equations; it returns the
study as a :class:`~latent_sindy.world_study.WorldStudy` (every number, its page), which
``latent-sindy reproduce`` writes as every world's study (summary.json, table.md,
report.html: :func:`latent_sindy.study.runner.run_study`). The push world's ``reproduce``
hook is its one entry (:mod:`latent_sindy.worlds.push.plugin`). A re-run reuses every
finished piece (data, trained runs, evaluations, control episodes); an interrupted training
run resumes from its checkpoint.

    latent-sindy reproduce --scale demo --out results
    latent-sindy reproduce --scale paper --out results-paper --seeds 0..2
    latent-sindy reproduce --scale paper --out /shared/paper --executor ray --ray-address auto
    latent-sindy reproduce --scale demo --out results/l1 --models sindy2 --sweep lambda_l1=1e-3,1e-2

    from latent_sindy.study.runner import run_study
    from latent_sindy.study.settings import StudySettings
    report = run_study(StudySettings(scale="demo", out=Path("results")), {"models": ("sindy2",)})

OUT holds::

    data.h5                      trajectories (collected if missing)
    runs/seed<S>/<model>/        training run folders, with evaluation.json and
                                 control-<task>-<latent|image>/ (results.json, GIFs)
    table1.md, table1.csv        the paper's Table I beside ours
    figures/                     loss histories, rollouts, coefficient maps, prediction error,
                                 control, gifs/
    equations_<model>.txt        discovered equations (every seed)
    summary.json, table.md       every number, the settings, versions, seeds, timings; the tables
    report.html                  all of it in one self-contained page
    sweep.md                     with --sweep: a row per variant (mean ± std, Wilson intervals)

The pipeline reads as stages, each a function of what the earlier ones returned
(:mod:`.stages`, :mod:`.outputs`): data (collect) -> train + evaluate + control (the
evaluations) -> baselines -> the :class:`~.results.Study` they make -> outputs (figures,
equations, tables) -> the study's record and page. Collection shards and the (model, seed)
jobs run on the study's executor (latent_sindy.executors: local processes or Ray).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import torch

from latent_sindy.configs import to_json
from latent_sindy.data import SequenceData, read_sequences
from latent_sindy.errors import UserError
from latent_sindy.executors import ExecutorOptions, make_executor
from latent_sindy.study.evaluation import BASELINES, Stat
from latent_sindy.study.runner import json_safe, machine, versions
from latent_sindy.world_study import WorldStudy
from latent_sindy.worlds.push.study.config import PushStudyConfig, StudyPlan
from latent_sindy.worlds.push.study.outputs import output_stage, submit_model_figures
from latent_sindy.worlds.push.study.results import Study
from latent_sindy.worlds.push.study.stages import (
    baseline_stage,
    check_given_data,
    collect_stage,
    run_stage,
)
from latent_sindy.worlds.push.study.study_report import (
    findings,
    study_figures,
    study_page,
    study_tables,
)

__all__ = ["SETTINGS", "push_study", "record_name", "record_of", "study_record"]

Say = Callable[[str], None]


def _stat_dict(s: Stat) -> dict[str, Any]:
    return {"mean": s.mean, "std": s.std, "n": s.n}


#: The keys of :func:`study_record` that are the study's settings (summary.json's
#: ``study``); the others are its numbers (``results``).
SETTINGS = ("config", "scale", "models", "data", "control")


def study_record(study: Study, data: SequenceData, data_path: Path) -> dict[str, Any]:
    """Everything the study measured and ran on: every number, the config, versions, seeds,
    timings (summary.json holds its :data:`SETTINGS` as the study's settings, the rest but
    versions and machine as its results; the page shows it)."""
    scale = study.scale
    return json_safe({
        "config": {**to_json(study.config), "data": str(data_path)},
        "scale": to_json(scale),
        "seeds": list(study.config.seeds),
        "models": {s.name: {"label": s.label, "model": to_json(s.model), "window": s.window}
                   for s in study.specs},
        "data": {"path": str(data_path), "trajectories": data.n, "steps": data.steps,
                 "splits": data.split_counts(), "seed": data.seed,
                 "fingerprint": data.fingerprint()},
        "control": {s.name: {c.name: to_json(scale.control_config(c, 0, study.config.world))
                             for c in scale.conditions(s)} for s in study.specs},
        "versions": versions(),
        "machine": machine(),
        "timings_s": study.timings,
        "train_status": study.evaluations.train_status,
        "failures": study.evaluations.failures,
        "baselines": {"labels": BASELINES, "pred_err": study.baselines.pred_err,
                      "position_cm": study.baselines.position},
        "aggregate": {m: {k: _stat_dict(s) for k, s in st.items()}
                      for m, st in study.stats.items()},
        "per_seed": {str(s): v for s, v in study.per_seed.items()},
        "losses_per_seed": {str(s): {m: r.losses for m, r in v.items()}
                            for s, v in study.results.items()},
    })


def record_name(config: PushStudyConfig) -> str:
    """The study's result file name: its scale, then its world and image size where they
    are not the default's (``demo-long_textured``, ``demo_64px``)."""
    parts = [config.scale]
    if config.world != "symmetric":
        parts.append(config.world)
    if config.image_size is not None:
        parts.append(f"{config.image_size}px")
    return "_".join(parts)


def record_of(study: Study) -> list[dict[str, Any]]:
    """Table I's headline figures as result rows, one per model and seed: the random goals'
    strict and course successes in latent MPPI (counts), active terms, validation loss, the
    final distance and the block's position error after 10 pushes."""
    rows = []
    for seed in study.config.seeds:
        done = study.per_seed.get(seed, {})
        for model, m in ((s.name, done[s.name]) for s in study.specs if s.name in done):
            key = "control/random/latent/"
            n = m.get(key + "episodes")
            n = None if n is None or n != n else int(n)

            def count(rate: float | None, n: int | None = n) -> int | None:
                return None if rate is None or n is None or rate != rate else round(rate * n)

            rows.append({"model": model, "seed": seed,
                         "validation_loss": m.get("loss/val"),
                         "active_terms": m.get("sindy/active"),
                         "strict_successes": count(m.get(key + "strict_success_rate")),
                         "strict_episodes": n,
                         "course_successes": count(m.get(key + "success_rate")),
                         "course_episodes": n,
                         "final_distance_m": m.get(key + "final_distance_mean"),
                         "block_error_10_cm": m.get("pos_err/h10")})
    return rows


# ----------------------------------------------------------------------------- the pipeline
def push_study(config: PushStudyConfig, say: Say) -> WorldStudy:
    """Run (or complete) the whole study in ``config.out`` (held by the caller: the push
    world's ``reproduce`` hook, through :func:`latent_sindy.study.runner.run_study`);
    ``say`` receives one line per stage and per finished job (training milestones are
    printed by the workers). Returns the study: its numbers, rows and page."""
    t_start = time.perf_counter()
    if config.data is not None and config.data.exists():
        # a foreign or damaged file, or one of another image size, is refused before any output
        check_given_data(config, read_sequences(config.data))
    out = config.out
    out.mkdir(parents=True, exist_ok=True)
    plan = StudyPlan.of(config)
    threads = torch.get_num_threads()
    torch.set_num_threads(config.threads)  # for the in-process work; restored below
    options = ExecutorOptions(workers=config.workers, threads=config.threads,
                              address=config.ray_address)
    try:
        with make_executor(config.executor, options) as pool:
            try:
                data_path = collect_stage(config, pool, say)
                timings = {"collect": time.perf_counter() - t_start}
                t = time.perf_counter()
                # the figures of trained models queue behind the last evaluations, on the
                # slots those leave idle (one slot has none: drawn with the outputs)
                started: dict[str, Future] = {}
                draw = None if pool.slots < 2 else (lambda trained: started.update(
                    submit_model_figures(plan, trained, data_path, pool)))
                evaluations = run_stage(plan, data_path, pool, say, draw)
                timings["train_evaluate_control"] = time.perf_counter() - t
                if not evaluations.results.get(config.seeds[0]):
                    raise UserError(f"no model of seed {config.seeds[0]} finished training: "
                                    + "; ".join(evaluations.failures))
                t = time.perf_counter()
                data = read_sequences(data_path)
                study = Study(config=plan.config, specs=plan.specs, runs=plan.runs,
                              evaluations=evaluations, baselines=baseline_stage(data),
                              timings=timings)
                files = output_stage(study, data, say, started, pool)
            except BaseException:
                pool.shutdown(wait=False, cancel_futures=True)  # no queued job starts after this
                raise
        study = dataclasses.replace(study, timings={
            **timings, "outputs": time.perf_counter() - t,
            "total": time.perf_counter() - t_start})
        record = study_record(study, data, data_path)
    finally:
        torch.set_num_threads(threads)
    return WorldStudy(
        title=f"latent-sindy: the paper's study, reproduced ({config.scale} scale)",
        settings={k: record[k] for k in SETTINGS}, seeds=list(config.seeds),
        numbers={k: v for k, v in record.items()
                 if k not in (*SETTINGS, "seeds", "versions", "machine")},
        findings=findings(study), tables=study_tables(study),
        figures=study_figures(files), rows=record_of(study), record_name=record_name(config),
        report=study_page(study, files, record))
