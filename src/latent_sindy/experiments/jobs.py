"""The study's unit jobs and the pool that runs them.

A :class:`TrainJob` trains one (model, seed) or reuses its finished run folder (resumes an
interrupted one); an :class:`EvalJob` measures one trained run (losses, prediction error,
model statistics, cached in RUN/evaluation.json) and runs its closed-loop conditions (cached
per condition in RUN/control-<task>-<space>/results.json). Jobs run in fresh worker
processes, or in this process when there is one worker.

    latent-sindy reproduce --scale demo --out results   # schedules these jobs
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Callable, Mapping
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import torch

from latent_sindy.atomic import write_atomic
from latent_sindy.control.closed_loop import ControlSettings, run_control
from latent_sindy.data.store import Trajectories, read_trajectories
from latent_sindy.errors import UserError
from latent_sindy.experiments import evaluation
from latent_sindy.training import (
    CONFIG_FILE,
    MODEL_FILE,
    RESUMABLE,
    TrainConfig,
    TrainingDiverged,
    load_run,
    read_metrics,
    train,
)

__all__ = ["EvalJob", "Inline", "Pool", "TrainJob", "ensure_trained", "eval_job", "executor",
           "flat_metrics", "held_out", "say_stderr", "train_job"]

EVAL_FILE = "evaluation.json"
EVAL_VERSION = 1


def say_stderr(text: str) -> None:
    """A progress line on stderr (stdout stays free for results)."""
    print(text, file=sys.stderr, flush=True)


class _Milestones:
    """Training progress as a few lines (every 20% of the epochs), for logs from workers."""

    def __init__(self, label: str) -> None:
        self.label = label
        self.every = 1

    def start(self, total: int, initial: int) -> None:
        self.total, self.every = total, max(1, total // 5)

    def update(self, epoch: int, metrics: Mapping[str, float | None]) -> None:
        if epoch % self.every == 0 or epoch == self.total:
            val = metrics.get("val/objective")
            say_stderr(f"    {self.label}: epoch {epoch}/{self.total}, train "
                        f"{metrics['train/objective']:.4g}"
                        + ("" if val is None else f", val {val:.4g}"))

    def note(self, text: str) -> None:
        say_stderr(f"    {self.label}: {text}")

    def close(self) -> None: ...


@dataclass(frozen=True)
class TrainJob:
    config: TrainConfig
    name: str
    seed: int
    threads: int
    verbose: bool
    cost: float


@dataclass(frozen=True)
class EvalJob:
    run: Path
    data: Path
    name: str
    seed: int
    controls: dict[str, ControlSettings]
    threads: int


def _comparable(train_record: Mapping[str, Any]) -> dict[str, Any]:
    ignore = RESUMABLE - {"epochs"}  # paths and run-folder flags may differ
    return {k: v for k, v in train_record.items() if k not in ignore}


def ensure_trained(cfg: TrainConfig, progress=None) -> str:
    """Train ``cfg`` unless its run folder already holds it: "reused", "resumed" or "trained".

    A finished run with other settings is an error (the study would mix recipes).
    """
    run = cfg.out
    if (run / MODEL_FILE).exists():
        record = json.loads((run / CONFIG_FILE).read_text())["train"]
        want = json.loads(json.dumps(cfg.to_dict()))
        if _comparable(record) != _comparable(want):
            diff = sorted(k for k in _comparable(want) if record.get(k) != want[k])
            raise UserError(f"{run} holds a model trained with other settings ({', '.join(diff)})"
                            f": delete {run} or choose another --out")
        return "reused"
    if (run / "checkpoint.pt").exists():
        train(replace(cfg, resume=True), progress)
        return "resumed"
    train(cfg, progress)
    return "trained"


def train_job(job: TrainJob) -> dict[str, Any]:
    torch.set_num_threads(job.threads)
    t0 = time.perf_counter()
    label = f"{job.name} (seed {job.seed})"
    try:
        status = ensure_trained(job.config, _Milestones(label) if job.verbose else None)
    except TrainingDiverged as e:
        return {"status": "diverged", "error": str(e), "seconds": time.perf_counter() - t0}
    return {"status": status, "error": None, "seconds": time.perf_counter() - t0}


def held_out(data: Trajectories) -> Trajectories:
    """The trajectories predictions are judged on: test, else validation, else training."""
    counts = data.split_counts()
    return data.split(next((s for s in ("test", "val") if counts[s]), "train"))


def _eval_key(run: Path, data: Path) -> dict[str, Any]:
    return {"version": EVAL_VERSION, "model_mtime_ns": (run / MODEL_FILE).stat().st_mtime_ns,
            "data": str(data.resolve()), "data_mtime_ns": data.stat().st_mtime_ns}


def _control(run: Any, folder: Path, settings: ControlSettings) -> dict[str, Any]:
    """Closed-loop summary of one condition, reusing results.json written with equal settings.

    Adds ``nonfinite_actions``: executed pushes with a NaN or inf component (should be 0).
    """
    results = folder / "results.json"
    want = json.loads(json.dumps(asdict(settings)))
    fresh = not (results.exists() and results.stat().st_mtime_ns >= (
        folder.parent / MODEL_FILE).stat().st_mtime_ns)
    if not fresh:
        record = json.loads(results.read_text())
        fresh = record.get("settings") != want
    if fresh:
        run_control(run.model, run.normalizer, run.env_config, settings, folder)
        record = json.loads(results.read_text())
    actions = [a for ep in record["episodes"] for a in ep["actions"]]
    bad = sum(not all(math.isfinite(v) for v in a) for a in actions)
    return {**record["summary"], "nonfinite_actions": bad}


def eval_job(job: EvalJob) -> dict[str, Any]:
    """Losses, prediction error, model statistics (cached in evaluation.json) and control."""
    torch.set_num_threads(job.threads)
    t0 = time.perf_counter()
    run = load_run(job.run)
    cache, key = job.run / EVAL_FILE, _eval_key(job.run, job.data)
    record = json.loads(cache.read_text()) if cache.exists() else {}
    if record.get("key") != key:
        data = read_trajectories(job.data)
        record = {"key": key,
                  "losses": evaluation.split_losses(run.model, data, run.normalizer,
                                                    run.config.weights),
                  "horizon": evaluation.horizon_errors(run.model, held_out(data),
                                                       run.normalizer),
                  "stats": evaluation.model_stats(run.model)}
        write_atomic(cache, lambda f: f.write(json.dumps(record, indent=1)), binary=False)
    control = {name: _control(run, job.run / name, s) for name, s in job.controls.items()}
    train_s = sum(r["time_s"] or 0.0 for r in read_metrics(job.run))
    return {**record, "control": control, "train_seconds": train_s,
            "seconds": time.perf_counter() - t0}


class Inline:
    """workers=1: jobs run in this process one at a time, newest first (so an evaluation
    follows its training at once), when :meth:`wait_one` is called."""

    def __init__(self) -> None:
        self._queue: list[tuple[Future, Callable, tuple]] = []

    def submit(self, fn: Callable, *args: Any) -> Future:
        fut: Future = Future()
        self._queue.append((fut, fn, args))
        return fut

    def wait_one(self, pending: Mapping[Future, Any]) -> set[Future]:
        fut, fn, args = self._queue.pop()
        try:
            fut.set_result(fn(*args))
        except Exception as e:  # re-raised by fut.result(), as a process pool would
            fut.set_exception(e)
        return {fut}

    def shutdown(self, wait: bool = True, cancel_futures: bool = False) -> None:
        self._queue.clear()

    def __enter__(self) -> Inline:
        return self

    def __exit__(self, *exc: object) -> None: ...


class Pool(ProcessPoolExecutor):
    """Worker processes started fresh (spawn: no inherited PyBullet or torch state)."""

    def __init__(self, workers: int) -> None:
        import multiprocessing as mp

        super().__init__(workers, mp_context=mp.get_context("spawn"))

    def wait_one(self, pending: Mapping[Future, Any]) -> set[Future]:
        return wait(pending, return_when=FIRST_COMPLETED).done


def executor(workers: int, jobs: int) -> Inline | Pool:
    return Inline() if workers == 1 or jobs <= 1 else Pool(min(workers, jobs))


def flat_metrics(result: Mapping[str, Any]) -> dict[str, float | None]:
    """One (seed, model) evaluation as a flat {metric: value} dictionary (see table.ROWS)."""
    m: dict[str, float | None] = {}
    for split, key in (("train", "loss/train"), ("val", "loss/val"), ("test", "loss/test")):
        m[key] = result["losses"].get(split, {}).get("objective")
    m.update(result["stats"])
    horizon = result["horizon"]
    m.update({f"pred_err/h{h}": v for h, v in enumerate(horizon, start=1)})
    m["pred_err/hmax"] = horizon[-1]
    plan_ms: dict[str, list[float]] = {"latent": [], "image": []}
    discarded = nonfinite = 0
    for folder, s in result["control"].items():
        _, task, space = folder.split("-")
        for k in ("success_rate", "strict_success_rate", "steps_to_goal_mean",
                  "steps_to_strict_mean", "final_distance_mean", "plan_ms_mean",
                  "discarded_total", "left_workspace", "episodes"):
            m[f"control/{task}/{space}/{k}"] = s[k]
        if math.isfinite(s["plan_ms_mean"]):
            plan_ms[space].append(s["plan_ms_mean"])
        discarded += s["discarded_total"]
        nonfinite += s["nonfinite_actions"]
    for space, values in plan_ms.items():
        m[f"control/{space}/plan_ms_mean"] = sum(values) / len(values) if values else math.nan
    m["control/discarded_total"] = discarded
    m["train/seconds"] = result["train_seconds"]
    m["control/nonfinite_actions"] = nonfinite
    return m
