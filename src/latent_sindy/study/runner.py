"""What every study of ``latent-sindy reproduce`` shares, whatever its world: the study folder
(one study at a time, one kind of study per folder), the record of versions and machine,
standard JSON, and the run of a world plug-in's own study (its ``reproduce`` hook, see
:data:`latent_sindy.plugins.HOOKS`) written in the common format: summary.json, table.md,
equations_<name>.txt and report.html. It knows no world: it asks the plug-ins.

    latent-sindy reproduce --world pendulum --scale tiny --out /tmp/pendulum

    with study_folder(Path("results"), "pendulum") as out:
        report = write_world_study(study_worlds()["pendulum"], settings, say)[0]
"""

from __future__ import annotations

import json
import math
import os
import platform
import subprocess
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import torch

from latent_sindy.atomic import check_output_dir, write_atomic
from latent_sindy.configs import to_json
from latent_sindy.errors import UserError
from latent_sindy.locks import exclusive
from latent_sindy.plugins import CONFIG_GIVEN, default_world, get_world, hook, world_names
from latent_sindy.progress import say_stderr
from latent_sindy.result_files import record_rows
from latent_sindy.study.report import Report
from latent_sindy.world_study import WorldStudy

__all__ = ["check_study_folder", "json_safe", "machine", "run_world_study", "study_folder",
           "study_worlds", "versions", "write_world_study"]

Say = Callable[[str], None]


def study_worlds() -> dict[str, Any]:
    """The installed world plug-ins that have a study of their own (``reproduce``)."""
    found = {}
    for name in world_names():
        try:
            world = get_world(name)
        except Exception:  # a broken plug-in must not break the other commands (asked for
            continue       # by name, get_world raises its error)
        if callable(hook(world, "reproduce")) and hook(world, "scales") is not None:
            found[name] = world
    return found


def json_safe(obj: Any) -> Any:
    """NaN and inf to None, recursively, so summary.json is standard JSON."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Mapping):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [json_safe(v) for v in obj]
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


def machine() -> dict[str, Any]:
    """The machine a study ran on: cores, load, platform."""
    return {"cpus": os.cpu_count(), "load_average": list(os.getloadavg()),
            "platform": platform.platform()}


def check_study_folder(out: Path, study: str) -> None:
    """UserError if ``out`` holds the results of another study (its summary.json names the
    world: a world study's at its top; one with its config but no world is the default
    world's study): the study would write its summary.json, report.html and table.md over
    them."""
    path = out / "summary.json"
    try:
        summary = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return  # no summary (yet), or one no study can have written: nothing to keep apart
    if not isinstance(summary, dict):
        return
    held = summary.get("world") or (default_world() if "config" in summary else None)
    if held is not None and held != study:
        raise UserError(f"--out {out} holds the {held} study (its summary.json): choose "
                        f"another --out for the {study} study")


@contextmanager
def study_folder(out: Path, study: str) -> Iterator[Path]:
    """The study folder ``out`` held by this process for the study ``study`` (a world's
    name): refused if another study's results are there; a study refused before it wrote
    anything leaves no folder. Its workers do not lock it: they write into it only while
    this process holds it, and die with this process (latent_sindy.executors)."""
    out = check_output_dir(out, "--out")
    with exclusive(out, "study folder"):
        check_study_folder(out, study)
        created = not out.exists()
        try:
            yield out
        except BaseException:
            if created and out.is_dir() and not any(out.iterdir()):
                out.rmdir()
            raise


def _markdown(header: list[str], rows: list[list[str]]) -> list[str]:
    def cell(v: object) -> str:
        return str(v).replace("|", "\\|")

    return ["| " + " | ".join(map(cell, header)) + " |", "|" + "---|" * len(header),
            *("| " + " | ".join(map(cell, r)) + " |" for r in rows)]


def _device() -> dict[str, Any]:
    cuda = torch.cuda.is_available()
    return {"cuda_available": cuda, "cuda_device": torch.cuda.get_device_name(0) if cuda
            else None, "torch_threads": torch.get_num_threads()}


def write_world_study(world: Any, settings: Any, say: Say, t_start: float | None = None
                      ) -> tuple[Path, WorldStudy, dict[str, Any]]:
    """The study of the world plug-in ``world`` (its ``reproduce`` hook), run in
    ``settings.out`` (the caller holds the folder: :func:`study_folder`) with the settings'
    ``scale``, ``seeds``, ``device`` and ``threads``; what it returns (a
    :class:`~latent_sindy.world_study.WorldStudy`) is written as summary.json (with
    ``settings`` whole, a dataclass), table.md, equations_<name>.txt and report.html.
    Returns (report.html, that study, the summary written)."""
    t_start = time.perf_counter() if t_start is None else t_start
    out = settings.out
    out.mkdir(parents=True, exist_ok=True)
    options = {name: getattr(settings, name) for name in hook(world, "study_options") or ()}
    study = world.reproduce(settings.scale, out, settings.seeds, settings.device,
                            settings.threads, say, **options)
    if not isinstance(study, WorldStudy):
        raise TypeError(f"the {settings.world} world's reproduce returned "
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
    summary = json_safe({
        "world": settings.world, "scale": settings.scale, "config": to_json(settings),
        "study": study.settings, "seeds": list(study.seeds), "results": study.numbers,
        "findings": study.findings, "versions": versions(),
        "machine": {**machine(), **_device()},
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
    if getattr(settings, "record", None) is not None and study.rows:
        given = getattr(world, CONFIG_GIVEN, ())
        name = "_".join([settings.scale, *(f"{k}={getattr(world.config, k)}" for k in given)])
        cuda = _device()["cuda_device"]
        device = "cpu" if cuda is None or getattr(settings, "device", "auto") == "cpu" \
            else f"cuda ({cuda})"
        path = record_rows(settings.record, settings.world, name, study.rows, device=device)
        say(f"recorded {len(study.rows)} row(s) in {path}")
    say(f"report: {report} (this run took {time.perf_counter() - t_start:.0f} s)")
    return report, study, summary


def run_world_study(world: Any, settings: Any, say: Say | None = None) -> Path:
    """``latent-sindy reproduce`` of a world with a study of its own (:func:`study_worlds`):
    its study in ``settings.out``, held for it; returns the path of report.html. ``say``
    receives the study's lines (default: stderr when ``settings.verbose``, if it has one)."""
    t_start = time.perf_counter()
    if say is None:
        say = say_stderr if getattr(settings, "verbose", True) else (lambda _: None)
    with study_folder(settings.out, settings.world):
        return write_world_study(world, settings, say, t_start)[0]
