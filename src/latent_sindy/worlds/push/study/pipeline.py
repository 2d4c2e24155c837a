"""One command reproduces the paper's study, and what we add to it, into one folder and report.

It collects the data if missing, trains SINDy orders 1-4, the linear (E2C) and the MLP
baselines and a multi-step-trained SINDy on the same data, splits and seeds, evaluates every
model on the same footing (losses on H = 1 windows, prediction error against horizon,
sparsity, closed-loop control with latent and image-space MPPI on the paper task and random
tasks) and writes Table I beside the paper's, the figures, the equations and the report.
A re-run reuses every finished piece (data, trained runs, evaluations, control episodes);
an interrupted training run resumes from its checkpoint.

    latent-sindy reproduce --scale demo --out results
    latent-sindy reproduce --scale paper --out results-paper --seeds 0..2
    latent-sindy reproduce --scale paper --out /shared/paper --executor ray --ray-address auto
    latent-sindy reproduce --scale demo --out results/l1 --models sindy2 --sweep lambda_l1=1e-3,1e-2
    latent-sindy reproduce --world pendulum-video --scale demo --out results/pendulum-video
    latent-sindy reproduce --world pendulum --scale tiny --out /tmp/pendulum

    from latent_sindy.worlds.push.study.config import ReproduceConfig
    from latent_sindy.worlds.push.study.pipeline import reproduce
    report = reproduce(ReproduceConfig(scale="demo", out=Path("results")))

OUT holds::

    data.h5                      trajectories (collected if missing)
    runs/seed<S>/<model>/        training run folders, with evaluation.json and
                                 control-<task>-<latent|image>/ (results.json, GIFs)
    table1.md, table1.csv        the paper's Table I beside ours
    figures/                     loss histories, rollouts, coefficient maps, prediction error,
                                 control, gifs/
    equations_<model>.txt        discovered equations (every seed)
    summary.json                 every number, the config, versions, seeds, timings
    report.html                  all of it in one self-contained page
    sweep.md                     with --sweep: a row per variant (mean ± std, Wilson intervals)

A world plug-in with a study of its own (``--world pendulum``, ``--world pendulum-video``;
see :func:`latent_sindy.study.runner.study_worlds`) is not run here: the command reaches it
through its ``reproduce`` hook (:func:`latent_sindy.study.runner.run_world_study`).

The push pipeline reads as stages, each a function of what the earlier ones returned
(:mod:`.stages`, :mod:`.outputs`): data (collect) -> train + evaluate + control (the
evaluations) -> baselines -> the :class:`~.results.Study` they make -> outputs (figures,
equations, tables) -> summary.json and report.html. Collection shards and the
(model, seed) jobs run on the study's executor (latent_sindy.executors: local processes or Ray).
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import torch

from latent_sindy.atomic import check_output_dir, write_atomic
from latent_sindy.configs import to_json
from latent_sindy.data import SequenceData, read_sequences
from latent_sindy.errors import UserError
from latent_sindy.executors import ExecutorOptions, make_executor
from latent_sindy.progress import say_stderr
from latent_sindy.result_files import record_rows
from latent_sindy.study.evaluation import BASELINES, Stat
from latent_sindy.study.runner import json_safe, machine, study_folder, versions
from latent_sindy.worlds.push.study.config import ReproduceConfig, StudyPlan
from latent_sindy.worlds.push.study.outputs import output_stage, submit_model_figures
from latent_sindy.worlds.push.study.results import Study
from latent_sindy.worlds.push.study.stages import (
    baseline_stage,
    check_given_data,
    collect_stage,
    run_stage,
)
from latent_sindy.worlds.push.study.study_report import write_report

__all__ = ["record_name", "record_of", "reproduce", "summary_record"]

Say = Callable[[str], None]


def _stat_dict(s: Stat) -> dict[str, Any]:
    return {"mean": s.mean, "std": s.std, "n": s.n}


def summary_record(study: Study, data: SequenceData, data_path: Path) -> dict[str, Any]:
    """Everything summary.json holds: every number, the config, versions, seeds, timings."""
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


def record_name(config: ReproduceConfig) -> str:
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
def reproduce(config: ReproduceConfig, progress: Say | None = None) -> Path:
    """Run (or complete) the whole study in ``config.out``; returns the path of report.html.

    ``progress`` receives one line per stage and per finished job; None prints them to
    stderr when ``config.verbose`` (training milestones are printed by the workers).
    """
    t_start = time.perf_counter()
    say = progress or (say_stderr if config.verbose else (lambda _: None))
    if config.study_world is not None:
        raise UserError(f"--world {config.world} has a study of its own: run it with "
                        f"latent-sindy reproduce --world {config.world}")
    out = check_output_dir(config.out, "--out")
    if config.data is not None and config.data.exists():
        # a foreign or damaged file, or one of another image size, is refused before any output
        check_given_data(config, read_sequences(config.data))
    with study_folder(out, "push"):
        return _study(config, out, say, t_start)


def _study(config: ReproduceConfig, out: Path, say: Say, t_start: float) -> Path:
    """The study of :func:`reproduce`, once its folder ``out`` is this process's."""
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
        summary = summary_record(study, data, data_path)
        text = json.dumps(summary, indent=1, allow_nan=False)
        write_atomic(out / "summary.json", lambda f: f.write(text), binary=False)
        report = write_report(study, files, summary, out / "report.html")
        if config.record is not None:
            rows = record_of(study)
            path = record_rows(config.record, "push", record_name(config), rows)
            say(f"recorded {len(rows)} row(s) in {path}")
    finally:
        torch.set_num_threads(threads)
    say(f"[4/4] report: {report} (this run took {time.perf_counter() - t_start:.0f} s)")
    return report
