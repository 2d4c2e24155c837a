"""The push study's settings and the plan they resolve to.

:class:`PushStudyOptions` is what the push study takes beyond the settings every study does
(the push world's ``study_flags``: flags of ``latent-sindy reproduce``, the field docstrings
its ``--help``); :class:`PushStudyConfig` is one study's settings, checked, as the push
world's ``reproduce`` hook builds them; :class:`StudyPlan` is what a config resolves to
before anything runs: the models (:func:`study_specs`) and each (seed, model)'s run folder.

    latent-sindy reproduce --scale demo --out results --seeds 0..2 --models sindy2 linear

    from latent_sindy.worlds.push.study.config import PushStudyConfig, StudyPlan
    plan = StudyPlan.of(PushStudyConfig(scale="tiny", out=Path("results")))
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import tyro

from latent_sindy.errors import UserError, check_seed
from latent_sindy.worlds.push.config import ENV_PRESETS, PushEnvConfig
from latent_sindy.worlds.push.study.catalogue import model_specs
from latent_sindy.worlds.push.study.scales import SCALES, Scale
from latent_sindy.worlds.push.study.spec import SINGLE_STEP, ModelSpec
from latent_sindy.worlds.push.study.sweeps import Sweeps, check_windows, sweep_help, sweepable

__all__ = ["PushStudyConfig", "PushStudyOptions", "StudyPlan", "study_specs"]


@dataclass(frozen=True)
class PushStudyOptions:
    """The push study's own options (flags of `latent-sindy reproduce` while push is the
    default world)."""

    data: Path | None = None
    """Trajectory file to use (default OUT/data.h5, collected for the scale if missing)."""
    data_seed: int = 0
    """Seed of the data collection (the same data serve every training seed)."""
    decoder: Literal["conv", "fc"] = "conv"
    """Decoder of every model: "conv" (transposed convolutions; generalises better) or "fc"
    (the course's fully connected one)."""
    image_size: int | None = None
    """Side in pixels of the images the study collects (default: the world's, 32); a given
    or reused trajectory file must have it. 64 shows the block's pose about twice as
    sharply, and the image models train about four times longer per epoch."""
    models: tuple[str, ...] = ()
    """Train only these of the study's models (default: all), e.g. sindy2 linear."""
    # Its --help is sweeps.sweep_help(), made from the registry of sweepable settings.
    sweep: Annotated[Sweeps, tyro.conf.arg(help=sweep_help())] = ()

    def __post_init__(self) -> None:
        check_seed(self.data_seed, "--data-seed")
        if self.image_size is not None:
            PushEnvConfig(image_size=self.image_size)  # checks the size


@dataclass(frozen=True)
class PushStudyConfig(PushStudyOptions):
    """One push study's settings, checked: its scale, folder, seeds, named world (of
    :data:`~latent_sindy.worlds.push.config.ENV_PRESETS`) and where its jobs run, with the
    options above."""

    scale: str = "demo"
    out: Path = Path("results")
    seeds: tuple[int, ...] = (0,)
    world: str = "symmetric"
    """The named pushing world the study collects its data in and plays."""
    workers: int = 2
    """Processes for collection, training and control (1: everything in this process)."""
    threads: int = 1
    """torch CPU threads per process."""
    executor: Literal["local", "ray"] = "local"
    ray_address: str | None = None
    gpus: float = 0.0
    """Ray: GPUs each training job declares."""
    verbose: bool = True
    """Show the collection's progress bar and the training milestones (stderr)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.scale not in SCALES:
            raise UserError(f"--scale {self.scale}: the push world's scales are "
                            f"{', '.join(SCALES)}")
        if self.world not in ENV_PRESETS:
            raise UserError(f"world {self.world!r}: the push study runs a named world: "
                            f"{', '.join(ENV_PRESETS)}")
        if not self.seeds:
            raise UserError("--seeds: give at least one seed")
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

    config: PushStudyConfig
    specs: tuple[ModelSpec, ...]
    runs: dict[int, dict[str, Path]]
    """Seed -> model name -> run folder."""

    @staticmethod
    def of(config: PushStudyConfig) -> StudyPlan:
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


def study_specs(config: PushStudyConfig) -> tuple[ModelSpec, ...]:
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
