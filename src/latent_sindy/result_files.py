"""The tracked result files: one CSV per world and benchmark, ``results/<world>/<benchmark>.csv``,
one row per model and seed (and, where one model and seed were measured on several cases, a
``case``), each row with the commit, date, machine, device and command that produced it.
RESULTS.md is generated from these files (:mod:`latent_sindy.results_page`). The module knows
no world: what a world's figures mean (its published baselines, whether a model's latent is
learned or read by a hand-made reader, its known limits) is data in ``results/<world>/world.json``.

    rows = [{"model": "sindy", "seed": 0, "return": 808.5, "active_terms": 37}]
    record_rows(Path("results"), "dmc", "read-100k", rows,
                command="latent-sindy reproduce --world dmc --scale read-100k --seeds 0")
    read_rows(Path("results/dmc/read-100k.csv"))   # the rows, figures parsed back

A study records its rows with ``latent-sindy reproduce ... --record results``; a benchmark
script calls :func:`record_rows` the same way.
"""

from __future__ import annotations

import csv
import datetime
import io
import math
import os
import platform
import re
import shlex
import subprocess
import sys
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from latent_sindy.atomic import write_atomic
from latent_sindy.errors import UserError

__all__ = ["KEY", "PROVENANCE", "command_line", "provenance", "read_rows", "record_rows",
           "result_path", "write_rows"]

KEY = ("model", "seed", "case")
"""The columns that name a row: a study's new row replaces the old row of the same key."""

PROVENANCE = ("commit", "date", "machine", "device", "command", "source")
"""Where a row's figures come from; the other columns are its figures."""

_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._=,+-]*$")


def result_path(root: Path, world: str, benchmark: str) -> Path:
    """``root/world/benchmark.csv``; UserError for a name that is not a plain file name."""
    for what, name in (("world", world), ("benchmark", benchmark)):
        if not _NAME.match(name):
            raise UserError(f"result files: the {what} name {name!r} is not a plain file name "
                            "(letters, digits and . _ = , + - only)")
    return Path(root) / world / f"{benchmark}.csv"


def _cell(value: Any) -> str:
    if hasattr(value, "item") and not isinstance(value, str | bytes):
        value = value.item()  # a NumPy or torch scalar as the Python number it holds
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "" if math.isnan(value) else repr(value)
    return str(value)


def _parse(text: str) -> Any:
    """A figure's cell back to its value: empty is None, true/false bools, numbers numbers,
    anything else the text itself."""
    if text == "":
        return None
    if text in ("true", "false"):
        return text == "true"
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text


def _key(row: Mapping[str, Any]) -> tuple[str, ...]:
    return tuple(_cell(row.get(k)) for k in KEY)


def read_rows(path: Path) -> list[dict[str, Any]]:
    """The rows of one result file, in its order: the key and provenance columns as text
    (a seed that is a number as an int), every other column parsed (None where empty).
    An absent file has no rows."""
    path = Path(path)
    if not path.exists():
        return []
    with path.open(newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        if reader.fieldnames is None or "model" not in reader.fieldnames:
            raise UserError(f"{path}: not a result file (its first line names no 'model' "
                            "column); result files are written by latent_sindy.result_files")
        rows = []
        for raw in reader:
            row: dict[str, Any] = {}
            for name, text in raw.items():
                text = text or ""
                if name in KEY or name in PROVENANCE:
                    row[name] = int(text) if name == "seed" and text.isdigit() else text
                else:
                    row[name] = _parse(text)
            rows.append(row)
    return rows


def write_rows(path: Path, rows: Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Merge ``rows`` into the result file ``path``: a row whose model, seed and case equal an
    existing row's replaces it in place, the others are appended. Columns: the key, then the
    provenance, then the figures in the order they first appear. Returns the file's rows."""
    path = Path(path)
    old = read_rows(path)
    index = {_key(r): i for i, r in enumerate(old)}
    merged = [dict(r) for r in old]
    for row in rows:
        if not _cell(row.get("model")):
            raise UserError(f"{path}: a result row needs a model, got {dict(row)!r}")
        k = _key(row)
        if k in index:
            merged[index[k]] = dict(row)
        else:
            index[k] = len(merged)
            merged.append(dict(row))
    figures: list[str] = []
    for row in merged:
        figures += [c for c in row if c not in KEY and c not in PROVENANCE and c not in figures]
    columns = [*KEY, *PROVENANCE, *figures]
    buf = io.StringIO()
    writer = csv.DictWriter(buf, columns, lineterminator="\n")
    writer.writeheader()
    for row in merged:
        writer.writerow({c: _cell(row.get(c)) for c in columns})
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, lambda f: f.write(buf.getvalue()), binary=False)
    return merged


def _git(*args: str) -> str:
    try:
        done = subprocess.run(["git", *args], cwd=Path(__file__).parent, capture_output=True,
                              text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return ""
    return done.stdout.strip() if done.returncode == 0 else ""


def _machine() -> str:
    cpu = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        cpu = platform.processor()
    return f"{os.cpu_count()} cores{f' ({cpu})' if cpu else ''}, {platform.system()}"


def _device() -> str:
    try:
        import torch
    except ImportError:
        return "cpu"
    if torch.cuda.is_available():
        return f"cuda ({torch.cuda.get_device_name(0)})"
    return "cpu"


def command_line(argv: Sequence[str] | None = None) -> str:
    """The command this process runs, as a user would type it (``latent-sindy ...`` for the
    CLI however it was started)."""
    args = list(sys.argv if argv is None else argv)
    if not args:
        return ""
    first = Path(args[0]).name
    if first in ("cli.py", "latent-sindy", "__main__.py"):
        first = "latent-sindy"
    return shlex.join([first, *args[1:]])


def provenance(command: str, device: str | None = None) -> dict[str, str]:
    """This run's commit (short; ``+dirty`` when the work tree has changes), today's date
    (UTC), the machine, the device (``cpu`` or the CUDA device's name) and ``command``."""
    commit = _git("rev-parse", "--short", "HEAD")
    if commit and _git("status", "--porcelain", "--untracked-files=no"):
        commit += "+dirty"
    return {"commit": commit, "date": datetime.datetime.now(datetime.UTC).date().isoformat(),
            "machine": _machine(), "device": device or _device(), "command": command,
            "source": "measured"}


def record_rows(root: Path, world: str, benchmark: str, rows: Iterable[Mapping[str, Any]],
                command: str | None = None, device: str | None = None) -> Path:
    """Write ``rows`` (one per model and seed: ``model``, ``seed``, optionally ``case``, then
    the figures) into ``root/world/benchmark.csv`` with this run's provenance
    (:func:`provenance`; ``command`` defaults to this process's :func:`command_line`),
    replacing the rows of the same model, seed and case. Returns the file's path."""
    path = result_path(root, world, benchmark)
    stamp = provenance(command_line() if command is None else command, device)
    write_rows(path, [{**{k: r.get(k) for k in KEY}, **stamp,
                       **{k: v for k, v in r.items() if k not in KEY}} for r in rows])
    return path
