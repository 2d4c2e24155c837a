"""The push study as `latent-sindy reproduce` runs it, for the tests: through its one entry,
the push world's ``reproduce`` hook, called by :func:`latent_sindy.study.runner.run_study`."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

from latent_sindy.study.runner import run_study
from latent_sindy.study.settings import StudySettings

COMMON = {f.name for f in dataclasses.fields(StudySettings)}


def run_push(out: Path, say: Callable[[str], None] | None = None, **settings: Any) -> Path:
    """report.html of the push study in ``out``: ``settings`` every study takes (scale,
    seeds, workers, world, ...) and the push study's own options (data, models, sweep, ...),
    its lines to ``say`` (default: none)."""
    common = {k: v for k, v in settings.items() if k in COMMON}
    options = {k: v for k, v in settings.items() if k not in COMMON}
    return run_study(StudySettings(out=out, **common), options,
                     say=say or (lambda _: None))
