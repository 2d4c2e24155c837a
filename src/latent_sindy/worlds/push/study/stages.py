"""The study's stages before its outputs, each a function of what the earlier ones returned.

* :func:`collect_stage`: the trajectory file (as given, reused, or collected for the scale);
* :func:`run_stage`: every (seed, model) trained (or reused), then evaluated and controlled,
  on the study's executor; returns the :class:`~.results.Evaluations`;
* :func:`baseline_stage`: the predictors that learn nothing; returns the
  :class:`~.results.Baselines`.

Training and evaluation are one stage because each finished training job queues its
evaluation at once, so the executor's slots stay busy. :func:`train_config` is how the study
trains a model.

    latent-sindy reproduce --scale tiny --out /tmp/tiny   # runs these stages, then the outputs
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import torch

from latent_sindy.configs import from_json
from latent_sindy.data import SequenceData, read_sequences
from latent_sindy.data.windows import Normalizer
from latent_sindy.errors import UserError
from latent_sindy.executors import Executor, Resources
from latent_sindy.progress import bar
from latent_sindy.study.evaluation import aggregate, baseline_errors
from latent_sindy.training import TrainConfig
from latent_sindy.worlds.push.collect import CollectionPlan, collect
from latent_sindy.worlds.push.study.catalogue import ModelSpec
from latent_sindy.worlds.push.study.config import PushStudyConfig, StudyPlan
from latent_sindy.worlds.push.study.jobs import EvalJob, TrainJob, eval_job, held_out, train_job
from latent_sindy.worlds.push.study.probe import position_errors
from latent_sindy.worlds.push.study.results import Baselines, Evaluations, RunResult
from latent_sindy.worlds.push.study.scales import SCALES
from latent_sindy.worlds.push.study.sweeps import check_windows

__all__ = ["baseline_stage", "check_given_data", "check_reused_data", "collect_stage", "run_stage",
           "train_config"]

Say = Callable[[str], None]


# ----------------------------------------------------------------------------- stage 1: data
def collect_stage(cfg: PushStudyConfig, pool: Executor, say: Say) -> Path:
    """The trajectory file of the study: as given, reused, or collected for the scale."""
    path = cfg.data_path
    scale = cfg.preset
    if cfg.data is not None and path.exists():
        say(f"[1/3] data: using {path} as given")
        return path
    plan = CollectionPlan(scale.trajectories, scale.steps, cfg.data_seed, env=cfg.env_config())
    if path.exists():  # collect() returns it if it was collected to this plan, else refuses
        check_reused_data(cfg, plan, path)
        say(f"[1/3] data: reusing {path}")
    else:
        say(f"[1/3] data: collecting {plan.trajectories} trajectories x {plan.steps} pushes "
            f"into {path} ({cfg.executor} executor, {pool.slots} at once)")

    def progress(it, total, initial):
        return bar(it, total, initial, desc="collect", unit="traj", leave=False)

    return collect(path, plan, progress=progress if cfg.verbose else None, executor=pool)


def _scale_name(trajectories: int, steps: int) -> str | None:
    return next((name for name, s in SCALES.items()
                 if (s.trajectories, s.steps) == (trajectories, steps)), None)


def check_reused_data(cfg: PushStudyConfig, plan: CollectionPlan, path: Path) -> None:
    """OUT/data.h5 of an earlier study is reused only if collected to ``plan``: UserError
    naming each option (--world, --image-size, --data-seed, --scale) it was collected with
    otherwise. A file without a readable plan is left to :func:`collect`, which refuses it."""
    try:
        recorded = read_sequences(path).record.get("collection", {}).get("plan")
        old = from_json(CollectionPlan, recorded, str(path))
    except (UserError, AttributeError, TypeError, ValueError):
        return
    if old == plan:
        return
    world = old.env.world_name
    size = old.env.image_size
    differs = []
    if old.env.world_key != plan.env.world_key:
        differs.append(f"--world {world or 'of another kind'} (this study: --world {cfg.world})")
    if size != plan.env.image_size:
        differs.append(f"--image-size {size} (this study: --image-size {plan.env.image_size})")
    if old.seed != plan.seed:
        differs.append(f"--data-seed {old.seed} (this study: --data-seed {plan.seed})")
    if (old.trajectories, old.steps) != (plan.trajectories, plan.steps):
        scale = _scale_name(old.trajectories, old.steps)
        differs.append(f"{f'--scale {scale}, ' if scale else ''}{old.trajectories} "
                       f"trajectories of {old.steps} pushes (this study: --scale {cfg.scale}, "
                       f"{plan.trajectories} of {plan.steps})")
    if not differs:  # fractions or world details no option of the study sets
        changed = [f.name for f in dataclasses.fields(plan) if getattr(old, f.name)
                   != getattr(plan, f.name)]
        differs.append(f"another {' and '.join(changed)} than this study's (`latent-sindy "
                       "info` shows them)")
    raise UserError(f"{path} already exists with other collection settings: it was collected "
                    f"with {'; '.join(differs)}. Re-run with those settings, or choose another "
                    "--out, or delete the file")


def check_given_data(cfg: PushStudyConfig, data: SequenceData) -> None:
    """A given trajectory file must be of the study's ``--world``, hold images of
    ``--image-size`` (where that is given) and trajectories as long as every swept window."""
    env = data.world_config
    if env.world_key != cfg.env_config().world_key:
        world = env.world_name
        raise UserError(f"--world {cfg.world}, but {cfg.data} was collected in "
                        f"{f'the {world} world' if world else 'another world'}: "
                        f"{f'give --world {world}' if world else 'drop --world'}, or another "
                        "--data")
    side = env.image_size
    if cfg.image_size is not None and side != cfg.image_size:
        raise UserError(f"--image-size {cfg.image_size}, but {cfg.data} holds {side}x{side} "
                        f"images: drop --image-size, or give another --data")
    check_windows(cfg.sweep, data.steps, f"the trajectories of {cfg.data}")


# ----------------------------------------------------------------------------- stage 2: runs
def run_stage(plan: StudyPlan, data: Path, pool: Executor, say: Say,
              trained: Callable[[set[str]], Any] | None = None) -> Evaluations:
    """Every (seed, model): train (or reuse), then evaluate and control, on the executor;
    returns what was measured of every run that finished training. ``trained`` is called
    once, when the last training is done, with the first seed's models that finished
    training (it may queue work of its own on the executor behind the evaluations)."""
    cfg = plan.config
    scale = plan.scale
    jobs = []
    for seed in cfg.seeds:
        for spec in plan.specs:
            tc = train_config(plan, spec, seed, data)
            jobs.append(TrainJob(tc, spec.name, seed, cfg.threads, cfg.verbose, spec.relative_time))
    jobs.sort(key=lambda j: -j.relative_time)  # longest first: the pool's tail stays short
    episodes = sum(c.episodes for spec in plan.specs for c in scale.conditions(spec))
    say(f"[2/3] training and evaluating {len(plan.specs)} models x {len(cfg.seeds)} seed(s) "
        f"({scale.epochs} epochs; {episodes} control episodes per seed), "
        f"{cfg.executor} executor, {min(pool.slots, len(jobs))} at once")
    results, per_seed, train_status, failures = _drain(pool, jobs, plan, data, say,
                                                         trained)
    stats = {name: aggregate([per_seed[s][name] for s in cfg.seeds
                              if name in per_seed.get(s, {})])
             for name in plan.models}
    return Evaluations(results, per_seed, stats, train_status, tuple(failures))


def _drain(pool: Executor, jobs: list[TrainJob], plan: StudyPlan, data: Path, say: Say,
           trained: Callable[[set[str]], Any] | None = None
           ) -> tuple[dict[int, dict[str, RunResult]],
                      dict[int, dict[str, dict[str, float | None]]], dict[str, str], list[str]]:
    """Run the training jobs; each finished one queues its evaluation; until all are done.
    Returns the results and metrics per seed and model, the training status per run and
    the failures. ``trained``: as :func:`run_stage`'s."""
    scale = plan.scale
    threads = plan.config.threads
    n = len(jobs)
    train_needs = Resources(cpus=threads, gpus=plan.config.gpus)
    eval_needs = Resources(cpus=threads)
    results: dict[int, dict[str, RunResult]] = {}
    per_seed: dict[int, dict[str, dict[str, float | None]]] = {}
    train_status: dict[str, str] = {}
    failures: list[str] = []
    t0 = time.perf_counter()
    done_eval = 0
    trainings = n
    first = plan.config.seeds[0]
    ready: set[str] = set()  # the first seed's models that finished training
    pending: dict[Future, tuple[str, Any]] = {
        pool.submit(train_job, j, resources=train_needs,
                    name=f"training {j.name} (seed {j.seed})"): ("train", j) for j in jobs}
    while pending:
        for fut in pool.wait_one(pending):
            kind, job = pending.pop(fut)
            result = fut.result()
            elapsed = time.perf_counter() - t0
            if kind == "train":
                trainings -= 1
                train_status[f"{job.name}/seed{job.seed}"] = result["status"]
                if not result["error"] and job.seed == first:
                    ready.add(job.name)
                if result["error"]:
                    failures.append(f"{job.name} (seed {job.seed}): {result['error']}")
                    say(f"  [{elapsed:5.0f} s] {job.name} (seed {job.seed}) FAILED: "
                        f"{result['error']}")
                    _after_training(trainings, trained, ready)
                    continue
                say(f"  [{elapsed:5.0f} s] {result['status']} {job.name} (seed {job.seed})"
                    f" in {result['seconds']:.0f} s")
                spec = plan.spec(job.name)
                controls = tuple((c, scale.control_config(c, job.seed, plan.config.world))
                                 for c in scale.conditions(spec))
                ev = EvalJob(job.config.out, data, job.name, job.seed, controls, threads)
                pending[pool.submit(eval_job, ev, resources=eval_needs,
                                    name=f"evaluating {ev.name} (seed {ev.seed})")] = ("eval", ev)
                _after_training(trainings, trained, ready)
            else:
                done_eval += 1
                results.setdefault(job.seed, {})[job.name] = result
                m = result.metrics(scale.conditions(plan.spec(job.name)))
                per_seed.setdefault(job.seed, {})[job.name] = m
                say(f"  [{elapsed:5.0f} s] evaluated {job.name} (seed {job.seed}) in "
                    f"{result.seconds:.0f} s: test loss {_num(m['loss/test'])}, "
                    f"random-task success {_pct(m.get('control/random/latent/success_rate'))}"
                    f" ({done_eval}/{n})")
    return results, per_seed, train_status, failures


def _after_training(left: int, trained: Callable[[set[str]], Any] | None, ready: set[str]
                    ) -> None:
    """Call ``trained`` with ``ready`` once no training is ``left``."""
    if left == 0 and trained is not None:
        trained(set(ready))


def _pct(v: float | None) -> str:
    return "n/a" if v is None or not math.isfinite(v) else f"{100 * v:.0f}%"


def _num(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.4g}"


# ----------------------------------------------------------------------------- stage 3
def baseline_stage(data: SequenceData) -> Baselines:
    """Prediction error against horizon of the predictors that learn nothing, and the block
    position error of reading the true held-out images and of "nothing moves"."""
    normalizer = Normalizer.from_trajectories(data)
    test = held_out(data)
    return Baselines(pred_err=baseline_errors(data.split("train"), test, normalizer),
                     position=position_errors(None, test, normalizer))


@torch.no_grad()
def train_config(plan: StudyPlan, spec: ModelSpec, seed: int, data: Path) -> TrainConfig:
    """How the study trains ``spec`` for ``seed``: the scale's schedule (times the spec's
    epochs factor), the spec's model, loss weights, window and pruning cut (if it sets one)."""
    scale = plan.scale
    return TrainConfig(data=data, out=plan.runs[seed][spec.name], model=spec.model,
                       loss=spec.loss, window=spec.window,
                       epochs=scale.epochs * spec.epochs_factor,
                       batch_size=scale.batch_size, lr=scale.lr,
                       prune_below=(scale.prune_below if spec.prune_below is None
                                    else spec.prune_below),
                       prune="absolute", starts=1,
                       prune_every=scale.prune_every * spec.epochs_factor,
                       eval_every=scale.eval_every * spec.epochs_factor,
                       sindy_init_share=spec.init_share,
                       sindy_fit=spec.sindy_fit,
                       batching=scale.batching, seed=seed,
                       device="auto" if plan.config.gpus > 0 else "cpu")
