"""The study's unit jobs and the pool that runs them.

A :class:`TrainJob` trains one (model, seed) or reuses its finished run folder (resumes an
interrupted one); an :class:`EvalJob` measures one trained run (losses, prediction error,
model statistics, what the latent knows: cached in RUN/evaluation.json) and runs its
closed-loop conditions (cached per condition in RUN/control-<task>-<space>/results.json).
A cache that is truncated or holds the wrong types is computed again; a reused run's lost
metrics.csv and loss.png are restored from its checkpoint (:func:`restore_finished`).
Jobs run on the study's executor (:mod:`latent_sindy.executors`: local processes, this
process, or Ray tasks); each may run again after its worker died, and then reuses or resumes
what the lost attempt wrote.

    latent-sindy reproduce --scale demo --out results   # schedules these jobs
"""

from __future__ import annotations

import json
import math
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from latent_sindy.api import AllTermsPruned, LatentSINDy
from latent_sindy.atomic import write_atomic
from latent_sindy.configs import to_json
from latent_sindy.data import SequenceData, read_sequences
from latent_sindy.errors import UserError
from latent_sindy.progress import Milestones
from latent_sindy.study import evaluation
from latent_sindy.training import RESUMABLE, RunDir, TrainConfig, TrainingDiverged
from latent_sindy.training.record import run_record
from latent_sindy.training.train_run import restore_finished
from latent_sindy.worlds.push.episodes import ControlConfig, run_control
from latent_sindy.worlds.push.study import probe
from latent_sindy.worlds.push.study.results import RunResult
from latent_sindy.worlds.push.study.scales import Condition

__all__ = ["EvalJob", "TrainJob", "ensure_trained", "eval_job", "held_out", "held_out_split",
           "train_job", "written_after"]

#: Version of evaluation.json's contents: 2 added the latent probe and position errors, 3
#: the state models' position errors, 4 the kernel probe (probe["kernel/..."]).
EVAL_VERSION = 4


@dataclass(frozen=True)
class TrainJob:
    config: TrainConfig
    name: str
    seed: int
    threads: int
    verbose: bool
    relative_time: float


@dataclass(frozen=True)
class EvalJob:
    run: Path
    data: Path
    name: str
    seed: int
    controls: tuple[tuple[Condition, ControlConfig], ...]
    threads: int


def ensure_trained(cfg: TrainConfig, progress=None) -> str:
    """Train ``cfg`` unless its run folder already holds it: "reused", "resumed" or "trained".

    A finished run with other settings or other data is an error (the study would mix
    recipes or data).
    """
    run = RunDir(cfg.out)
    if run.finished:
        want = run_record(cfg, read_sequences(cfg.data))
        diffs = run.differences(want, ignore=RESUMABLE - {"epochs"})
        if diffs:
            raise UserError(f"{run.path} holds a model trained with other settings or data "
                            f"({'; '.join(diffs)}): delete {run.path} or choose another --out")
        restore_finished(run)  # a deleted or damaged metrics.csv, a missing loss.png
        return "reused"
    if run.interrupted:
        _fit(cfg, progress, resume=True)
        return "resumed"
    _fit(cfg, progress)
    return "trained"


def _fit(cfg: TrainConfig, progress: Any, resume: bool = False) -> None:
    """Train ``cfg`` into its run folder through the estimator, as a user of the library
    would: ``LatentSINDy(model=..., settings=...).fit(data, out=...)`` (``resume``: go on
    from the folder's checkpoint)."""
    estimator = LatentSINDy(model=cfg.model, settings=cfg, loss=cfg.loss, seed=cfg.seed,
                            device=cfg.device)
    with warnings.catch_warnings():  # (the study reports each model's sparsity itself)
        warnings.simplefilter("ignore", AllTermsPruned)
        estimator.fit(read_sequences(cfg.data), out=cfg.out, progress=progress,
                      **({"resume": True} if resume else {}))


def train_job(job: TrainJob) -> dict[str, Any]:
    torch.set_num_threads(job.threads)
    t0 = time.perf_counter()
    label = f"{job.name} (seed {job.seed})"
    try:
        status = ensure_trained(job.config, Milestones(label) if job.verbose else None)
    except TrainingDiverged as e:
        return {"status": "diverged", "error": str(e), "seconds": time.perf_counter() - t0}
    return {"status": status, "error": None, "seconds": time.perf_counter() - t0}


def held_out_split(data: SequenceData) -> str:
    """The split predictions are judged on: test, else validation, else training."""
    counts = data.split_counts()
    return next((s for s in ("test", "val") if counts[s]), "train")


def held_out(data: SequenceData) -> SequenceData:
    """The trajectories of :func:`held_out_split`."""
    return data.split(held_out_split(data))


def _what_the_latent_knows(loaded: Any, data: SequenceData,
                           predictions: list[torch.Tensor]) -> dict[str, Any]:
    """The latent probe and the block position errors of an image model; a state model's
    latent is the pose (no probe), its position errors are those of its predicted poses.
    ``predictions``: the model's rollouts on :func:`held_out`."""
    if loaded.model.config.observation.kind == "state":
        return {"probe": None,
                "position": probe.state_position_errors(held_out(data), predictions)}
    if loaded.model.config.observation.kind != "image":
        return {"probe": None, "position": None}
    return {"probe": probe.latent_probes(loaded.model, data, loaded.normalizer,
                                         held_out_split(data)),
            "position": probe.position_errors(loaded.model, held_out(data), loaded.normalizer,
                                              predictions=predictions)}


def written_after(path: Path, sources: list[Path]) -> bool:
    """Whether ``path`` exists and was written after every one of ``sources`` (a result or
    figure of them that a study run again reuses; one of a model trained again is redone)."""
    try:
        written = path.stat().st_mtime_ns
        return all(src.stat().st_mtime_ns <= written for src in sources)
    except FileNotFoundError:
        return False


def _eval_key(run: RunDir, data: Path) -> dict[str, Any]:
    return {"version": EVAL_VERSION, "model_mtime_ns": (run / run.MODEL).stat().st_mtime_ns,
            "data": str(data.resolve()), "data_mtime_ns": data.stat().st_mtime_ns}


def _read_json(path: Path) -> Any:
    """The JSON value in ``path``; None where it is missing, truncated or not text."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError, RecursionError):  # JSONDecodeError, UnicodeDecodeError
        return None


def _number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _numbers(v: Any) -> bool:
    return isinstance(v, list) and all(map(_number, v))


def _whole_evaluation(record: Any, key: dict[str, Any]) -> bool:
    """Whether ``record`` is evaluation.json as :func:`eval_job` writes it for ``key``."""
    if not (isinstance(record, dict) and record.get("key") == key):
        return False
    losses = record.get("losses")
    stats = record.get("stats")
    probe = record.get("probe", 0)
    position = record.get("position", 0)
    if not (isinstance(losses, dict) and isinstance(stats, dict)
            and _numbers(record.get("horizon")) and record["horizon"]):
        return False
    if not all(isinstance(v, dict) and all(map(_number, v.values())) for v in losses.values()):
        return False
    if not all(v is None or _number(v) for v in stats.values()):
        return False
    if probe is not None and not (isinstance(probe, dict)
                                  and {"cos", "sin", "kernel/angle"} <= probe.keys()
                                  and all(map(_number, probe.values()))):
        return False
    return position is None or (isinstance(position, dict) and _number(position.get("recon"))
                                and _numbers(position.get("model"))
                                and _numbers(position.get("still")))


def _whole_results(record: Any, settings: dict[str, Any]) -> bool:
    """Whether ``record`` is a results.json that :func:`run_control` wrote with
    ``settings``."""
    return (isinstance(record, dict) and record.get("settings") == settings
            and isinstance(record.get("summary"), dict)
            and all(_number(record["summary"].get(k))
                    for k in ("plan_ms_mean", "discarded_total", "success_rate"))
            and isinstance(record.get("episodes"), list)
            and all(isinstance(ep, dict) and isinstance(ep.get("actions"), list)
                    and all(map(_numbers, ep["actions"])) for ep in record["episodes"]))


def _control(loaded: Any, run: RunDir, condition: Condition, settings: ControlConfig
             ) -> dict[str, Any]:
    """Closed-loop summary of one condition, reusing results.json written with equal settings
    (run again where it is older than the model, or damaged).

    Adds ``nonfinite_actions``: executed pushes with a NaN or inf component (should be 0).
    """
    folder = run.control_dir(condition.task, condition.cost_space)
    results = folder / "results.json"
    want = json.loads(json.dumps(to_json(settings)))
    record = None
    if written_after(results, [run / run.MODEL]):
        record = _read_json(results)
    if not _whole_results(record, want):
        run_control(loaded.model, loaded.normalizer, loaded.world_config, settings, folder)
        record = json.loads(results.read_text())
    actions = [a for ep in record["episodes"] for a in ep["actions"]]
    bad = sum(not all(math.isfinite(v) for v in a) for a in actions)
    return {**record["summary"], "nonfinite_actions": bad}


def eval_job(job: EvalJob) -> RunResult:
    """Losses, prediction error, model statistics (cached in evaluation.json) and control."""
    torch.set_num_threads(job.threads)
    t0 = time.perf_counter()
    run = RunDir(job.run)
    loaded = run.load()
    cache = run / run.EVALUATION
    key = _eval_key(run, job.data)
    record = _read_json(cache)
    if not _whole_evaluation(record, key):  # missing, stale or damaged: measured again
        data = read_sequences(job.data)
        # One set of open-loop rollouts for the image MSE and the block position errors.
        rollouts = evaluation.rollouts(loaded.model, held_out(data), loaded.normalizer)
        record = {"key": key,
                  "losses": evaluation.split_losses(loaded.model, data, loaded.normalizer,
                                                    loaded.config.loss),
                  "horizon": evaluation.horizon_errors(loaded.model, held_out(data),
                                                       loaded.normalizer, rollouts),
                  "stats": evaluation.model_stats(loaded.model),
                  **_what_the_latent_knows(loaded, data, rollouts)}
        write_atomic(cache, lambda f: f.write(json.dumps(record, indent=1)), binary=False)
    control = {cond.name: _control(loaded, run, cond, s) for cond, s in job.controls}
    train_s = sum(r.get("time_s") or 0.0 for r in run.read_metrics())
    return RunResult(losses=record["losses"], horizon=record["horizon"], stats=record["stats"],
                     control=control, train_seconds=train_s, seconds=time.perf_counter() - t0,
                     observation=loaded.model.config.observation.kind, probe=record["probe"],
                     position=record["position"])
