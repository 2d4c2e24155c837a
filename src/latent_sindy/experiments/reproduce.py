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

    from latent_sindy.experiments.config import ReproduceConfig
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

A world plug-in with a study of its own (``--world pendulum``, ``--world pendulum-video``;
see :func:`.config.study_worlds`) runs that study instead, and OUT holds what it returns in
the same format: summary.json, table.md, report.html, equations_<name>.txt, figures/ and
whatever the study keeps to resume (:func:`world_study`).

The push pipeline reads as stages, each a function of what the earlier ones returned
(:mod:`.stages`, :mod:`.outputs`): data (collect) -> train + evaluate + control (the
evaluations) -> baselines -> the :class:`~.results.Study` they make -> outputs (figures,
equations, tables) -> summary.json and report.html. Collection shards and the
(model, seed) jobs run on the study's executor (latent_sindy.executors: local processes or Ray).
"""


from __future__ import annotations

import dataclasses
import json
import math
import os
import platform
import subprocess
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import torch

from latent_sindy.atomic import check_output_dir, write_atomic
from latent_sindy.configs import to_json
from latent_sindy.data import SequenceData, read_sequences
from latent_sindy.errors import UserError
from latent_sindy.executors import ExecutorOptions, make_executor
from latent_sindy.experiments.config import ReproduceConfig, StudyPlan
from latent_sindy.experiments.evaluation import BASELINES, Stat
from latent_sindy.experiments.outputs import output_stage
from latent_sindy.experiments.report import Report
from latent_sindy.experiments.results import Study
from latent_sindy.experiments.stages import (
    baseline_stage,
    check_given_data,
    collect_stage,
    run_stage,
)
from latent_sindy.experiments.study_report import write_report
from latent_sindy.locks import exclusive
from latent_sindy.progress import say_stderr
from latent_sindy.world_study import WorldStudy

__all__ = ["reproduce", "summary_record", "versions", "world_study"]

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

    from latent_sindy.version import __version__

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


def summary_record(study: Study, data: SequenceData, data_path: Path) -> dict[str, Any]:
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
        check_given_data(config, read_sequences(config.data))
    # One study per folder at a time. Its workers do not lock it: they write into it only
    # while this process holds it, and die with this process (latent_sindy.executors).
    with exclusive(out, "study folder"):
        _check_study_folder(out, config.world if config.study_world is not None else "push")
        created = not out.exists()
        try:
            if config.study_world is not None:
                return world_study(config, say, t_start)[0]
            return _study(config, out, say, t_start)
        except BaseException:
            if created and out.is_dir() and not any(out.iterdir()):
                out.rmdir()  # a study refused before it wrote anything leaves no folder
            raise


def _check_study_folder(out: Path, study: str) -> None:
    """UserError if ``out`` holds the results of another study (its summary.json names the
    world: a world study's at its top, the push study's in its config): the study would
    write its summary.json, report.html and table.md over them."""
    path = out / "summary.json"
    try:
        summary = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return  # no summary (yet), or one no study can have written: nothing to keep apart
    if not isinstance(summary, dict):
        return
    held = summary.get("world") or ("push" if "config" in summary else None)
    if held is not None and held != study:
        raise UserError(f"--out {out} holds the {held} study (its summary.json): choose "
                        f"another --out for the {study} study")


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
                evaluations = run_stage(plan, data_path, pool, say)
                timings["train_evaluate_control"] = time.perf_counter() - t
            except BaseException:
                pool.shutdown(wait=False, cancel_futures=True)  # no queued job starts after this
                raise
        if not evaluations.results.get(config.seeds[0]):
            raise UserError(f"no model of seed {config.seeds[0]} finished training: "
                            + "; ".join(evaluations.failures))
        t = time.perf_counter()
        data = read_sequences(data_path)
        study = Study(config=plan.config, specs=plan.specs, runs=plan.runs,
                      evaluations=evaluations, baselines=baseline_stage(data), timings=timings)
        files = output_stage(study, data, say)
        study = dataclasses.replace(study, timings={
            **timings, "outputs": time.perf_counter() - t,
            "total": time.perf_counter() - t_start})
        summary = summary_record(study, data, data_path)
        text = json.dumps(summary, indent=1, allow_nan=False)
        write_atomic(out / "summary.json", lambda f: f.write(text), binary=False)
        report = write_report(study, files, summary, out / "report.html")
    finally:
        torch.set_num_threads(threads)
    say(f"[4/4] report: {report} (this run took {time.perf_counter() - t_start:.0f} s)")
    return report


# ----------------------------------------------------------------------------- a world's study
def _markdown(header: list[str], rows: list[list[str]]) -> list[str]:
    def cell(v: object) -> str:
        return str(v).replace("|", "\\|")

    return ["| " + " | ".join(map(cell, header)) + " |", "|" + "---|" * len(header),
            *("| " + " | ".join(map(cell, r)) + " |" for r in rows)]


def _device() -> dict[str, Any]:
    cuda = torch.cuda.is_available()
    return {"cuda_available": cuda, "cuda_device": torch.cuda.get_device_name(0) if cuda
            else None, "torch_threads": torch.get_num_threads()}


def world_study(config: ReproduceConfig, say: Say, t_start: float | None = None
                ) -> tuple[Path, Any, dict[str, Any]]:
    """The study of the world plug-in ``config.world`` in ``config.out`` (the caller holds
    the folder): it runs there and returns what it found (an object with ``title``,
    ``settings``, ``seeds``, ``numbers``, ``findings``, ``tables`` of (``heading``,
    ``header``, ``rows``, ``note``), ``figures`` of (PNG, caption) and ``equations``, name ->
    text), which is written as summary.json, table.md, equations_<name>.txt and
    report.html. Returns (report.html, that study, the summary written)."""
    t_start = time.perf_counter() if t_start is None else t_start
    out = config.out
    out.mkdir(parents=True, exist_ok=True)
    world = config.study_world
    study = world.reproduce(config.scale, out, config.seeds, config.device,
                            config.threads, say)
    if not isinstance(study, WorldStudy):
        raise TypeError(f"the {config.world} world's reproduce returned "
                        f"{type(study).__name__}, not a latent_sindy.world_study.WorldStudy")
    t_study = time.perf_counter() - t_start
    files = []
    for name, text in study.equations.items():
        path = out / f"equations_{name}.txt"
        write_atomic(path, lambda f, t=text: f.write(t if t.endswith("\n") else t + "\n"),
                     binary=False)
        files.append(path.name)
    md = [f"# {study.title}", "", *study.findings]
    for t in study.tables:
        md += ["", f"## {t.heading}", "", *_markdown(t.header, t.rows)]
        md += ["", t.note] if t.note else []
    write_atomic(out / "table.md", lambda f: f.write("\n".join(md) + "\n"), binary=False)
    summary = _json_safe({
        "world": config.world, "scale": config.scale, "config": to_json(config),
        "study": study.settings, "seeds": list(study.seeds), "results": study.numbers,
        "findings": study.findings, "versions": versions(),
        "machine": {"cpus": os.cpu_count(), "load_average": list(os.getloadavg()),
                    "platform": platform.platform(), **_device()},
        "files": ["table.md", "report.html", *files,
                  *(str(p.relative_to(out)) for p, _ in study.figures)],
        "timings_s": {"study": t_study, "total": time.perf_counter() - t_start}})
    text = json.dumps(summary, indent=1, allow_nan=False)
    write_atomic(out / "summary.json", lambda f: f.write(text), binary=False)
    r = Report(study.title)
    for line in study.findings:
        r.paragraph(line)
    for t in study.tables:
        r.heading(t.heading).table(t.header, t.rows)
        if t.note:
            r.paragraph(t.note, cls="note")
    for path, caption in study.figures:
        r.image(path, caption)
    r.heading("Equations")
    for name, eqs in study.equations.items():
        r.paragraph(f"{name} (equations_{name}.txt)").preformatted(eqs)
    r.heading("Settings, versions, timings")
    r.preformatted(json.dumps({k: summary[k] for k in ("config", "study", "versions",
                                                       "machine", "timings_s")}, indent=1))
    report = r.write(out / "report.html")
    say(f"report: {report} (this run took {time.perf_counter() - t_start:.0f} s)")
    return report, study, summary
