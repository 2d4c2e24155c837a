"""The `latent-sindy` command: a thin layer that parses typed settings and calls the library.

    latent-sindy collect --out data/push.h5 --trajectories 200 --workers 2 --seed 0
    latent-sindy info data/push.h5
    latent-sindy preview data/push.h5 --out data/push.png
    latent-sindy train --data data/push.h5 --model sindy --order 2 --horizon 1 --out runs/sindy2
    latent-sindy equations runs/sindy2
    latent-sindy control runs/sindy2 --task paper --episodes 1
    latent-sindy reproduce --scale demo --out results/demo

Mistakes a user can fix (a missing file, an impossible setting) end with one line on
stderr and exit status 2; set LATENT_SINDY_DEBUG=1 to see the traceback.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import tyro

from latent_sindy.errors import UserError
from latent_sindy.experiments.reproduce import ReproduceConfig
from latent_sindy.training import TrainConfig


def _progress(desc: str):
    """A tqdm wrapper matching collect()'s progress(iterable, total, initial) hook."""
    from tqdm import tqdm

    def wrap(iterable, total: int, initial: int):
        return tqdm(iterable, total=total, initial=initial, desc=desc, unit="traj",
                    dynamic_ncols=True, file=sys.stderr)

    return wrap


@dataclass
class Collect:
    """Collect random-push trajectories into an HDF5 file (resumable: re-run to finish)."""

    out: Path = Path("data/push.h5")
    """Trajectory file to write (.h5). An interrupted run keeps its progress in OUT.partial/."""
    trajectories: int = 200
    """Number of trajectories in all splits (paper: 200 = 100 train / 50 val / 50 test)."""
    steps: int = 10
    """Pushes per trajectory (each trajectory holds steps + 1 images)."""
    workers: int = 2
    """Worker processes simulating in parallel (1 runs in this process)."""
    seed: int = 0
    """Seed of every random choice; the same seed gives the same file."""
    val_fraction: float = 0.25
    """Fraction of trajectories for the validation split."""
    test_fraction: float = 0.25
    """Fraction of trajectories for the test split."""
    channels: Annotated[int, tyro.conf.arg(help="1: grayscale images, 3: RGB.")] = 1
    image_size: int = 32
    """Side of the square camera image in pixels."""
    progress: bool = True
    """Show a progress bar."""

    def run(self) -> None:
        from latent_sindy.data.collect import CollectionPlan, collect
        from latent_sindy.envs.config import PushEnvConfig

        plan = CollectionPlan(self.trajectories, self.steps, self.seed, self.val_fraction,
                              self.test_fraction,
                              PushEnvConfig(image_size=self.image_size, channels=self.channels))
        existed = self.out.exists()
        t0 = time.perf_counter()
        path = collect(self.out, plan, self.workers,
                       _progress("collect") if self.progress else None)
        if existed:
            print(f"{path} is already complete with these settings; nothing to do")
        else:
            print(f"wrote {path} ({plan.trajectories} trajectories x {plan.steps} pushes, "
                  f"splits {plan.split_counts()}) in {time.perf_counter() - t0:.1f} s")


@dataclass
class Info:
    """Validate a trajectory file and print what it holds."""

    data: tyro.conf.Positional[Path]
    """Trajectory file (.h5)."""

    def run(self) -> None:
        from latent_sindy.data.store import read_trajectories

        d = read_trajectories(self.data)
        mean, std = d.pixel_stats()
        step = d.poses[:, 1:, :2] - d.poses[:, :-1, :2]
        print(f"{self.data}: valid latent-sindy trajectory file")
        print(f"  trajectories {d.n} {d.split_counts()}, {d.steps} pushes each, seed {d.seed}")
        print(f"  images {d.images.shape} uint8, pixels {d.images.min()}..{d.images.max()}, "
              f"train mean {mean:.1f} std {std:.1f}")
        print(f"  block moves {1000 * float(abs(step).sum(-1).mean()):.1f} mm per push on "
              f"average (L1 of x, y)")


@dataclass
class Preview:
    """Save a PNG grid of a trajectory file's images."""

    data: tyro.conf.Positional[Path]
    """Trajectory file (.h5)."""
    out: Path | None = None
    """PNG to write (default: beside the data, same name, .png)."""
    rows: int = 6
    """Trajectories to show."""

    def run(self) -> None:
        from latent_sindy.data.preview import save_preview
        from latent_sindy.data.store import read_trajectories

        if self.rows < 1:
            raise UserError(f"--rows {self.rows}: show at least 1 trajectory")
        out = save_preview(read_trajectories(self.data), self.out or self.data.with_suffix(".png"),
                           self.rows)
        print(f"wrote {out}")


@dataclass
class Train:
    """Train a latent model (autoencoder + SINDy / linear / MLP dynamics) into a run folder.

    The run folder describes itself (config.json, model.pt with the SINDy mask,
    checkpoint.pt, metrics.csv, loss.png); every later command needs only the folder.
    An interrupted run continues with --resume to the same final model.
    """

    config: Annotated[TrainConfig, tyro.conf.arg(name=""), tyro.conf.OmitArgPrefixes] = field(
        default_factory=TrainConfig)
    threads: int = 1
    """torch CPU threads (1 is fastest when other jobs share the cores)."""
    progress: bool = True
    """Show a progress bar."""

    def run(self) -> None:
        import torch

        from latent_sindy.training import TqdmProgress, train

        if self.threads < 1:
            raise UserError(f"--threads {self.threads}: use 1 or more")
        torch.set_num_threads(self.threads)
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
    """Push the block to a goal with MPPI in a trained run's latent space (closed loop).

    Writes RUN/control-TASK[-image]/results.json, results.csv and episode GIFs, and prints
    a summary: success rates (course and strict criteria), steps to goal, planning time.
    """

    run_dir: tyro.conf.Positional[Path]
    """Run folder written by `latent-sindy train`."""
    task: Literal["paper", "random"] = "paper"
    """paper: start (0.4, 0, 0.2 pi), goal (0.7, 0, 0); random: start and goal from the seed."""
    episodes: int = 1
    """Number of episodes."""
    seed: int = 0
    """Seeds the random tasks and the controller's noise."""
    image_space: bool = False
    """Plan with the cost in image space (decode each predicted latent, compare with the goal
    image) instead of latent space."""
    max_steps: int = 20
    """Pushes allowed per episode (course: 20 latent, 30 image space)."""
    until: Literal["course", "strict"] = "course"
    """Stop an episode when this success criterion is met."""
    samples: int = 100
    """MPPI samples K (course: 100)."""
    horizon: int = 10
    """MPPI horizon H (course: 10)."""
    sigma: float = 0.1
    """MPPI noise variance per action dimension (course: 0.1)."""
    lambda_: Annotated[float, tyro.conf.arg(name="lambda")] = 0.01
    """MPPI temperature (course: 0.01)."""
    gif_episodes: int = 1
    """Save a GIF of the first this many episodes."""
    out: Path | None = None
    """Output folder (default: RUN/control-TASK, with -image for image space)."""
    threads: int = 1
    """torch CPU threads."""
    progress: bool = True
    """Show a progress bar over episodes."""

    def run(self) -> None:
        import torch

        from latent_sindy.control.closed_loop import ControlSettings, format_summary, run_control
        from latent_sindy.training import load_run

        settings = ControlSettings(
            task=self.task, episodes=self.episodes, seed=self.seed,
            image_space=self.image_space, max_steps=self.max_steps, until=self.until,
            samples=self.samples, horizon=self.horizon, sigma=self.sigma,
            lambda_=self.lambda_, gif_episodes=self.gif_episodes)
        torch.set_num_threads(max(1, self.threads))
        run = load_run(self.run_dir)
        out = self.out or self.run_dir / (
            f"control-{self.task}" + ("-image" if self.image_space else ""))
        progress = None
        if self.progress:
            from tqdm import tqdm

            def progress(it, total):
                return tqdm(it, total=total, desc="episodes", unit="ep", file=sys.stderr)

        _, summary = run_control(run.model, run.normalizer, run.env_config, settings, out,
                                 progress)
        space = "image" if self.image_space else "latent"
        print(format_summary(summary, f"{self.run_dir} ({run.config.model.kind}), "
                                      f"{self.task} task, {space}-space MPPI:"))
        print(f"wrote {out}/results.json, results.csv"
              + (", episode GIFs" if self.gif_episodes else ""))


@dataclass
class Reproduce:
    """Reproduce the paper's study and our additions in one command, and write the report.

    Collects the data if missing; trains SINDy orders 1-4, a multi-step SINDy, the linear (E2C)
    and the MLP baselines on the same data, splits and seeds; evaluates losses, prediction
    error against horizon, sparsity and closed-loop control (latent and image-space MPPI);
    writes table1.md/csv, figures/, equations, summary.json and a self-contained report.html.
    A re-run reuses finished pieces.
    """

    config: Annotated[ReproduceConfig, tyro.conf.arg(name=""), tyro.conf.OmitArgPrefixes] = (
        field(default_factory=ReproduceConfig))

    def run(self) -> None:
        from latent_sindy.experiments.reproduce import reproduce

        report = reproduce(self.config)
        print(f"report: {report}")


COMMANDS = {"collect": Collect, "info": Info, "preview": Preview, "train": Train,
            "equations": Equations, "control": Control, "reproduce": Reproduce}


def main(argv: list[str] | None = None) -> int:
    try:
        # settings are validated while tyro builds them, so parsing is inside the try
        cmd = tyro.extras.subcommand_cli_from_dict(
            COMMANDS, prog="latent-sindy", args=argv,
            description="Sparse latent dynamics (SINDy) from images, for planar pushing.")
        cmd.run()
    except UserError as e:
        if os.environ.get("LATENT_SINDY_DEBUG"):
            raise
        print(f"latent-sindy: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("latent-sindy: interrupted; re-run the same command to resume", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
