"""The settings every study of ``latent-sindy reproduce`` takes, whatever its world, and the
seed lists ``--seeds`` reads. A world's own options (the default world's become flags of the
command) are passed beside them by name (:func:`latent_sindy.study.runner.run_study`).

    latent-sindy reproduce --scale demo --out results/demo --seeds 0..2

    from latent_sindy.study.runner import run_study
    from latent_sindy.study.settings import StudySettings
    run_study(StudySettings(world="pendulum", scale="tiny", out=Path("/tmp/pendulum")))

    >>> parse_seeds(["0..2", "5"])
    (0, 1, 2, 5)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import tyro

from latent_sindy.errors import UserError, check_seed

__all__ = ["MAX_SEEDS", "OPTIONS", "Seeds", "StudySettings", "parse_seeds"]

#: The most seeds a study takes (each trains and evaluates every model).
MAX_SEEDS = 1000


def parse_seeds(args: list[str]) -> tuple[int, ...]:
    """Seeds from the command line: ``0 1 2``, ``0,1,2``, ranges ``0..9`` (both ends
    included), or a mix; UserError naming the bad part. A list longer than
    :data:`MAX_SEEDS` is refused from the ranges' sizes, before it is built."""
    ranges: list[range] = []
    for arg in args:
        for part in arg.split(","):
            lo, dots, hi = part.partition("..")
            try:
                ranges.append(range(int(lo), int(hi) + 1) if dots else range(int(part),
                                                                              int(part) + 1))
            except ValueError:
                raise UserError(f"--seeds {part!r}: give integers (0 1 2), a list (0,1,2) or "
                                "a range (0..9)") from None
            if dots and int(hi) < int(lo):
                raise UserError(f"--seeds {part}: a range runs from low to high (e.g. 0..9)")
    total = sum(r.stop - r.start for r in ranges)  # len() overflows past 2**63
    if total > MAX_SEEDS:
        raise UserError(f"--seeds {' '.join(args)}: {total} seeds; a study takes at most "
                        f"{MAX_SEEDS} (each trains and evaluates every model)")
    return tuple(s for r in ranges for s in r)


Seeds = Annotated[tuple[int, ...], tyro.constructors.PrimitiveConstructorSpec(
    nargs="*", metavar="SEED|A..B", instance_from_str=parse_seeds,
    is_instance=lambda v: isinstance(v, tuple), str_from_instance=lambda v: [str(s) for s in v])]


@dataclass(frozen=True)
class StudySettings:
    """What every study of `latent-sindy reproduce` takes: its world, scale, folder, seeds
    and where it computes. ``workers``, ``executor``, ``ray_address`` and ``gpus`` reach the
    studies that run jobs side by side (those their world's ``study_options`` names); the
    others refuse them when given."""

    scale: str = "demo"
    """The study's size: one of its world's scales (`reproduce --help` lists them)."""
    out: Path = Path("results")
    """Folder for everything the study writes (summary.json, table.md, report.html, ...);
    re-runs reuse what is finished there."""
    world: str | None = None
    """The world whose study runs: an installed world with a study of its own, or a named
    world of one; None: the CLI's default world."""
    seeds: Seeds | None = None
    """Training and control seeds; several give mean ± std: 0 1 2, 0,1,2 or a range 0..9.
    Default: the scale's."""
    device: Literal["auto", "cpu", "cuda"] = "auto"
    """Where the models train: cuda when torch sees one (auto), or as named (a study that
    trains on the CPU only refuses cuda)."""
    threads: int = 1
    """torch CPU threads per process."""
    workers: int = 2
    """Jobs the study runs at once (processes; 1: everything in this process); with
    --executor ray and no --ray-address, the CPUs of the Ray started here."""
    executor: Literal["local", "ray"] = "local"
    """Where the jobs run: local (processes on this machine) or ray (Ray tasks; `pip install
    'latent-sindy[ray]'`). Results are the same for the same seeds."""
    ray_address: str | None = None
    """--executor ray: the Ray cluster to join ("auto", HOST:6379); default: start a Ray on
    this machine with --workers CPUs. A cluster of several machines needs --out (and the
    study's data) on a filesystem they share."""
    gpus: float = 0.0
    """--executor ray: GPUs each training job declares (>0 trains on the GPU Ray assigns,
    which is not bit-identical to the CPU)."""
    record: Path | None = None
    """Also write the study's rows (a row per model and seed, with the commit, date, machine,
    device and this command) into RECORD/<world>/<scale>.csv, replacing the rows of the same
    model and seed: the tracked result files RESULTS.md is generated from (`--record
    results`, then `python -m latent_sindy.results_page`)."""
    verbose: tyro.conf.Suppress[bool] = True
    """Print the study's lines to stderr."""

    def __post_init__(self) -> None:
        if self.seeds is not None and (not self.seeds or len(set(self.seeds)) != len(self.seeds)
                                       or min(self.seeds) < 0):
            raise UserError(f"--seeds {list(self.seeds)}: give distinct non-negative seeds")
        for seed in self.seeds or ():
            check_seed(seed, "--seeds")
        if self.seeds is not None and len(self.seeds) > MAX_SEEDS:
            raise UserError(f"--seeds: {len(self.seeds)} seeds; a study takes at most "
                            f"{MAX_SEEDS} (each trains and evaluates every model)")
        if self.workers < 1 or not 1 <= self.threads <= 1024:
            raise UserError(f"--workers {self.workers} and --threads {self.threads}: use 1 or "
                            "more workers and 1 to 1024 threads")
        if not (math.isfinite(self.gpus) and self.gpus >= 0):
            raise UserError(f"--gpus {self.gpus}: use a number >= 0 (GPUs per training job)")
        if self.gpus > 0 and self.executor != "ray":
            raise UserError(f"--gpus {self.gpus} is for --executor ray (it reserves GPUs per "
                            "job); the local executor trains on the CPU: drop --gpus")
        if self.ray_address is not None and self.executor != "ray":
            raise UserError(f"--ray-address {self.ray_address} is for --executor ray (the Ray "
                            "cluster to join); the local executor runs on this machine: add "
                            "--executor ray or drop --ray-address")


#: The settings above that reach a study as options (by name), with their flags: a world
#: whose ``study_options`` does not name one refuses it when it is given.
OPTIONS = {"workers": "--workers", "executor": "--executor", "ray_address": "--ray-address",
           "gpus": "--gpus"}
