"""The `latent-sindy` command: a thin layer that parses typed settings and calls the library.

    latent-sindy collect --out data/push.h5 --trajectories 200 --workers 2 --seed 0
    latent-sindy info data/push.h5
    latent-sindy preview data/push.h5 --out data/push.png
    latent-sindy train sindy --order 2 --window 1 --data data/push.h5 --out runs/sindy2
    latent-sindy train linear --data data/push.h5 --out runs/linear
    latent-sindy equations runs/sindy2
    latent-sindy control runs/sindy2 --task paper --episodes 1
    latent-sindy reproduce --scale demo --out results/demo

Mistakes a user can fix (a missing file, an impossible setting) end with one line on
stderr and exit status 2; set LATENT_SINDY_DEBUG=1 to see the traceback.
"""

from __future__ import annotations

import os

# Read once, when torch loads libgomp, hence before any import below: OpenMP threads waiting
# at the end of a parallel region sleep instead of spinning on a core. While other jobs held
# both cores, spinning made 2 training threads 2x slower than 1, sleeping 1.2x slower at worst
# (BENCHMARKS.md); the arithmetic is unchanged. A value in the environment wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Annotated

import tyro

from latent_sindy.atomic import check_output_dir, check_output_file
from latent_sindy.control.mppi import MPPIConfig
from latent_sindy.errors import CarriedUserError, UserError, carried_through_parsers
from latent_sindy.models.autoencoder_flags import CLI_REGISTRY
from latent_sindy.plugins import default_world, get_world, hook
from latent_sindy.progress import bar
from latent_sindy.study.commands import configured_world
from latent_sindy.study.runner import given_options, scale_help, world_help
from latent_sindy.study.settings import StudySettings
from latent_sindy.training.config import TrainConfig

Flat = tyro.conf.OmitArgPrefixes


@dataclass(frozen=True)
class SequencePlan:
    """What collect takes of any world: the flags collect keeps where no installed world
    gives its own (no default world)."""

    trajectories: int = 200
    """Sequences to collect."""
    steps: int = 10
    """Actions per sequence."""
    seed: int = 0
    """Seed of every random choice."""


@dataclass(frozen=True)
class ClosedLoop:
    """What control takes of any world's run: the flags control keeps where no installed
    world gives its own (no default world)."""

    episodes: int = 10
    max_steps: int = 20
    seed: int = 0
    space: str = "latent"
    """latent or image."""
    mppi: MPPIConfig = field(default_factory=MPPIConfig)


@dataclass(frozen=True)
class NoOptions:
    """No study options of a default world (none is installed)."""


try:
    DEFAULT_WORLD: str | None = default_world()
    """The world plug-in whose settings collect and control take as flags, and whose study
    reproduce runs without --world (its ``commands`` and ``study_flags`` hooks): the one the
    installed plug-ins name (:func:`~latent_sindy.plugins.default_world`); the commands reach
    other worlds through the generic hooks. None where no installed world has commands: the
    commands that need one say so when run."""
    NO_DEFAULT_WORLD = ""
except UserError as e:
    DEFAULT_WORLD = None
    NO_DEFAULT_WORLD = str(e)
DEFAULT = None if DEFAULT_WORLD is None else get_world(DEFAULT_WORLD)
COMMAND_OF = {} if DEFAULT is None else hook(DEFAULT, "commands")
CollectSettings = COMMAND_OF["collect"].settings if COMMAND_OF else SequencePlan
ControlSettings = COMMAND_OF["control"].settings if COMMAND_OF else ClosedLoop
WorldOptions = (hook(DEFAULT, "study_flags") if DEFAULT is not None else None) or NoOptions
DATA = Path(f"data/{DEFAULT_WORLD or 'sequences'}.h5")
"""The data file collect writes and train reads by default."""


def _default_command(name: str):
    """The default world's ``name`` command; the one-line reason where there is none."""
    if name not in COMMAND_OF:
        raise UserError(NO_DEFAULT_WORLD or f"the {DEFAULT_WORLD} world has no {name} command")
    return COMMAND_OF[name]


#: The control settings every world's closed loop takes (the rest are the default world's).
GENERIC = ("episodes", "max_steps", "seed", "space", "mppi")


def _cores() -> int:
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # (no affinity on this platform)
        return os.cpu_count() or 1


def _check_threads(n: int, auto: bool) -> None:
    """UserError unless ``n`` is a usable torch thread count: 1 to the cores this process may
    run on (more only compete for them), or 0 for one per core if ``auto``."""
    cores = _cores()
    if not (0 if auto else 1) <= n <= cores:
        raise UserError(f"--threads {n}: this process may run on {cores} core(s): use 1 to "
                        f"{cores}" + (", or 0 for one per core" if auto else ""))


def _bar(desc: str, unit: str):
    def wrap(iterable, total: int, initial: int = 0):
        return bar(iterable, total, initial, desc=desc, unit=unit)

    return wrap


@dataclass
class Collect:
    """Collect the default world's random-action trajectories into an HDF5 file (resumable:
    re-run to finish); with --world, random-action sequences of any world that collects (its
    collect hook)."""

    world: str | None = DEFAULT_WORLD
    """The world to collect from: the default world (the options below), or another installed
    world with a collect hook (e.g. pendulum), which takes --trajectories, --steps and --seed
    only."""
    world_config: tuple[str, ...] = ()
    """KEY=VALUE settings of a --world other than the default world (fields of its config
    dataclass, the others at their defaults), e.g. `image_size=32` for pendulum or
    `task=reacher-easy size=32` for dmc."""
    out: Path = DATA
    """Trajectory file to write (.h5). An interrupted run keeps its progress in OUT.partial/."""
    plan: Annotated[CollectSettings, tyro.conf.arg(name=""), Flat] = field(
        default_factory=CollectSettings)
    workers: int = 2
    """Worker processes simulating in parallel (1 runs in this process); more than
    --trajectories is cut to one a trajectory, with a note."""
    progress: bool = True
    """Show a progress bar."""

    def run(self) -> None:
        if self.world is not None and self.world != DEFAULT_WORLD:
            self._collect_world()
            return
        command = _default_command("collect")
        if self.world_config:
            raise UserError(f"--world-config sets another world's settings: the "
                            f"{DEFAULT_WORLD} world takes the options below")
        workers = self.workers
        if workers > self.plan.trajectories:  # (one trajectory is one worker's job)
            workers = self.plan.trajectories
            print(f"latent-sindy: note: --workers {self.workers} for {workers} "
                  f"trajector{'y' if workers == 1 else 'ies'}: using {workers} worker "
                  f"process{'' if workers == 1 else 'es'}", file=sys.stderr)
        command.run(self.plan, self.out, workers,
                    _bar("collect", "traj") if self.progress else None)

    def _collect_world(self) -> None:
        from latent_sindy.data.store import write_sequences

        world = configured_world(self.world, self.world_config)
        make = hook(world, "collect")
        if make is None:
            raise UserError(f"--world {self.world} does not collect data (no collect hook): "
                            "use a world that does, e.g. pendulum")
        default = CollectSettings()
        if replace(self.plan, trajectories=default.trajectories, steps=default.steps,
                   seed=default.seed) != default:
            raise UserError(f"--world {self.world} takes --trajectories, --steps and --seed; "
                            f"the other collection options are the {DEFAULT_WORLD} world's: "
                            "drop them")
        out = check_output_file(self.out, "--out", (".h5",))
        if out.exists():
            raise UserError(f"--out {out} exists: choose another file or delete it first")
        p = self.plan
        t0 = time.perf_counter()
        data = make(p.trajectories, p.steps, p.seed)
        write_sequences(out, data)
        print(f"wrote {out} ({data.n} sequences x {data.steps} steps of {self.world}, splits "
              f"{data.split_counts()}) in {time.perf_counter() - t0:.1f} s")


@dataclass
class Info:
    """Validate a data file and print what it holds (any file of the layout in docs/data.md)."""

    data: tyro.conf.Positional[Path]
    """Trajectory file (.h5)."""

    def run(self) -> None:
        import numpy as np

        from latent_sindy.data import read_sequences

        d = read_sequences(self.data)
        mean, std = d.pixel_stats()
        print(f"{self.data}: valid latent-sindy data file"
              + (f" of the {d.world!r} world" if d.world else ""))
        print(f"  sequences {d.n} {d.split_counts()}, {d.steps} steps each"
              + ("" if d.seed is None else f", seed {d.seed}")
              + ("" if d.dt is None else f", dt {d.dt:g}"))
        print(f"  images {d.images.shape} {d.images.dtype}, pixels {d.images.min()}.."
              f"{d.images.max()}, train mean {mean:.4g} std {std:.4g}")
        box = ", ".join(f"{n} [{lo:g}, {hi:g}]" for n, lo, hi in
                        zip(d.action_names, d.action_low, d.action_high, strict=True))
        print(f"  actions {d.nu}: {box or 'none (an autonomous system)'}")
        if d.states is None:
            print("  states: none")
        else:
            moves = np.abs(np.diff(d.states, axis=1)).mean(axis=(0, 1))
            print("  states " + ", ".join(f"{n} (moves {m:.4g} per step)" for n, m in
                                          zip(d.state_names, moves, strict=True)))
        if d.executed is not None:  # actions the world could not carry out (out of reach)
            missed = int(d.executed.size - np.count_nonzero(d.executed))
            print(f"  not executed: {missed} of {d.executed.size} actions "
                  f"({missed / max(d.executed.size, 1):.1%})")


@dataclass
class Preview:
    """Save a PNG grid of a trajectory file's images."""

    data: tyro.conf.Positional[Path]
    """Trajectory file (.h5)."""
    out: Path | None = None
    """PNG to write (default: beside the data, same name, .png)."""
    rows: int = 6
    """SequenceData to show."""

    def run(self) -> None:
        from latent_sindy.data import read_sequences
        from latent_sindy.data.preview import save_preview

        if self.rows < 1:
            raise UserError(f"--rows {self.rows}: show at least 1 trajectory")
        out = check_output_file(self.out or self.data.with_suffix(".png"), "--out", (".png",),
                                inputs=(self.data,))
        out = save_preview(read_sequences(self.data), out, self.rows)
        print(f"wrote {out}")


@dataclass
class Train:
    """Train a latent model (autoencoder + SINDy / linear / MLP dynamics) into a run folder.

    The run folder describes itself (config.json, model.pt with the SINDy mask,
    checkpoint.pt, metrics.csv, loss.png); every later command needs only the folder.
    An interrupted run continues with --resume to the same final model.
    """

    config: Annotated[TrainConfig, tyro.conf.arg(name=""), Flat] = field(
        default_factory=lambda: TrainConfig(data=DATA))
    # A second thread pays on a machine of one's own; while other jobs hold the cores it
    # measured 0.86-1.06x of one (BENCHMARKS.md). A CPU result's bits depend on the count.
    threads: int = 0
    """torch CPU threads; 0: one per core (results are bit-identical per seed and thread count)."""
    progress: bool = True
    """Show a progress bar."""

    def run(self) -> None:
        import torch

        from latent_sindy.progress import TqdmProgress
        from latent_sindy.training import default_threads, train

        _check_threads(self.threads, auto=True)
        torch.set_num_threads(self.threads or default_threads())
        out = train(self.config, TqdmProgress() if self.progress else None)
        print(f"wrote {out} (config.json, model.pt, metrics.csv, loss.png)")


@dataclass
class Equations:
    """Print a run's discovered latent equations and export its coefficients (CSV, JSON)."""

    run_dir: tyro.conf.Positional[Path]
    """Run folder written by `latent-sindy train`."""
    precision: int = 3
    """Significant digits shown (the exported files keep full precision)."""
    export: bool = True
    """Write RUN/coefficients.csv and RUN/coefficients.json."""

    def run(self) -> None:
        from latent_sindy.equations import equations_report

        if self.precision < 1:
            raise UserError(f"--precision {self.precision}: use 1 or more digits")
        print(equations_report(self.run_dir, export=self.export, precision=self.precision))


@dataclass
class Control:
    """Reach a goal with MPPI in a trained run's latent space (closed loop) in the run's world:
    a run of the default world plays its tasks with the options below, results in
    RUN/control-TASK-SPACE; a run of another world (e.g. the pendulum) plays that world's
    tasks, results in RUN/control-SPACE.

    Writes RUN/control-TASK-SPACE/results.json, results.csv and episode GIFs, and prints a
    summary: success rates (course and strict criteria), steps to goal, planning time. Without
    a planner option (--samples, --horizon, --sigma, --lambda, ...) it plans as the study does
    in the run's world (the world's own planner settings).
    """

    run_dir: tyro.conf.Positional[Path]
    """Run folder written by `latent-sindy train`."""
    settings: Annotated[ControlSettings, tyro.conf.arg(name=""), Flat] = field(
        default_factory=ControlSettings)
    out: Path | None = None
    """Output folder (default: RUN/control-TASK-SPACE)."""
    threads: int = 1
    """torch CPU threads."""
    progress: bool = True
    """Show a progress bar over episodes."""

    def run(self) -> None:
        import torch

        from latent_sindy.training import RunDir

        s = self.settings
        _check_threads(self.threads, auto=False)
        torch.set_num_threads(self.threads)
        run_dir = RunDir(self.run_dir)
        run = run_dir.load()
        if run.world is not None and run.world != DEFAULT_WORLD:
            from latent_sindy.study.commands import control_world

            control_world(self.run_dir, run, s, check_output_dir(
                self.out or run_dir.path / f"control-{s.space}", "--out"),
                ControlSettings(), GENERIC, DEFAULT_WORLD)
            return
        command = _default_command("control")
        out = check_output_dir(self.out or run_dir.control_dir(s.task, s.space), "--out")
        command.run(self.run_dir, run, s, out, _bar("episodes", "ep") if self.progress else None)


@dataclass(frozen=True)
class ReproduceSettings(StudySettings):
    """:class:`~latent_sindy.study.settings.StudySettings` with the installed worlds, their
    scales and the default world in its --help."""

    scale: Annotated[str, tyro.conf.arg(help=scale_help(), metavar="SCALE")] = "demo"
    world: Annotated[str | None, tyro.conf.arg(help=world_help(), metavar="WORLD")] = (
        DEFAULT_WORLD)


@dataclass
class Reproduce:
    """Run a world's study in one command and write its report: without --world, the
    default world's (the paper's study: data, every model, evaluation, control, Table I
    beside the paper's, figures, equations). Every study writes summary.json, table.md and
    a self-contained report.html into --out; a re-run reuses finished pieces.

    --world names a world with a study of its own (or a named world of one): e.g.
    pendulum-video, the SINDy autoencoder's pendulum-video recovery over seeds; pendulum, the
    controlled pendulum's swing-up; dmc, a DeepMind Control task from pixels; gym, any
    Gymnasium environment. Its settings: --world-config KEY=VALUE.
    """

    settings: Annotated[ReproduceSettings, tyro.conf.arg(name=""), Flat] = field(
        default_factory=ReproduceSettings)
    options: Annotated[WorldOptions, tyro.conf.arg(name=""), Flat] = field(
        default_factory=WorldOptions)
    world_config: tuple[str, ...] = ()
    """KEY=VALUE settings of the --world (fields of its config dataclass, the others at
    their defaults, or at its named world's), e.g. `task=reacher-easy` for dmc."""

    def run(self) -> None:
        from latent_sindy.study.runner import run_study

        s = self.settings
        if not (s.executor == "ray" and s.ray_address):
            _check_threads(s.threads, auto=False)  # (else: another machine's)
        if s.world is None:
            raise UserError(NO_DEFAULT_WORLD)
        report = run_study(s, given_options(self.options), self.world_config)
        print(f"report: {report}")


def _how_to_continue(argv: list[str] | None) -> str:
    """How to continue an interrupted command: ``train`` resumes only when told to."""
    args = sys.argv[1:] if argv is None else argv
    if args[:1] == ["train"] and "--resume" not in args and "--overwrite" not in args:
        return "to continue the run, re-run the same command with --resume added"
    if args[:1] == ["train"] and "--overwrite" in args:
        return ("to continue the run, re-run the same command with --resume in place of "
                "--overwrite")
    return "re-run the same command to resume"


COMMANDS = {"collect": Collect, "info": Info, "preview": Preview, "train": Train,
            "equations": Equations, "control": Control, "reproduce": Reproduce}


def main(argv: list[str] | None = None) -> int:
    try:
        # settings are validated while tyro builds them, so parsing is inside the try
        with carried_through_parsers():
            cmd = tyro.extras.subcommand_cli_from_dict(
                COMMANDS, prog="latent-sindy", args=argv,
                description="Sparse latent dynamics (SINDy) learned from images: train on "
                            "your own data, read the equations, plan with them.",
                config=(tyro.conf.OmitSubcommandPrefixes, tyro.conf.CascadeSubcommandArgs),
                registry=CLI_REGISTRY)  # the image model's flat options
        cmd.run()
    except (UserError, CarriedUserError) as e:
        if os.environ.get("LATENT_SINDY_DEBUG"):
            raise
        print(f"latent-sindy: error: {e}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # the reader of our output went away (`| head`): stop quietly, as shell tools do
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except OSError as e:  # permissions, missing folders, a full disk: the path and the reason
        if os.environ.get("LATENT_SINDY_DEBUG"):
            raise
        where = e.filename or "a file"
        reason = e.strerror or type(e).__name__
        print(f"latent-sindy: error: cannot use {where}: {reason}; check the path and its "
              "permissions (and free disk space)", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"latent-sindy: interrupted; {_how_to_continue(argv)}", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
