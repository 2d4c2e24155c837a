"""The study's last stage: figures, equations and tables of a finished :class:`~.results.Study`.

:func:`output_stage` writes them under OUT and returns the files the report shows (the page:
:mod:`.study_report`; summary.json and report.html are written by ``latent-sindy reproduce``
from what :mod:`latent_sindy.worlds.push.study.pipeline` returns).

    latent-sindy reproduce --scale tiny --out /tmp/tiny   # OUT/figures/, table1.md, equations_*.txt
"""

from __future__ import annotations

import shutil
from collections.abc import Callable, Collection, Mapping
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import torch

from latent_sindy.atomic import write_atomic
from latent_sindy.data import SequenceData, read_sequences
from latent_sindy.executors import Executor, Resources
from latent_sindy.study.evaluation import BASELINES
from latent_sindy.training import RunDir, load_run, read_metrics
from latent_sindy.worlds.push.study import figures
from latent_sindy.worlds.push.study.config import StudyPlan
from latent_sindy.worlds.push.study.jobs import held_out, written_after
from latent_sindy.worlds.push.study.results import Study
from latent_sindy.worlds.push.study.table import write_sweep_table, write_table1

__all__ = ["model_figure_jobs", "model_figures", "output_stage", "submit_model_figures",
           "write_equations"]

Say = Callable[[str], None]


def output_stage(study: Study, data: SequenceData, say: Say,
                 started: Mapping[str, Future] | None = None,
                 pool: Executor | None = None) -> dict[str, Any]:
    """Figures, equations and tables of a finished study; returns what the report shows.
    ``started``: the :func:`submit_model_figures` of ``pool``, drawn while the evaluations
    ran; a figure it lacks is drawn here."""
    out = study.config.out
    cfg = study.config
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
    references = {BASELINES[k]: v for k, v in study.baselines.pred_err.items()}
    files["horizon"] = figures.horizon_plot(curves, study.labels, fig_dir / "prediction_error.png",
                                            references)
    position = _curves(study, "pos_err/h")
    if position and study.baselines.position:
        files["position"] = figures.horizon_plot(
            position, study.labels, fig_dir / "position_error.png",
            {"nothing moves": study.baselines.position["still"],
             "reading the true image": study.baselines.position["reader"]},
            ylabel="block position error (cm)", yscale="linear", cap=10.0,
            title="block position in open-loop predictions (state rows: predicted poses), "
                  "test trajectories")

    conditions = study.scale.all_conditions()
    bars = {}
    plan_ms = {}
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

    files["equations"] = write_equations(study)
    files["table_md"], files["table_csv"] = write_table1(
        out, study.models, study.labels, study.stats, len(cfg.seeds))
    if cfg.sweep:
        files["sweep"] = write_sweep_table(out / "sweep.md", study.models, study.labels,
                                           study.per_seed, cfg.seeds)
    # last: what the pool drew meanwhile (or, without one, drawn now)
    for key, path in model_figures(study, ok, data, started or {}, pool).items():
        if key == "rollouts":
            files["rollouts"] = path
        elif path is not None:
            files["coefficients"][key] = path
    say(f"[3/3] wrote {files['table_md']}, {files['table_csv']}, figures/ and equations")
    return files


# ------------------------------------------------------------ figures of trained models
def model_figure_jobs(plan: StudyPlan, trained: Collection[str], data: Path | SequenceData
                      ) -> list[tuple[str, Callable, tuple]]:
    """The figures of the first seed's ``trained`` models that need no evaluation, as
    (key, function, arguments): "rollouts" (Fig. 8: the single- and multi-step SINDy-2, the
    paper's, then the other headline image models, what the representation work bought) and
    each model's coefficient map (key: its name; None for a model without one)."""
    fig_dir = plan.config.out / "figures"
    threads = plan.config.threads
    runs = plan.runs[plan.config.seeds[0]]
    single, multi = plan.single_step, plan.multistep
    strip = [(runs[s.name], f"{kind} {s.label}\n(trained on H={s.window})")
             for kind, s in (("single-step", single), ("multi-step", multi))
             if s is not None and s.name in trained]
    strip += [(runs[s.name], s.label.replace(", ", ",\n", 1) if len(s.label) > 24 else s.label)
              for s in plan.specs if s.headline and s.name in trained
              and s not in (single, multi) and s.model.observation.kind == "image"]
    jobs: list[tuple[str, Callable, tuple]] = []
    if strip:
        jobs.append(("rollouts", rollout_job, (strip, data, fig_dir / "rollouts.png", threads)))
    jobs += [(s.name, coefficient_job, (runs[s.name], s.label,
                                        fig_dir / f"coefficients_{s.name}.png", threads))
             for s in plan.specs if s.name in trained]
    return jobs


def submit_model_figures(plan: StudyPlan, trained: Collection[str], data: Path,
                         pool: Executor) -> dict[str, Future]:
    """:func:`model_figure_jobs` started on ``pool`` (queued behind its jobs: they fill the
    slots the last evaluations leave idle); key -> future of the figure's path."""
    (plan.config.out / "figures").mkdir(parents=True, exist_ok=True)
    return {key: pool.submit(fn, *args, resources=Resources(cpus=plan.config.threads),
                             name=f"drawing the figure {key}")
            for key, fn, args in model_figure_jobs(plan, trained, data)}


def model_figures(plan: StudyPlan, trained: Collection[str], data: Path | SequenceData,
                  started: Mapping[str, Future], pool: Executor | None = None
                  ) -> dict[str, Path | None]:
    """Key -> path of each :func:`model_figure_jobs` figure: as ``started`` drew it (on
    ``pool``), else drawn here."""
    jobs = model_figure_jobs(plan, trained, data)
    waiting = {started[key]: key for key, _, _ in jobs if key in started}
    while waiting and pool is not None:
        for fut in pool.wait_one(waiting):
            waiting.pop(fut, None)
    return {key: started[key].result() if key in started else fn(*args)
            for key, fn, args in jobs}


def coefficient_job(run_dir: Path, label: str, path: Path, threads: int) -> Path | None:
    """The coefficient map of the run in ``run_dir`` (None if its dynamics are not sparse);
    one drawn after the run's model was written is reused."""
    if written_after(path, [RunDir(run_dir) / RunDir.MODEL]):
        return path
    torch.set_num_threads(threads)
    dyn = load_run(run_dir).model.dynamics
    return figures.coefficient_map(dyn, label, path) if hasattr(dyn, "mask") else None


def rollout_job(models: list[tuple[Path, str]], data: Path | SequenceData, path: Path,
                threads: int) -> Path:
    """Fig. 8 (:func:`_rollout_figure`) from the trajectories ``data`` (or their file); one
    drawn after their file and every model was written is reused."""
    file = data if isinstance(data, Path) else Path(data.source)
    if file.is_file() and written_after(
            path, [file, *(RunDir(run) / RunDir.MODEL for run, _ in models)]):
        return path
    torch.set_num_threads(threads)
    data = read_sequences(data) if isinstance(data, Path) else data
    return _rollout_figure(models, held_out(data), path)


def write_equations(study: Study) -> dict[str, Path]:
    """OUT/equations_<model>.txt: each finished seed's equations (and each run's exported
    coefficients, where missing); returns {model: path}."""
    from latent_sindy.equations import equations_report

    files = {}
    for m in study.models:
        parts = []
        for s in study.config.seeds:
            run = RunDir(study.runs[s][m])
            if m in study.results.get(s, {}):
                export = not (run / run.COEFFICIENTS_CSV).exists()
                parts.append(f"# seed {s}\n{equations_report(run.path, export=export)}")
        if parts:
            path = study.config.out / f"equations_{m}.txt"
            text = "\n\n".join(parts) + "\n"
            write_atomic(path, lambda f, text=text: f.write(text), binary=False)
            files[m] = path
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


def _rollout_figure(models: list[tuple[Path, str]], test: SequenceData, path: Path) -> Path:
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
