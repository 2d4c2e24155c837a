"""The settings of ``latent-sindy reproduce`` and the plan they resolve to.

:class:`ReproduceConfig` is the command's typed settings (its field docstrings are the
``--help``); :class:`StudyPlan` is what a config resolves to before anything runs: the
models (:func:`study_specs`) and each (seed, model)'s run folder.

``--world`` names a pushing world (``ENV_PRESETS``: the push study) or a world plug-in
(entry points ``latent_sindy.worlds``) that has a study of its own: an object with ``about``,
``scales`` (name -> what it runs) and ``reproduce(scale, out, seeds, device, threads, say)``.
This module knows those plug-ins only through that interface.

    latent-sindy reproduce --scale demo --out results --seeds 0..2

    from latent_sindy.worlds.push.study.config import ReproduceConfig, StudyPlan
    plan = StudyPlan.of(ReproduceConfig(scale="tiny", out=Path("results")))
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import tyro

from latent_sindy.errors import UserError, check_seed
from latent_sindy.plugins import hook
from latent_sindy.study.runner import study_worlds
from latent_sindy.training.config import resolve_device
from latent_sindy.worlds.push.config import ENV_PRESETS, WORLD_ABOUT, PushEnvConfig
from latent_sindy.worlds.push.study.catalogue import model_specs
from latent_sindy.worlds.push.study.scales import SCALES, Scale
from latent_sindy.worlds.push.study.spec import SINGLE_STEP, ModelSpec
from latent_sindy.worlds.push.study.sweeps import (
    MAX_SEEDS,
    Seeds,
    Sweeps,
    check_windows,
    sweep_help,
    sweepable,
)

__all__ = ["ReproduceConfig", "StudyPlan", "study_specs"]


def _world_help() -> str:
    studies = "; ".join(f"{name}: {hook(w, 'about') or 'its own study'}"
                        for name, w in study_worlds().items())
    push = "; ".join(f"{name} ({WORLD_ABOUT.get(name, 'a pushing world')})"
                     for name in ENV_PRESETS)
    return ("The world. A pushing world (the push study of models, control and Table I; "
            f"symmetric is the default): {push}. Or a world with a study of its own, written "
            f"into the same report format: {studies or '(none installed)'}.")


def _scale_help() -> str:
    push = ("Push worlds: demo (the whole study in under 10 minutes on 2 cores); demo-long "
            "(the demo's first, twice longer schedule: 60 epochs, 50 random tasks per "
            "headline row); large (ten times the paper's data on the demo-long schedule); "
            "paper (the paper's sizes, many hours on a CPU); tiny (seconds, for tests).")
    others = " ".join(f"{name}: " + "; ".join(f"{s} ({what})" for s, what in w.scales.items())
                      + "." for name, w in study_worlds().items())
    return f"The study's size. {push} {others}".strip()


#: Settings only the push study reads: refused with a world of another study, unless that
#: world's ``study_options`` hook names them.
PUSH_ONLY = {"data": "--data", "data_seed": "--data-seed", "decoder": "--decoder",
             "image_size": "--image-size", "workers": "--workers", "models": "--models",
             "sweep": "--sweep", "executor": "--executor", "ray_address": "--ray-address",
             "gpus": "--gpus"}


@dataclass(frozen=True)
class ReproduceConfig:
    """Settings of `latent-sindy reproduce`."""

    scale: Annotated[str, tyro.conf.arg(help=_scale_help(), metavar="SCALE")] = "demo"
    out: Path = Path("results")
    """Folder for everything (data, runs, tables, figures, report.html); re-runs reuse it."""
    record: Path | None = None
    """Also write the study's rows (a row per model and seed, with the commit, date, machine,
    device and this command) into RECORD/<world>/<scale>.csv, replacing the rows of the same
    model and seed: the tracked result files RESULTS.md is generated from (`--record
    results`, then `python -m latent_sindy.results_page`)."""
    seeds: Seeds | None = None
    """Training and control seeds; several give mean ± std: 0 1 2, 0,1,2 or a range 0..9.
    Default: the scale's (the push study: 0; a world with a study of its own: as its
    --scale says)."""
    data: Path | None = None
    """Trajectory file to use (default OUT/data.h5, collected for the scale if missing)."""
    data_seed: int = 0
    """Seed of the data collection (the same data serve every training seed)."""
    world: Annotated[str, tyro.conf.arg(help=_world_help(), metavar="WORLD")] = "symmetric"
    device: Literal["auto", "cpu", "cuda"] = "auto"
    """Where a world study's models train (pendulum, pendulum-video): cuda when torch sees
    one (auto), or as named. The push study trains on the CPU (on Ray, see --gpus)."""
    decoder: Literal["conv", "fc"] = "conv"
    """Decoder of every model: "conv" (transposed convolutions; generalises better) or "fc"
    (the course's fully connected one)."""
    image_size: int | None = None
    """Side in pixels of the images the study collects (default: the world's, 32); a given
    or reused trajectory file must have it. 64 shows the block's pose about twice as
    sharply, and the image models train about four times longer per epoch."""
    workers: int = 2
    """Processes for collection, training and control (1: everything in this process); with
    --executor ray and no --ray-address, the CPUs of the Ray started here. --world dmc: its
    (seed, model) loops run at a time."""
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
        if self.seeds is not None and (not self.seeds or len(set(self.seeds)) != len(self.seeds)
                                       or min(self.seeds) < 0):
            raise UserError(f"--seeds {list(self.seeds)}: give distinct non-negative seeds")
        for seed in self.seeds or ():
            check_seed(seed, "--seeds")
        if self.world not in ENV_PRESETS:
            self._check_world_study()
            return
        if self.seeds is None:  # the push study's default; resolved here, once, at construction
            object.__setattr__(self, "seeds", (0,))
        if self.scale not in SCALES:
            raise UserError(f"--scale {self.scale}: the push worlds' scales are "
                            f"{', '.join(SCALES)}")
        if self.device == "cuda":
            raise UserError(f"--device cuda is for a world with a study of its own (--world "
                            f"{' or '.join(study_worlds()) or '...'}); the push study trains "
                            "on the CPU (on Ray: --executor ray --gpus N): drop --device")
        if len(self.seeds) > MAX_SEEDS:
            raise UserError(f"--seeds: {len(self.seeds)} seeds; a study takes at most "
                            f"{MAX_SEEDS} (each trains and evaluates every model)")
        if self.workers < 1 or not 1 <= self.threads <= 1024:
            raise UserError(f"--workers {self.workers} and --threads {self.threads}: use 1 or "
                            "more workers and 1 to 1024 threads")
        check_seed(self.data_seed, "--data-seed")
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

    def _check_world_study(self) -> None:
        """UserError unless ``world`` names a plug-in with a study that has ``scale``, and
        no setting of the push study alone is given."""
        studies = study_worlds()
        if self.world not in studies:
            raise UserError(f"--world {self.world}: use a pushing world ({', '.join(ENV_PRESETS)})"
                            f" or a world with a study of its own ({', '.join(studies)})")
        scales = studies[self.world].scales
        if self.scale not in scales:
            raise UserError(f"--scale {self.scale}: the {self.world} world's scales are "
                            f"{', '.join(scales)}")
        default = ReproduceConfig.__dataclass_fields__
        takes = hook(studies[self.world], "study_options") or ()
        given = [flag for name, flag in PUSH_ONLY.items()
                 if name not in takes and getattr(self, name) != default[name].default]
        if given:
            raise UserError(f"{', '.join(given)} {'is' if len(given) == 1 else 'are'} for the "
                            f"push study; --world {self.world} runs its own study: drop "
                            f"{'it' if len(given) == 1 else 'them'}")
        if not 1 <= self.threads <= 1024:
            raise UserError(f"--threads {self.threads}: use 1 to 1024 threads")
        resolve_device(self.device)  # --device cuda without one: refused before anything runs

    @property
    def study_world(self) -> Any | None:
        """The plug-in whose study ``world`` names; None for a pushing world."""
        return None if self.world in ENV_PRESETS else study_worlds()[self.world]

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


def study_specs(config: ReproduceConfig) -> tuple[ModelSpec, ...]:
    """The models of a study: :func:`model_specs`, those of ``--models``, and for each model
    one variant per combination of the ``--sweep`` values that apply to it."""
    world = PushEnvConfig.named(config.world)
    specs = model_specs(config.preset, config.decoder, world.angle_period, world.push)
    names = [s.name for s in specs]
    unknown = [m for m in config.models if m not in names]
    if unknown or len(set(config.models)) != len(config.models):
        raise UserError(f"--models {' '.join(config.models)}: give distinct names among "
                        f"{', '.join(names)}")
    if config.models:
        specs = tuple(s for s in specs if s.name in config.models)
    out: list[ModelSpec] = []
    for sweep in config.sweep:
        setting = sweepable(sweep.setting)
        if not any(setting.applies(s) for s in specs):
            raise UserError(f"{sweep.text}: none of the chosen models "
                            f"({', '.join(s.name for s in specs)}) has this setting; "
                            f"{sweep.setting} is a setting of {setting.models}: choose such "
                            "models with --models")
    for spec in specs:
        sweeps = [sw for sw in config.sweep if sweepable(sw.setting).applies(spec)]
        for combo in itertools.product(*(sw.variants() for sw in sweeps)):
            variant = spec
            for sw, (name, value) in zip(sweeps, combo, strict=True):
                try:
                    variant = sweepable(sw.setting).apply(variant, value)
                except UserError as e:  # a value this model does not take: name both
                    raise UserError(f"--sweep {name}: model {spec.name}: {e}; leave it out "
                                    "with --models") from None
            if combo:
                suffix = ".".join(name for name, _ in combo)
                label = ", ".join(f"{sweepable(sw.setting).label}={v:g}"
                                  for sw, (_, v) in zip(sweeps, combo, strict=True))
                variant = dataclasses.replace(variant, name=f"{spec.name}.{suffix}",
                                              label=f"{spec.label}, {label}")
            out.append(variant)
    return tuple(out)
