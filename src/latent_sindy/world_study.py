"""What a world's own study hands to ``latent-sindy reproduce``: its tables, figures,
equations and every number, which the command writes in the common format (summary.json,
table.md, report.html, equations_*.txt). It knows no world: a world plug-in's ``reproduce``
hook (:data:`latent_sindy.plugins.HOOKS`) returns one.

    study = WorldStudy(title="...", settings={...}, seeds=[0], numbers={...},
                       findings=["..."], tables=[Table("heading", ["a", "b"], [["1", "2"]])])
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["Table", "WorldStudy"]


@dataclass
class Table:
    """One table of the report: a heading, its header and rows (cells as shown)."""

    heading: str
    header: list[str]
    rows: list[list[str]]
    note: str = ""


@dataclass
class WorldStudy:
    """What a world's study hands to ``reproduce``: written there in the common format."""

    title: str
    settings: dict[str, Any]
    """The study's own settings (JSON values)."""
    seeds: list[int]
    numbers: dict[str, Any]
    """Every number of the study (JSON values; NaN allowed, made null on writing)."""
    findings: list[str]
    tables: list[Table]
    figures: list[tuple[Path, str]] = field(default_factory=list)
    """PNGs already written inside the study's folder, with captions."""
    equations: dict[str, str] = field(default_factory=dict)
    """Name -> text, written as equations_<name>.txt."""
    rows: list[dict[str, Any]] = field(default_factory=list)
    """One per model and seed (``model``, ``seed``, then its figures): what ``reproduce
    --record`` writes into the tracked result files (:mod:`latent_sindy.result_files`)."""
    record_name: str | None = None
    """The name of those rows' file (RECORD/<world>/<name>.csv) where the study names it;
    None: its scale, then each world setting given as key=value."""
    report: Any = None
    """The world's own page, not yet written (an object with ``write(path) -> path``, e.g. a
    :class:`latent_sindy.study.report.Report`): written as report.html in place of the page
    made of the findings, tables, figures and equations above."""
