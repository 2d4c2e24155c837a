"""The `latent-sindy` command: a thin layer that parses typed settings and calls the library.

    latent-sindy collect --out data/push.h5 --trajectories 200 --workers 2 --seed 0
    latent-sindy info data/push.h5
    latent-sindy preview data/push.h5 --out data/push.png
    latent-sindy demo --out runs/demo

Mistakes a user can fix (a missing file, an impossible setting) end with one line on
stderr and exit status 2; set LATENT_SINDY_DEBUG=1 to see the traceback.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import tyro

from latent_sindy.errors import UserError


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
class Demo:
    """The main job on its defaults: collect a small data set and write its preview."""

    out: Path = Path("runs/demo")
    """Folder for everything the demo writes."""
    trajectories: int = 20
    workers: int = 2
    seed: int = 0

    def run(self) -> None:
        data = self.out / "data.h5"
        Collect(out=data, trajectories=self.trajectories, workers=self.workers,
                seed=self.seed).run()
        Info(data).run()
        Preview(data, out=self.out / "data_preview.png").run()


COMMANDS = {"collect": Collect, "info": Info, "preview": Preview, "demo": Demo}


def main(argv: list[str] | None = None) -> int:
    cmd = tyro.extras.subcommand_cli_from_dict(
        COMMANDS, prog="latent-sindy", args=argv,
        description="Sparse latent dynamics (SINDy) from images, for planar pushing.")
    try:
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
