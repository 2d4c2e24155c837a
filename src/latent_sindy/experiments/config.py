"""The settings of ``latent-sindy reproduce`` and the plan they resolve to.

:class:`ReproduceConfig` is the command's typed settings (its field docstrings are the
``--help``); :class:`StudyPlan` is what a config resolves to before anything runs: the
models (:func:`.catalogue.study_specs`) and each (seed, model)'s run folder.

    latent-sindy reproduce --scale demo --out results --seeds 0..2

    from latent_sindy.experiments.config import ReproduceConfig, StudyPlan
    plan = StudyPlan.of(ReproduceConfig(scale="tiny", out=Path("results")))
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import tyro

from latent_sindy.errors import UserError
from latent_sindy.experiments.catalogue import SINGLE_STEP, ModelSpec, study_specs
from latent_sindy.experiments.scales import SCALES, Scale
from latent_sindy.experiments.sweeps import MAX_SEEDS, Seeds, Sweeps, check_windows, sweep_help
from latent_sindy.worlds.push.config import PushEnvConfig

__all__ = ["ReproduceConfig", "StudyPlan"]


@dataclass(frozen=True)
class ReproduceConfig:
    """Settings of `latent-sindy reproduce`."""

    scale: Literal["demo", "large", "paper", "tiny", "round-one"] = "demo"
    """demo: the whole study in under 10 minutes on 2 cores; round-one: the demo's first,
    twice longer schedule (60 epochs, 50 random tasks per headline row); large: ten times the
    paper's data on the round-one schedule; paper: the paper's sizes (many hours on a CPU);
    tiny: seconds, for tests."""
    out: Path = Path("results")
    """Folder for everything (data, runs, tables, figures, report.html); re-runs reuse it."""
    seeds: Seeds = (0,)
    """Training and control seeds; several give mean ± std: 0 1 2, 0,1,2 or a range 0..9."""
    data: Path | None = None
    """Trajectory file to use (default OUT/data.h5, collected for the scale if missing)."""
    data_seed: int = 0
    """Seed of the data collection (the same data serve every training seed)."""
    world: Literal["symmetric", "paper", "marked"] = "symmetric"
    """The pushing world (envs.config.ENV_PRESETS): "symmetric" (pushes in any direction, the
    default), "paper" (the course's world: reproduces Table I as the paper defined it) or
    "marked" (the paper's push on a block with a visible mark)."""
    decoder: Literal["conv", "fc"] = "conv"
    """Decoder of every model: "conv" (transposed convolutions; generalises better) or "fc"
    (the course's fully connected one)."""
    image_size: int | None = None
    """Side in pixels of the images the study collects (default: the world's, 32); a given
    or reused trajectory file must have it. 64 shows the block's pose about twice as
    sharply, and the image models train about four times longer per epoch."""
    workers: int = 2
    """Processes for collection, training and control (1: everything in this process); with
    --executor ray and no --ray-address, the CPUs of the Ray started here."""
    threads: int = 1
    """torch CPU threads per process."""
    models: tuple[str, ...] = ()
    """Train only these of the study's models (default: all), e.g. sindy2 linear."""
    # Its --help is sweeps.sweep_help(), made from the registry of sweepable settings.
    sweep: Annotated[Sweeps, tyro.conf.arg(help=sweep_help())] = ()
    executor: Literal["local", "ray"] = "local"
    """Where jobs run: local (processes on this machine) or ray (Ray tasks; `pip install
    'latent-sindy[ray]'`). Results are the same for the same seeds."""
    ray_address: str | None = None
    """--executor ray: the Ray cluster to join ("auto", HOST:6379); default: start a Ray on
    this machine with --workers CPUs. A cluster of several machines needs --out (and --data)
    on a filesystem they share."""
    gpus: float = 0.0
    """--executor ray: GPUs each training job declares (>0 trains on the GPU Ray assigns,
    which is not bit-identical to the CPU)."""
    verbose: tyro.conf.Suppress[bool] = True
    """Print stage lines and training milestones to stderr."""

    def __post_init__(self) -> None:
        if self.scale not in SCALES:
            raise UserError(f"--scale {self.scale}: use one of {', '.join(SCALES)}")
        if not self.seeds or len(set(self.seeds)) != len(self.seeds) or min(self.seeds) < 0:
            raise UserError(f"--seeds {list(self.seeds)}: give distinct non-negative seeds")
        if len(self.seeds) > MAX_SEEDS:
            raise UserError(f"--seeds: {len(self.seeds)} seeds; a study takes at most "
                            f"{MAX_SEEDS} (each trains and evaluates every model)")
        if self.workers < 1 or not 1 <= self.threads <= 1024:
            raise UserError(f"--workers {self.workers} and --threads {self.threads}: use 1 or "
                            "more workers and 1 to 1024 threads")
        if self.data_seed < 0:
            raise UserError(f"--data-seed {self.data_seed}: seeds are non-negative integers")
        if self.image_size is not None:
            self.env_config()  # checks the size
        if not (math.isfinite(self.gpus) and self.gpus >= 0):
            raise UserError(f"--gpus {self.gpus}: use a number >= 0 (GPUs per training job)")
        if self.gpus > 0 and self.executor != "ray":
            raise UserError(f"--gpus {self.gpus} is for --executor ray (it reserves GPUs per "
                            "job); the local executor trains on the CPU: drop --gpus")
        if self.ray_address is not None and self.executor != "ray":
            raise UserError(f"--ray-address {self.ray_address} is for --executor ray (the Ray "
                            "cluster to join); the local executor runs on this machine: add "
                            "--executor ray or drop --ray-address")
        study_specs(self)  # unknown models, a sweep that changes none of them or a bad value
        if self.data is None or not self.data.exists():  # collected for the scale
            check_windows(self.sweep, self.preset.steps,
                          f"the trajectories --scale {self.scale} collects")

    @property
    def preset(self) -> Scale:
        return SCALES[self.scale]

    @property
    def data_path(self) -> Path:
        return self.data if self.data is not None else self.out / "data.h5"

    def env_config(self) -> PushEnvConfig:
        """The world the study collects its data in: ``world``, at ``image_size``."""
        world = PushEnvConfig.named(self.world)
        if self.image_size is None:
            return world
        return dataclasses.replace(world, image_size=self.image_size)


@dataclass(frozen=True)
class StudyPlan:
    """What a study will do, known before anything runs: its settings, its models and the
    run folder of each (seed, model)."""

    config: ReproduceConfig
    specs: tuple[ModelSpec, ...]
    runs: dict[int, dict[str, Path]]
    """Seed -> model name -> run folder."""

    @staticmethod
    def of(config: ReproduceConfig) -> StudyPlan:
        """The plan of ``config``: its models, each trained in OUT/runs/seed<S>/<model>."""
        specs = study_specs(config)
        runs = {s: {m.name: config.out / "runs" / f"seed{s}" / m.name for m in specs}
                for s in config.seeds}
        return StudyPlan(config, specs, runs)

    @property
    def scale(self) -> Scale:
        return self.config.preset

    @property
    def models(self) -> list[str]:
        return [s.name for s in self.specs]

    @property
    def labels(self) -> dict[str, str]:
        return {s.name: s.label for s in self.specs}

    def spec(self, name: str) -> ModelSpec | None:
        return next((s for s in self.specs if s.name == name), None)

    @property
    def single_step(self) -> ModelSpec | None:
        """The single-step SINDy-2 the multi-step model is compared with."""
        return self.spec(SINGLE_STEP)

    @property
    def multistep(self) -> ModelSpec | None:
        """The SINDy model trained on multi-step windows."""
        return next((s for s in self.specs if s.window > 1), None)
