"""One command reproduces the paper's study, and what we add to it, into one folder and report.

It collects the data if missing, trains SINDy orders 1-4, the linear (E2C) and the MLP
baselines and a multi-step-trained SINDy on the same data, splits and seeds, evaluates every
model on the same footing (losses on H = 1 windows, prediction error against horizon,
sparsity, closed-loop control with latent and image-space MPPI on the paper task and random
tasks) and writes Table I beside the paper's, the figures, the equations and the report.
A re-run reuses every finished piece (data, trained runs, evaluations, control episodes);
an interrupted training run resumes from its checkpoint.

    latent-sindy reproduce --scale demo --out results
    latent-sindy reproduce --scale paper --out results-paper --seeds 0 1 2

    from latent_sindy.experiments.reproduce import ReproduceConfig, reproduce
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
"""

from __future__ import annotations

import json
import math
import os
import platform
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Mapping
from concurrent.futures import Future
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import torch

from latent_sindy.control.closed_loop import ControlSettings
from latent_sindy.data.collect import CollectionPlan, collect
from latent_sindy.data.store import Trajectories, read_trajectories
from latent_sindy.data.windows import Normalizer
from latent_sindy.errors import UserError
from latent_sindy.experiments import figures
from latent_sindy.experiments.evaluation import BASELINES, Stat, aggregate, baseline_errors
from latent_sindy.experiments.jobs import (
    EvalJob,
    Inline,
    Pool,
    TrainJob,
    eval_job,
    executor,
    flat_metrics,
    held_out,
    say_stderr,
    train_job,
)
from latent_sindy.experiments.study_report import write_report
from latent_sindy.experiments.table import write_table1
from latent_sindy.models.latent_model import ModelConfig
from latent_sindy.training import TrainConfig, load_run, read_metrics

__all__ = ["SCALES", "ModelSpec", "ReproduceConfig", "Scale", "model_specs", "reproduce"]


# ----------------------------------------------------------------------------- settings
@dataclass(frozen=True)
class Scale:
    """How big a study is: data, training schedule and control episodes."""

    trajectories: int
    """Trajectories in all splits (1/2 train, 1/4 validation, 1/4 test)."""
    steps: int
    """Pushes per trajectory."""
    epochs: int
    batch_size: int
    threshold_every: int
    """SINDy: prune |Ψ| < threshold every this many epochs."""
    multistep_horizon: int
    """Training horizon H of the multi-step SINDy model."""
    paper_episodes: int
    """Latent MPPI episodes on the paper's task (each with its own MPPI noise)."""
    random_episodes: int
    """Latent MPPI episodes on random tasks."""
    image_paper_episodes: int
    image_random_episodes: int
    max_steps: int = 20
    """Pushes per latent MPPI episode (the course: 20)."""
    image_max_steps: int = 30
    """Pushes per image-space MPPI episode (the course: 30)."""
    samples: int = 100
    """MPPI samples K (the course: 100)."""
    mppi_horizon: int = 10
    """MPPI horizon H (the course: 10)."""
    until: Literal["course", "strict"] = "strict"
    """Run episodes until the strict criterion (so both criteria are measured) or the course's."""
    threshold: float = 1e-3


SCALES: dict[str, Scale] = {
    # The paper's settings: 100/50/50 trajectories x 10 pushes, 3000 epochs, batch 500,
    # thresholding every 300 epochs at 1e-3; 10 paper-task runs (as its image-space test)
    # and 20 random tasks per model and planner.
    "paper": Scale(200, 10, 3000, 500, 300, 4, paper_episodes=10, random_episodes=20,
                   image_paper_episodes=10, image_random_episodes=20),
    # The paper's data (100/50/50 trajectories) and a short schedule, sized for <= ~12
    # minutes on 2 cores (measured; see RESULTS.md): 60 epochs of batch 64 are 960 updates,
    # pruning every 6 epochs (10 times, as the paper's 3000/300). On 30 training
    # trajectories every model overfitted (validation loss 3-5x the training loss).
    "demo": Scale(200, 10, 60, 64, 6, 4, paper_episodes=1, random_episodes=10,
                  image_paper_episodes=1, image_random_episodes=4),
    # Seconds: only checks that the pipeline runs end to end (tests).
    "tiny": Scale(6, 3, 2, 500, 1, 2, paper_episodes=1, random_episodes=1,
                  image_paper_episodes=1, image_random_episodes=1, max_steps=2,
                  image_max_steps=2, samples=8, mppi_horizon=2),
}


@dataclass(frozen=True)
class ReproduceConfig:
    """Settings of `latent-sindy reproduce`."""

    scale: Literal["demo", "paper", "tiny"] = "demo"
    """demo: the whole study in about 12 minutes on 2 cores; paper: the paper's sizes (many
    hours on a CPU); tiny: seconds, for tests."""
    out: Path = Path("results")
    """Folder for everything (data, runs, tables, figures, report.html); re-runs reuse it."""
    seeds: tuple[int, ...] = (0,)
    """Training and control seeds; several give mean ± std."""
    data: Path | None = None
    """Trajectory file to use (default OUT/data.h5, collected for the scale if missing)."""
    data_seed: int = 0
    """Seed of the data collection (the same data serve every training seed)."""
    decoder: Literal["conv", "fc"] = "conv"
    """Decoder of every model: "conv" (transposed convolutions; generalises better) or "fc"
    (the course's fully connected one)."""
    workers: int = 2
    """Processes for collection, training and control (1: everything in this process)."""
    threads: int = 1
    """torch CPU threads per process."""
    verbose: bool = True
    """Print stage lines and training milestones to stderr."""

    def __post_init__(self) -> None:
        if self.scale not in SCALES:
            raise UserError(f"--scale {self.scale}: use one of {', '.join(SCALES)}")
        if not self.seeds or len(set(self.seeds)) != len(self.seeds) or min(self.seeds) < 0:
            raise UserError(f"--seeds {list(self.seeds)}: give distinct non-negative seeds")
        if self.workers < 1 or self.threads < 1:
            raise UserError(f"--workers {self.workers} and --threads {self.threads}: use 1 or "
                            "more")
        if self.data_seed < 0:
            raise UserError(f"--data-seed {self.data_seed}: seeds are non-negative integers")

    @property
    def preset(self) -> Scale:
        return SCALES[self.scale]

    @property
    def data_path(self) -> Path:
        return self.data if self.data is not None else self.out / "data.h5"

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d.update(out=str(self.out), data=str(self.data_path), seeds=list(self.seeds))
        return d


@dataclass(frozen=True)
class ModelSpec:
    """One model of the study: its name (folder, table column), label and training recipe."""

    name: str
    label: str
    model: ModelConfig
    horizon: int = 1
    cost: float = 1.0
    """Relative training time, to start the longest jobs first."""


def model_specs(scale: Scale, decoder: Literal["conv", "fc"] = "conv"
                ) -> tuple[ModelSpec, ...]:
    """SINDy orders 1-4, linear (E2C), MLP, and SINDy order 2 trained on H-step windows, all
    with the same autoencoder architecture."""
    h = scale.multistep_horizon

    def model(kind: Literal["sindy", "linear", "mlp"], order: int = 2) -> ModelConfig:
        return ModelConfig(kind=kind, order=order, decoder=decoder)

    return (
        *(ModelSpec(f"sindy{k}", f"SINDy-{k}", model("sindy", k),
                    cost=(1.0, 1.1, 1.2, 1.6)[k - 1]) for k in (1, 2, 3, 4)),
        ModelSpec("linear", "linear (E2C)", model("linear"), cost=0.8),
        ModelSpec("mlp", "MLP", model("mlp"), cost=0.9),
        ModelSpec(f"sindy2_h{h}", f"SINDy-2, H={h}", model("sindy"),
                  horizon=h, cost=1.1 * (h + 1) / 2),
    )


def control_plan(scale: Scale, seed: int) -> dict[str, ControlSettings]:
    """Folder name -> settings of every closed-loop condition (episodes > 0 only)."""
    common = {"seed": seed, "until": scale.until, "samples": scale.samples,
              "horizon": scale.mppi_horizon, "gif_episodes": 1}
    conditions = (("paper", False, scale.paper_episodes, scale.max_steps),
                  ("random", False, scale.random_episodes, scale.max_steps),
                  ("paper", True, scale.image_paper_episodes, scale.image_max_steps),
                  ("random", True, scale.image_random_episodes, scale.image_max_steps))
    return {f"control-{task}-{'image' if image else 'latent'}":
            ControlSettings(task=task, episodes=n, image_space=image, max_steps=steps, **common)
            for task, image, n, steps in conditions if n > 0}


# ----------------------------------------------------------------------------- outputs
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


# ----------------------------------------------------------------------------- the study
@dataclass
class Study:
    """What the pipeline produced, handed to the outputs (tables, figures, report)."""

    config: ReproduceConfig
    specs: tuple[ModelSpec, ...]
    runs: dict[int, dict[str, Path]]
    results: dict[int, dict[str, dict[str, Any]]] = field(default_factory=dict)
    per_seed: dict[int, dict[str, dict[str, float | None]]] = field(default_factory=dict)
    stats: dict[str, dict[str, Stat]] = field(default_factory=dict)
    failures: list[str] = field(default_factory=list)
    baselines: dict[str, list[float]] = field(default_factory=dict)
    """Prediction error against horizon of the model-free predictors (evaluation.BASELINES)."""
    timings: dict[str, float] = field(default_factory=dict)
    train_status: dict[str, str] = field(default_factory=dict)

    @property
    def models(self) -> list[str]:
        return [s.name for s in self.specs]

    @property
    def labels(self) -> dict[str, str]:
        return {s.name: s.label for s in self.specs}


def _collect(cfg: ReproduceConfig, say: Callable[[str], None]) -> Path:
    path, scale = cfg.data_path, cfg.preset
    if cfg.data is not None and path.exists():
        say(f"[1/4] data: using {path} as given")
        return path
    plan = CollectionPlan(scale.trajectories, scale.steps, cfg.data_seed)
    if path.exists():
        say(f"[1/4] data: reusing {path}")
    else:
        say(f"[1/4] data: collecting {plan.trajectories} trajectories x {plan.steps} pushes "
            f"into {path} ({cfg.workers} worker(s))")
    bar = None
    if cfg.verbose:
        from tqdm import tqdm

        def bar(it, total, initial):
            return tqdm(it, total=total, initial=initial, desc="collect", unit="traj",
                        file=sys.stderr, dynamic_ncols=True, leave=False)

    return collect(path, plan, cfg.workers, bar)


def _train_and_evaluate(study: Study, data: Path, say: Callable[[str], None]) -> None:
    """Every (seed, model): train (or reuse), then evaluate and control, on a process pool."""
    cfg, scale = study.config, study.config.preset
    jobs = []
    for seed in cfg.seeds:
        for spec in study.specs:
            run = study.runs[seed][spec.name]
            tc = TrainConfig(data=data, out=run, model=spec.model, horizon=spec.horizon,
                             epochs=scale.epochs, batch_size=scale.batch_size,
                             threshold=scale.threshold, threshold_every=scale.threshold_every,
                             seed=seed)
            jobs.append(TrainJob(tc, spec.name, seed, cfg.threads, cfg.verbose, spec.cost))
    jobs.sort(key=lambda j: -j.cost)  # longest first: the pool's tail stays short
    n = len(jobs)
    episodes = sum(s.episodes for s in control_plan(scale, 0).values())
    say(f"[2/4] training and evaluating {len(study.specs)} models x {len(cfg.seeds)} seed(s) "
        f"({scale.epochs} epochs; {episodes} control episodes per model) on "
        f"{min(cfg.workers, n)} process(es)")
    with executor(cfg.workers, n) as pool:
        try:
            _drain(pool, jobs, study, data, say)
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)  # no queued job starts after an error
            raise
    study.stats = {name: aggregate([study.per_seed[s][name] for s in cfg.seeds
                                    if name in study.per_seed.get(s, {})])
                   for name in study.models}


def _drain(pool: Inline | Pool, jobs: list[TrainJob], study: Study, data: Path,
           say: Callable[[str], None]) -> None:
    """Run the training jobs; each finished one queues its evaluation; until all are done."""
    scale, threads, n = study.config.preset, study.config.threads, len(jobs)
    t0 = time.perf_counter()
    done_eval = 0
    pending: dict[Future, tuple[str, Any]] = {
        pool.submit(train_job, j): ("train", j) for j in jobs}
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
                ev = EvalJob(job.config.out, data, job.name, job.seed,
                              control_plan(scale, job.seed), threads)
                pending[pool.submit(eval_job, ev)] = ("eval", ev)
            else:
                done_eval += 1
                study.results.setdefault(job.seed, {})[job.name] = result
                m = flat_metrics(result)
                study.per_seed.setdefault(job.seed, {})[job.name] = m
                say(f"  [{elapsed:5.0f} s] evaluated {job.name} (seed {job.seed}) in "
                    f"{result['seconds']:.0f} s: test loss {_num(m['loss/test'])}, "
                    f"random-task success {_pct(m.get('control/random/latent/success_rate'))}"
                    f" ({done_eval}/{n})")


def _pct(v: float | None) -> str:
    return "n/a" if v is None or not math.isfinite(v) else f"{100 * v:.0f}%"


def _num(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.4g}"


def _write_outputs(study: Study, data: Path, say: Callable[[str], None]) -> dict[str, Any]:
    """Figures, equations, tables and summary.json; returns what the report shows."""
    from latent_sindy.equations import equations_report

    out, cfg = study.config.out, study.config
    fig_dir = out / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    first = cfg.seeds[0]
    ok = [m for m in study.models if m in study.results.get(first, {})]
    runs = study.runs[first]
    files: dict[str, Any] = {"coefficients": {}, "gifs": [], "equations": {}}

    histories = {m: read_metrics(runs[m]) for m in ok}
    loss_labels = {s.name: s.label + ("" if s.horizon == 1 else f" (its H={s.horizon} objective)")
                   for s in study.specs}
    files["loss"] = figures.loss_histories(histories, loss_labels, fig_dir / "loss_histories.png")

    curves = {}
    for m in study.models:
        hs = [study.per_seed[s][m] for s in cfg.seeds if m in study.per_seed.get(s, {})]
        if hs:
            keys = sorted((k for k in hs[0] if k.startswith("pred_err/h") and k[10:].isdigit()),
                          key=lambda k: int(k[10:]))
            st = [study.stats[m][k] for k in keys]
            curves[m] = ([s.mean for s in st], [s.std for s in st])
    trajectories = read_trajectories(data)
    test = held_out(trajectories)
    study.baselines = baseline_errors(trajectories.split("train"), test,
                                      Normalizer.from_trajectories(trajectories))
    references = {BASELINES[k]: v for k, v in study.baselines.items()}
    files["horizon"] = figures.horizon_plot(curves, study.labels, fig_dir / "prediction_error.png",
                                            references)

    single, multi = "sindy2", study.specs[-1].name
    if single in ok and multi in ok:
        files["rollouts"] = _rollout_figure(runs[single], runs[multi], test, study,
                                            fig_dir / "rollouts.png")
    for spec in study.specs:
        if spec.model.kind == "sindy" and spec.name in ok:
            dyn = load_run(runs[spec.name]).model.dynamics
            files["coefficients"][spec.name] = figures.coefficient_map(
                dyn, spec.label, fig_dir / f"coefficients_{spec.name}.png")

    bars, plan_ms = {}, {}
    for cond in ("paper/latent", "random/latent", "paper/image", "random/image"):
        key = f"control/{cond}/success_rate"
        if any(key in study.stats[m] for m in ok):
            bars[cond.replace("/", ", ")] = {m: study.stats[m][key].mean for m in ok
                                             if key in study.stats[m]}
    for m in ok:
        plan_ms[m] = study.stats[m]["control/latent/plan_ms_mean"].mean
    files["control"] = figures.control_bars(ok, study.labels, bars, plan_ms,
                                            fig_dir / "control.png")

    gif_dir = fig_dir / "gifs"
    gif_dir.mkdir(exist_ok=True)
    for m in ok:
        for folder in study.results[first][m]["control"]:
            src = runs[m] / folder / "episode_000.gif"
            if src.exists():
                dst = gif_dir / f"{m}_{folder.removeprefix('control-')}.gif"
                shutil.copyfile(src, dst)
                files["gifs"].append((m, folder, dst))

    for m in study.models:
        parts = []
        for s in cfg.seeds:
            run = study.runs[s][m]
            if m in study.results.get(s, {}):
                export = not (run / "coefficients.csv").exists()
                parts.append(f"# seed {s}\n{equations_report(run, export=export)}")
        if parts:
            path = out / f"equations_{m}.txt"
            path.write_text("\n\n".join(parts) + "\n")
            files["equations"][m] = path

    files["table_md"], files["table_csv"] = write_table1(
        out, study.models, study.labels, study.stats, len(cfg.seeds))
    say(f"[3/4] wrote {files['table_md']}, {files['table_csv']}, figures/ and equations")
    return files


@torch.no_grad()
def _rollout_figure(single: Path, multi: Path, test: Trajectories, study: Study,
                    path: Path) -> Path:
    """Fig. 8: a test trajectory, and both models' open-loop rollouts from its first image."""
    rows = [("ground truth", test.images[0].astype(float))]
    for run_dir, spec in ((single, study.specs[1]), (multi, study.specs[-1])):
        run = load_run(run_dir)
        x = run.normalizer.normalize(test.images[:1])  # (1, T+1, C, S, S)
        u = torch.as_tensor(test.actions[:1], dtype=torch.float32)  # (1, T, 3)
        pred = run.model.predict(x[:, 0], u)[0]  # (T+1, C, S, S)
        kind = "single-step" if spec.horizon == 1 else "multi-step"
        rows.append((f"{kind} SINDy-2\n(trained on H={spec.horizon})",
                     run.normalizer.denormalize(pred).numpy()))
    return figures.rollout_strip(rows, path)


def _summary(study: Study, data: Path) -> dict[str, Any]:
    d = read_trajectories(data)
    return _json_safe({
        "config": study.config.to_dict(),
        "scale": asdict(study.config.preset),
        "seeds": list(study.config.seeds),
        "models": {s.name: {"label": s.label, "model": s.model.to_dict(), "horizon": s.horizon}
                   for s in study.specs},
        "data": {"path": str(data), "trajectories": d.n, "steps": d.steps,
                 "splits": d.split_counts(), "seed": d.seed},
        "control": {k: asdict(v) for k, v in control_plan(study.config.preset, 0).items()},
        "versions": versions(),
        "machine": {"cpus": os.cpu_count(), "load_average": list(os.getloadavg()),
                    "platform": platform.platform()},
        "timings_s": study.timings,
        "train_status": study.train_status,
        "failures": study.failures,
        "baselines": {"labels": BASELINES, "pred_err": study.baselines},
        "aggregate": {m: {k: _stat_dict(s) for k, s in st.items()}
                      for m, st in study.stats.items()},
        "per_seed": {str(s): v for s, v in study.per_seed.items()},
        "losses_per_seed": {str(s): {m: r["losses"] for m, r in v.items()}
                            for s, v in study.results.items()},
    })


def reproduce(config: ReproduceConfig, progress: Callable[[str], None] | None = None) -> Path:
    """Run (or complete) the whole study in ``config.out``; returns the path of report.html.

    ``progress`` receives one line per stage and per finished job; None prints them to
    stderr when ``config.verbose`` (training milestones are printed by the workers).
    """
    t_start = time.perf_counter()
    say = progress or (say_stderr if config.verbose else (lambda _: None))
    out = config.out
    out.mkdir(parents=True, exist_ok=True)
    specs = model_specs(config.preset, config.decoder)
    runs = {s: {m.name: out / "runs" / f"seed{s}" / m.name for m in specs} for s in config.seeds}
    study = Study(config, specs, runs)
    threads = torch.get_num_threads()
    torch.set_num_threads(config.threads)  # for the in-process work; restored below
    try:
        data = _collect(config, say)
        study.timings["collect"] = time.perf_counter() - t_start
        t = time.perf_counter()
        _train_and_evaluate(study, data, say)
        study.timings["train_evaluate_control"] = time.perf_counter() - t
        if not study.results.get(config.seeds[0]):
            raise UserError(f"no model of seed {config.seeds[0]} finished training: "
                            + "; ".join(study.failures))
        t = time.perf_counter()
        files = _write_outputs(study, data, say)
        study.timings["outputs"] = time.perf_counter() - t
        study.timings["total"] = time.perf_counter() - t_start
        summary = _summary(study, data)
        (out / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=False))
        report = write_report(study, files, summary, out / "report.html")
    finally:
        torch.set_num_threads(threads)
    say(f"[4/4] report: {report} (this run took {time.perf_counter() - t_start:.0f} s)")
    return report
