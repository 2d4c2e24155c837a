"""What every study of ``latent-sindy reproduce`` shares, whatever its world: the world it
names (a world plug-in with a study of its own, or a named world of one), the study folder
(one study at a time, one kind of study per folder), the record of versions and machine,
standard JSON, and the run of the world's study (its ``reproduce`` hook, see
:data:`latent_sindy.plugins.HOOKS`) written in the common format: summary.json, table.md,
equations_<name>.txt and report.html (the world's own page where it gives one). It knows no
world: it asks the plug-ins.

    latent-sindy reproduce --world pendulum --scale tiny --out /tmp/pendulum

    report = run_study(StudySettings(world="pendulum", scale="tiny", out=Path("/tmp/p")))
    report = run_study(StudySettings(scale="tiny", out=Path("/tmp/s")), {"models": ("sindy2",)})
"""

from __future__ import annotations

import json
import math
import os
import platform
import subprocess
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

import torch

from latent_sindy.atomic import check_output_dir, write_atomic
from latent_sindy.configs import from_pairs, to_json
from latent_sindy.errors import UserError
from latent_sindy.locks import exclusive
from latent_sindy.plugins import CONFIG_GIVEN, default_world, get_world, hook, world_names
from latent_sindy.progress import say_stderr
from latent_sindy.result_files import record_rows
from latent_sindy.study.commands import configured_world
from latent_sindy.study.report import Report
from latent_sindy.study.settings import OPTIONS, StudySettings
from latent_sindy.training.config import resolve_device
from latent_sindy.world_study import WorldStudy

__all__ = ["check_study_folder", "given_options", "json_safe", "machine", "run_study",
           "scale_help", "study_folder", "study_options", "study_world", "study_worlds",
           "versions", "world_help", "write_world_study"]

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


def _named_worlds() -> dict[str, str]:
    """Named world -> the world with a study whose ``named_worlds`` holds it (a name two
    worlds hold, or a world's own name, is left out: ``--world`` would not say which)."""
    studies = study_worlds()
    owners: dict[str, list[str]] = {}
    for name, world in studies.items():
        for named in hook(world, "named_worlds") or {}:
            owners.setdefault(named, []).append(name)
    return {named: found[0] for named, found in owners.items()
            if len(found) == 1 and named not in studies}


def study_world(name: str, pairs: Sequence[str] = ()) -> tuple[str, Any]:
    """The world whose study ``reproduce --world NAME`` runs, and the name of its plug-in: a
    world with a study of its own, or a named world of one (its class built on those
    settings), rebuilt on the ``--world-config`` ``pairs`` where any are given."""
    studies = study_worlds()
    if name in studies:
        return name, configured_world(name, pairs)
    owner = _named_worlds().get(name)
    if owner is None:
        named = ", ".join(_named_worlds())
        raise UserError(f"--world {name}: use a world with a study of its own "
                        f"({', '.join(studies) or 'none installed'})"
                        + (f" or a named world of one ({named})" if named else ""))
    plugin = studies[owner]
    base = hook(plugin, "named_worlds")[name]
    world = type(plugin)(base)
    if pairs:
        given = from_pairs(type(base), pairs, "--world-config")
        keys = tuple(p.partition("=")[0].strip() for p in pairs)
        world = type(plugin)(replace(base, **{k: getattr(given, k) for k in keys}))
        setattr(world, CONFIG_GIVEN, keys)
    return owner, world


def _default_first(names: Sequence[str]) -> list[str]:
    """``names`` with the default world's first (where one is installed)."""
    try:
        default = default_world()
    except UserError:
        default = None
    return sorted(names, key=lambda name: name != default)


def world_help() -> str:
    """The ``--world`` help of ``reproduce``: each world with a study (its ``about`` names
    its named worlds)."""
    studies = study_worlds()
    return ("The world whose study runs (default: the default world, first here): "
            + "; ".join(f"{name}: {hook(studies[name], 'about') or 'its own study'}"
                        for name in _default_first(list(studies)))
            + ". Each writes the same report format.")


def scale_help() -> str:
    """The ``--scale`` help of ``reproduce``: each world's scales with what each runs."""
    studies = study_worlds()
    return "The study's size. " + " ".join(
        f"{name}: " + "; ".join(f"{scale} ({what})" for scale, what in studies[name].scales.items())
        + "." for name in _default_first(list(studies)))


def given_options(options: Any) -> dict[str, Any]:
    """The fields of the options dataclass ``options`` (a world's ``study_flags``) whose
    values differ from their defaults: the options a user gave."""
    given = {}
    for f in fields(options):
        default = f.default_factory() if callable(f.default_factory) else f.default
        if getattr(options, f.name) != default:
            given[f.name] = getattr(options, f.name)
    return given


def study_options(name: str, world: Any, settings: StudySettings,
                  options: Mapping[str, Any]) -> dict[str, Any]:
    """What the study of ``world`` (plug-in ``name``) takes by name (its ``study_options``):
    those of the common settings (:data:`~latent_sindy.study.settings.OPTIONS`) and of
    ``options`` (a user's). UserError naming every option given that it does not take."""
    takes = set(hook(world, "study_options") or ())
    default = StudySettings()
    refused = [flag for key, flag in OPTIONS.items()
               if key not in takes and getattr(settings, key) != getattr(default, key)]
    refused += [f"--{key.replace('_', '-')}" for key in options if key not in takes]
    if refused:
        one = len(refused) == 1
        raise UserError(f"{', '.join(refused)}: the {name} world's study does not take "
                        f"{'this option' if one else 'these options'} (`reproduce --help` says "
                        f"whose {'it is' if one else 'they are'}): drop "
                        f"{'it' if one else 'them'}")
    return {**{key: getattr(settings, key) for key in OPTIONS if key in takes}, **options}


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
    """UserError if ``out`` holds the results of another world's study (its summary.json
    names the world): the study would write its summary.json, report.html and table.md over
    them."""
    path = out / "summary.json"
    try:
        summary = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return  # no summary (yet), or one no study can have written: nothing to keep apart
    if not isinstance(summary, dict):
        return
    held = summary.get("world")
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


def write_world_study(world: Any, settings: Any, say: Say, t_start: float | None = None, *,
                      name: str | None = None, options: Mapping[str, Any] | None = None
                      ) -> tuple[Path, WorldStudy, dict[str, Any]]:
    """The study of the world plug-in ``world`` (its ``reproduce`` hook; ``name``: the
    plug-in's, default ``settings.world``), run in ``settings.out`` (the caller holds the
    folder: :func:`study_folder`) with the settings' ``scale``, ``seeds``, ``device`` and
    ``threads`` and the ``options`` it takes (:func:`study_options`); what it returns (a
    :class:`~latent_sindy.world_study.WorldStudy`) is written as summary.json (with
    ``settings`` whole, a dataclass, and the options), table.md, equations_<name>.txt and
    report.html. Returns (report.html, that study, the summary written)."""
    t_start = time.perf_counter() if t_start is None else t_start
    name = name or settings.world
    options = dict(options or {})
    out = settings.out
    out.mkdir(parents=True, exist_ok=True)
    study = world.reproduce(settings.scale, out, settings.seeds, settings.device,
                            settings.threads, say, **options)
    if not isinstance(study, WorldStudy):
        raise TypeError(f"the {name} world's reproduce returned "
                        f"{type(study).__name__}, not a latent_sindy.world_study.WorldStudy")
    t_study = time.perf_counter() - t_start
    files = []
    for model, text in study.equations.items():
        path = out / f"equations_{model}.txt"
        write_atomic(path, lambda f, t=text: f.write(t if t.endswith("\n") else t + "\n"),
                     binary=False)
        files.append(path.name)
    md = [f"# {study.title}", "", *study.findings]
    for t in study.tables:
        md += ["", f"## {t.heading}", "", *_markdown(t.header, t.rows)]
        md += ["", t.note] if t.note else []
    write_atomic(out / "table.md", lambda f: f.write("\n".join(md) + "\n"), binary=False)
    summary = json_safe({
        "world": name, "scale": settings.scale,
        "config": {**to_json(settings), "options": to_json(options)},
        "study": study.settings, "seeds": list(study.seeds), "results": study.numbers,
        "findings": study.findings, "versions": versions(),
        "machine": {**machine(), **_device()},
        "files": ["table.md", "report.html", *files,
                  *(str(p.relative_to(out)) for p, _ in study.figures)],
        "timings_s": {"study": t_study, "total": time.perf_counter() - t_start}})
    text = json.dumps(summary, indent=1, allow_nan=False)
    write_atomic(out / "summary.json", lambda f: f.write(text), binary=False)
    page = study.report if study.report is not None else _page(study, summary)
    report = page.write(out / "report.html")
    if getattr(settings, "record", None) is not None and study.rows:
        record = study.record_name or _record_name(world, settings, name)
        cuda = _device()["cuda_device"]
        device = "cpu" if cuda is None or getattr(settings, "device", "auto") == "cpu" \
            else f"cuda ({cuda})"
        path = record_rows(settings.record, name, record, study.rows, device=device)
        say(f"recorded {len(study.rows)} row(s) in {path}")
    say(f"report: {report} (this run took {time.perf_counter() - t_start:.0f} s)")
    return report, study, summary


def _page(study: WorldStudy, summary: dict[str, Any]) -> Report:
    """report.html of a world that gives no page of its own: findings, tables, figures,
    equations, then the settings, versions and timings."""
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
    return r


def _record_name(world: Any, settings: Any, name: str) -> str:
    """The result file of a study that does not name it: its scale, the named world it ran
    (where ``--world`` named one), then each world setting given as key=value."""
    given = getattr(world, CONFIG_GIVEN, ())
    named = [settings.world] if settings.world not in (None, name) else []
    return "_".join([settings.scale, *named,
                     *(f"{k}={getattr(world.config, k)}" for k in given)])


def run_study(settings: StudySettings, options: Mapping[str, Any] | None = None,
              world_config: Sequence[str] = (), say: Say | None = None) -> Path:
    """``latent-sindy reproduce``: the study of the world ``settings.world`` names (None: the
    default world; :func:`study_world`, rebuilt on ``world_config``), at its scale, with the
    ``options`` given (name -> value; :func:`study_options`), in ``settings.out``, held for
    it; returns the path of report.html. Everything is checked before the folder is made.
    ``say`` receives the study's lines (default: stderr when ``settings.verbose``)."""
    t_start = time.perf_counter()
    name, world = study_world(settings.world or default_world(), world_config)
    if settings.scale not in world.scales:
        raise UserError(f"--scale {settings.scale}: the {name} world's scales are "
                        f"{', '.join(world.scales)}")
    taken = study_options(name, world, settings, options or {})
    resolve_device(settings.device)  # --device cuda without one: refused before anything runs
    if say is None:
        say = say_stderr if settings.verbose else (lambda _: None)
    with study_folder(settings.out, name):
        return write_world_study(world, settings, say, t_start, name=name, options=taken)[0]
