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

    from latent_sindy.experiments.study import ReproduceConfig
    from latent_sindy.experiments.reproduce import reproduce
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

The pipeline reads as stages, each a function of what the earlier ones returned:
data (collect) -> train + evaluate + control -> baselines -> outputs
(figures, equations, tables) -> summary.json and report.html. Collection shards and the
(model, seed) jobs run on the study's executor (latent_sindy.executors: local processes or Ray).
"""

from __future__ import annotations

import json
import math
import os
import platform
import shutil
import subprocess
import time
from collections.abc import Callable, Mapping
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import torch

from latent_sindy.atomic import check_output_dir
from latent_sindy.configs import to_json
from latent_sindy.data.store import Trajectories, read_trajectories
from latent_sindy.data.windows import Normalizer
from latent_sindy.errors import UserError
from latent_sindy.executors import Executor, ExecutorOptions, Resources, make_executor
from latent_sindy.experiments import figures
from latent_sindy.experiments.evaluation import BASELINES, Stat, aggregate, baseline_errors
from latent_sindy.experiments.jobs import EvalJob, TrainJob, eval_job, held_out, train_job
from latent_sindy.experiments.probe import position_errors
from latent_sindy.experiments.study import ModelSpec, ReproduceConfig, Study, study_specs
from latent_sindy.experiments.study_report import write_report
from latent_sindy.experiments.table import write_sweep_table, write_table1
from latent_sindy.progress import bar, say_stderr
from latent_sindy.training import RunDir, TrainConfig, load_run, read_metrics
from latent_sindy.worlds.push.collect import CollectionPlan, collect

__all__ = ["reproduce", "train_config", "versions"]

Say = Callable[[str], None]


# ----------------------------------------------------------------------------- helpers
def _stat_dict(s: Stat) -> dict[str, Any]:
    return {"mean": s.mean, "std": s.std, "n": s.n}


def _json_safe(obj: Any) -> Any:
    """NaN and inf to None, recursively, so summary.json is standard JSON."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Mapping):
        return {str(k): _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_json_safe(v) for v in obj]
    return obj


def versions() -> dict[str, str | None]:
    """Versions of Python and the packages the results depend on, and the git commit."""
    from importlib.metadata import PackageNotFoundError, version

    from latent_sindy import __version__

    out: dict[str, str | None] = {"python": platform.python_version(),
                                  "latent-sindy": __version__}
    for pkg in ("torch", "numpy", "numba", "pybullet", "gymnasium", "matplotlib"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = None
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).parent,
                              capture_output=True, text=True, timeout=10)
        out["git_commit"] = head.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        out["git_commit"] = None
    return out


# ----------------------------------------------------------------------------- stage 1: data
def collect_stage(cfg: ReproduceConfig, pool: Executor, say: Say) -> Path:
    """The trajectory file of the study: as given, reused, or collected for the scale."""
    path, scale = cfg.data_path, cfg.preset
    if cfg.data is not None and path.exists():
        say(f"[1/4] data: using {path} as given")
        return path
    plan = CollectionPlan(scale.trajectories, scale.steps, cfg.data_seed, env=cfg.env_config())
    if path.exists():  # collect() returns it if it was collected to this plan, else refuses
        say(f"[1/4] data: reusing {path}")
    else:
        say(f"[1/4] data: collecting {plan.trajectories} trajectories x {plan.steps} pushes "
            f"into {path} ({cfg.executor} executor, {pool.slots} at once)")

    def progress(it, total, initial):
        return bar(it, total, initial, desc="collect", unit="traj", leave=False)

    return collect(path, plan, progress=progress if cfg.verbose else None, executor=pool)


def _check_given_data(cfg: ReproduceConfig, data: Trajectories) -> None:
    """A given trajectory file must hold images of ``--image-size``, where that is given."""
    side = data.env_config.image_size
    if cfg.image_size is not None and side != cfg.image_size:
        raise UserError(f"--image-size {cfg.image_size}, but {cfg.data} holds {side}x{side} "
                        f"images: drop --image-size, or give another --data")


# ----------------------------------------------------------------------------- stage 2: runs
def run_stage(study: Study, data: Path, pool: Executor, say: Say) -> None:
    """Every (seed, model): train (or reuse), then evaluate and control, on the executor.

    Fills ``study.results``, ``per_seed``, ``stats``, ``failures`` and ``train_status``.
    """
    cfg, scale = study.config, study.scale
    jobs = []
    for seed in cfg.seeds:
        for spec in study.specs:
            tc = train_config(study, spec, seed, data)
            jobs.append(TrainJob(tc, spec.name, seed, cfg.threads, cfg.verbose, spec.cost))
    jobs.sort(key=lambda j: -j.cost)  # longest first: the pool's tail stays short
    episodes = sum(c.episodes for spec in study.specs for c in scale.conditions(spec))
    say(f"[2/4] training and evaluating {len(study.specs)} models x {len(cfg.seeds)} seed(s) "
        f"({scale.epochs} epochs; {episodes} control episodes per seed), "
        f"{cfg.executor} executor, {min(pool.slots, len(jobs))} at once")
    _drain(pool, jobs, study, data, say)
    study.stats = {name: aggregate([study.per_seed[s][name] for s in cfg.seeds
                                    if name in study.per_seed.get(s, {})])
                   for name in study.models}


def _drain(pool: Executor, jobs: list[TrainJob], study: Study, data: Path,
           say: Say) -> None:
    """Run the training jobs; each finished one queues its evaluation; until all are done."""
    scale, threads, n = study.scale, study.config.threads, len(jobs)
    train_needs = Resources(cpus=threads, gpus=study.config.gpus)
    eval_needs = Resources(cpus=threads)
    t0 = time.perf_counter()
    done_eval = 0
    pending: dict[Future, tuple[str, Any]] = {
        pool.submit(train_job, j, resources=train_needs,
                    name=f"training {j.name} (seed {j.seed})"): ("train", j) for j in jobs}
    while pending:
        for fut in pool.wait_one(pending):
            kind, job = pending.pop(fut)
            result = fut.result()
            elapsed = time.perf_counter() - t0
            if kind == "train":
                study.train_status[f"{job.name}/seed{job.seed}"] = result["status"]
                if result["error"]:
                    study.failures.append(f"{job.name} (seed {job.seed}): {result['error']}")
                    say(f"  [{elapsed:5.0f} s] {job.name} (seed {job.seed}) FAILED: "
                        f"{result['error']}")
                    continue
                say(f"  [{elapsed:5.0f} s] {result['status']} {job.name} (seed {job.seed})"
                    f" in {result['seconds']:.0f} s")
                spec = study.spec(job.name)
                controls = tuple((c, scale.control_config(c, job.seed, study.config.world))
                                 for c in scale.conditions(spec))
                ev = EvalJob(job.config.out, data, job.name, job.seed, controls, threads)
                pending[pool.submit(eval_job, ev, resources=eval_needs,
                                    name=f"evaluating {ev.name} (seed {ev.seed})")] = ("eval", ev)
            else:
                done_eval += 1
                study.results.setdefault(job.seed, {})[job.name] = result
                m = result.metrics(scale.conditions(study.spec(job.name)))
                study.per_seed.setdefault(job.seed, {})[job.name] = m
                say(f"  [{elapsed:5.0f} s] evaluated {job.name} (seed {job.seed}) in "
                    f"{result.seconds:.0f} s: test loss {_num(m['loss/test'])}, "
                    f"random-task success {_pct(m.get('control/random/latent/success_rate'))}"
                    f" ({done_eval}/{n})")


def _pct(v: float | None) -> str:
    return "n/a" if v is None or not math.isfinite(v) else f"{100 * v:.0f}%"


def _num(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.4g}"


# ----------------------------------------------------------------------------- stage 3
def baseline_stage(data: Trajectories) -> dict[str, list[float]]:
    """Prediction error against horizon of the predictors that learn nothing."""
    return baseline_errors(data.split("train"), held_out(data),
                           Normalizer.from_trajectories(data))


def position_baseline_stage(data: Trajectories) -> dict[str, Any]:
    """Block position error of reading the true held-out images and of "nothing moves"."""
    return position_errors(None, held_out(data), Normalizer.from_trajectories(data))


# ----------------------------------------------------------------------------- stage 4
def output_stage(study: Study, data: Trajectories, say: Say) -> dict[str, Any]:
    """Figures, equations and tables of a finished study; returns what the report shows."""
    from latent_sindy.equations import equations_report

    out, cfg = study.config.out, study.config
    fig_dir = out / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    first = cfg.seeds[0]
    ok = [m for m in study.models if m in study.results.get(first, {})]
    runs = study.runs[first]
    files: dict[str, Any] = {"coefficients": {}, "gifs": [], "equations": {}}

    histories = {m: read_metrics(runs[m]) for m in ok}
    loss_labels = {s.name: s.label + ("" if s.window == 1 else f" (its H={s.window} objective)")
                   for s in study.specs}
    files["loss"] = figures.loss_histories(histories, loss_labels, fig_dir / "loss_histories.png")

    curves = _curves(study, "pred_err/h")
    references = {BASELINES[k]: v for k, v in study.baselines.items()}
    files["horizon"] = figures.horizon_plot(curves, study.labels, fig_dir / "prediction_error.png",
                                            references)
    position = _curves(study, "pos_err/h")
    if position and study.position_baselines:
        files["position"] = figures.horizon_plot(
            position, study.labels, fig_dir / "position_error.png",
            {"nothing moves": study.position_baselines["still"],
             "reading the true image": study.position_baselines["reader"]},
            ylabel="block position error (cm)", yscale="linear", cap=10.0,
            title="block position in open-loop predictions (state rows: predicted poses), "
                  "test trajectories")

    # Fig. 8: the single- and multi-step SINDy-2 (the paper's), then the other headline
    # image models (what the representation work bought).
    single, multi = study.single_step, study.multistep
    strip = [(runs[s.name], f"{kind} {s.label}\n(trained on H={s.window})")
             for kind, s in (("single-step", single), ("multi-step", multi))
             if s is not None and s.name in ok]
    strip += [(runs[s.name], s.label.replace(", ", ",\n", 1) if len(s.label) > 24 else s.label)
              for s in study.specs if s.headline and s.name in ok and s not in (single, multi)
              and s.model.encoder.kind == "image"]
    if strip:
        files["rollouts"] = _rollout_figure(strip, held_out(data), fig_dir / "rollouts.png")
    for spec in study.specs:
        if spec.name in ok:
            dyn = load_run(runs[spec.name]).model.dynamics
            if hasattr(dyn, "mask"):  # a sparse model: its coefficient map
                files["coefficients"][spec.name] = figures.coefficient_map(
                    dyn, spec.label, fig_dir / f"coefficients_{spec.name}.png")

    conditions = study.scale.all_conditions()
    bars, plan_ms = {}, {}
    for cond in conditions:
        key = f"control/{cond.name}/success_rate"
        if any(key in study.stats[m] for m in ok):
            bars[cond.label] = {m: study.stats[m][key].mean for m in ok if key in study.stats[m]}
    for m in ok:
        plan_ms[m] = study.stats[m]["control/latent/plan_ms_mean"].mean
    files["control"] = figures.control_bars(ok, study.labels, bars, plan_ms,
                                            fig_dir / "control.png")

    gif_dir = fig_dir / "gifs"
    gif_dir.mkdir(exist_ok=True)
    for m in ok:
        run = RunDir(runs[m])
        for cond in study.scale.conditions(study.spec(m)):
            src = run.control_dir(cond.task, cond.cost_space) / "episode_000.gif"
            if src.exists():
                dst = gif_dir / f"{m}_{cond.task}-{cond.space}.gif"
                shutil.copyfile(src, dst)
                files["gifs"].append((m, cond, dst))

    for m in study.models:
        parts = []
        for s in cfg.seeds:
            run = RunDir(study.runs[s][m])
            if m in study.results.get(s, {}):
                export = not (run / run.COEFFICIENTS_CSV).exists()
                parts.append(f"# seed {s}\n{equations_report(run.path, export=export)}")
        if parts:
            path = out / f"equations_{m}.txt"
            path.write_text("\n\n".join(parts) + "\n")
            files["equations"][m] = path

    files["table_md"], files["table_csv"] = write_table1(
        out, study.models, study.labels, study.stats, len(cfg.seeds))
    if cfg.sweep:
        files["sweep"] = write_sweep_table(out / "sweep.md", study.models, study.labels,
                                           study.per_seed, cfg.seeds)
    say(f"[3/4] wrote {files['table_md']}, {files['table_csv']}, figures/ and equations")
    return files


def _curves(study: Study, prefix: str) -> dict[str, tuple[list[float], list[float]]]:
    """{model: (means, stds)} of the metrics ``<prefix>1``, ``<prefix>2``, ... over seeds."""
    curves = {}
    for m in study.models:
        hs = [study.per_seed[s][m] for s in study.config.seeds
              if m in study.per_seed.get(s, {})]
        keys = sorted((k for k in (hs[0] if hs else {})
                       if k.startswith(prefix) and k[len(prefix):].isdigit()),
                      key=lambda k: int(k[len(prefix):]))
        if keys:
            st = [study.stats[m][k] for k in keys]
            curves[m] = ([s.mean for s in st], [s.std for s in st])
    return curves


@torch.no_grad()
def train_config(study: Study, spec: ModelSpec, seed: int, data: Path) -> TrainConfig:
    """How the study trains ``spec`` for ``seed``: the scale's schedule (times the spec's
    epochs factor), the spec's model, loss weights, window and threshold (if it sets one)."""
    scale = study.scale
    return TrainConfig(data=data, out=study.runs[seed][spec.name], model=spec.model,
                       loss=spec.loss, window=spec.window,
                       epochs=scale.epochs * spec.epochs_factor,
                       batch_size=scale.batch_size,
                       threshold=scale.threshold if spec.threshold is None else spec.threshold,
                       threshold_every=scale.threshold_every * spec.epochs_factor,
                       eval_every=scale.eval_every * spec.epochs_factor,
                       sindy_init_threshold=spec.init_threshold,
                       batching=scale.batching, seed=seed,
                       device="auto" if study.config.gpus > 0 else "cpu")


def _rollout_figure(models: list[tuple[Path, str]], test: Trajectories, path: Path) -> Path:
    """Fig. 8: a test trajectory, and each (run, label)'s open-loop rollout from its first
    image."""
    rows = [("ground truth", test.images[0].astype(float))]
    for run_dir, label in models:
        run = load_run(run_dir)
        x = run.normalizer.normalize(test.images[:1])  # (1, T+1, C, S, S)
        u = torch.as_tensor(test.actions[:1], dtype=torch.float32)  # (1, T, nu)
        with torch.no_grad():
            pred = run.model.predict(x[:, 0], u)[0]  # (T+1, C, S, S)
        rows.append((label, run.normalizer.denormalize(pred).numpy()))
    return figures.rollout_strip(rows, path)


def summary_record(study: Study, data: Trajectories, data_path: Path) -> dict[str, Any]:
    """Everything summary.json holds: every number, the config, versions, seeds, timings."""
    scale = study.scale
    return _json_safe({
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
        "machine": {"cpus": os.cpu_count(), "load_average": list(os.getloadavg()),
                    "platform": platform.platform()},
        "timings_s": study.timings,
        "train_status": study.train_status,
        "failures": study.failures,
        "baselines": {"labels": BASELINES, "pred_err": study.baselines,
                      "position_cm": study.position_baselines},
        "aggregate": {m: {k: _stat_dict(s) for k, s in st.items()}
                      for m, st in study.stats.items()},
        "per_seed": {str(s): v for s, v in study.per_seed.items()},
        "losses_per_seed": {str(s): {m: r.losses for m, r in v.items()}
                            for s, v in study.results.items()},
    })


# ----------------------------------------------------------------------------- the pipeline
def reproduce(config: ReproduceConfig, progress: Say | None = None) -> Path:
    """Run (or complete) the whole study in ``config.out``; returns the path of report.html.

    ``progress`` receives one line per stage and per finished job; None prints them to
    stderr when ``config.verbose`` (training milestones are printed by the workers).
    """
    t_start = time.perf_counter()
    say = progress or (say_stderr if config.verbose else (lambda _: None))
    out = check_output_dir(config.out, "--out")
    if config.data is not None and config.data.exists():
        # a foreign or damaged file, or one of another image size, is refused before any output
        _check_given_data(config, read_trajectories(config.data))
    out.mkdir(parents=True, exist_ok=True)
    specs = study_specs(config)
    runs = {s: {m.name: out / "runs" / f"seed{s}" / m.name for m in specs} for s in config.seeds}
    study = Study(config, specs, runs)
    threads = torch.get_num_threads()
    torch.set_num_threads(config.threads)  # for the in-process work; restored below
    options = ExecutorOptions(workers=config.workers, threads=config.threads,
                              address=config.ray_address)
    try:
        with make_executor(config.executor, options) as pool:
            try:
                data_path = collect_stage(config, pool, say)
                study.timings["collect"] = time.perf_counter() - t_start
                t = time.perf_counter()
                run_stage(study, data_path, pool, say)
                study.timings["train_evaluate_control"] = time.perf_counter() - t
            except BaseException:
                pool.shutdown(wait=False, cancel_futures=True)  # no queued job starts after this
                raise
        if not study.results.get(config.seeds[0]):
            raise UserError(f"no model of seed {config.seeds[0]} finished training: "
                            + "; ".join(study.failures))
        t = time.perf_counter()
        data = read_trajectories(data_path)
        study.baselines = baseline_stage(data)
        study.position_baselines = position_baseline_stage(data)
        files = output_stage(study, data, say)
        study.timings["outputs"] = time.perf_counter() - t
        study.timings["total"] = time.perf_counter() - t_start
        summary = summary_record(study, data, data_path)
        (out / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=False))
        report = write_report(study, files, summary, out / "report.html")
    finally:
        torch.set_num_threads(threads)
    say(f"[4/4] report: {report} (this run took {time.perf_counter() - t_start:.0f} s)")
    return report
