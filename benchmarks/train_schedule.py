"""Whole training epochs at the paper's schedule shape, before and after each trainer change.

SINDy-2 with the conv decoder (the study's model) on 100 training and 50 validation
trajectories of 10 pushes: 1000 single-step training windows in two batches of 500 and 500
validation windows, through :func:`latent_sindy.training.train` itself (run folder, metrics
CSV, a checkpoint every 10 epochs: everything a real run does). The variants add one change
each to the row above:

  * before: the trainer as it was (validation every epoch under ``torch.no_grad``, 1 thread);
  * inference_mode: validation under ``torch.inference_mode`` (the trainer's code now);
  * eval_every N: validation every N epochs and at the last (``--eval-every``);
  * threads T: T torch threads (the CLI's ``--threads``).

Every variant trains ``--epochs`` epochs (a multiple of ``--eval-every``) from the same seed;
variants are interleaved over ``--rounds`` rounds and each keeps its fastest round, the
figure least disturbed by other jobs on the machine. An epoch is timed from the trainer's
progress callbacks (start to last epoch, over the epochs); set-up and the final save and plot
are timed apart and added once to the projection of a ``--project``-epoch run.

    .venv/bin/python benchmarks/train_schedule.py --rounds 3
    .venv/bin/python benchmarks/train_schedule.py --data data/push.h5 --epochs 20
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from latent_sindy.data.store import Trajectories, write_trajectories
from latent_sindy.envs.config import ACTION_HIGH, ACTION_LOW, PushEnvConfig
from latent_sindy.models import AutoencoderConfig, ModelConfig, SindyConfig
from latent_sindy.training import TrainConfig, loop, train

BEFORE_MINUTES = 46  # the paper schedule's wall time on this machine before (RESULTS.md)


def load() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def synthetic_data(path: Path, train: int = 100, val: int = 50, test: int = 50,
                   steps: int = 10) -> Path:
    """Random 1x32x32 images and actions with the paper's split sizes (timing only)."""
    rng = np.random.default_rng(0)
    n = train + val + test
    images = rng.integers(0, 256, size=(n, steps + 1, 1, 32, 32), dtype=np.uint8)
    actions = rng.uniform(ACTION_LOW, ACTION_HIGH, size=(n, steps, 3)).astype(np.float32)
    poses = rng.uniform(-0.3, 0.7, size=(n, steps + 1, 3)).astype(np.float32)
    splits = np.repeat(np.array([0, 1, 2], dtype=np.uint8), [train, val, test])
    write_trajectories(path, Trajectories(images, actions, poses, splits, PushEnvConfig(),
                                          seed=0))
    return path


class Clock:
    """A training progress that records when training started and when each epoch ended."""

    def __init__(self) -> None:
        self.started = 0.0
        self.ends: list[float] = []

    def start(self, total: int, initial: int) -> None:
        self.started = time.perf_counter()

    def update(self, epoch: int, metrics: Mapping[str, float | None]) -> None:
        self.ends.append(time.perf_counter())

    def note(self, text: str) -> None: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class Variant:
    name: str
    threads: int
    eval_every: int
    inference_mode: bool


def run_variant(v: Variant, args: argparse.Namespace, data: Path, out: Path
                ) -> tuple[float, float]:
    """Train once; returns (seconds per epoch, fixed seconds: set-up + final save and plot)."""
    torch.set_num_threads(v.threads)
    evaluate = loop.evaluate
    if not v.inference_mode:  # the trainer as it was: validation under no_grad
        loop.evaluate = torch.no_grad()(evaluate.__wrapped__)
    model = ModelConfig(encoder=AutoencoderConfig(decoder=args.decoder),
                        dynamics=SindyConfig(order=2))
    cfg = TrainConfig(data=data, out=out, model=model, epochs=args.epochs,
                      batch_size=500, threshold_every=300, threshold=1e-3,
                      eval_every=v.eval_every, overwrite=True)
    clock = Clock()
    try:
        t0 = time.perf_counter()
        train(cfg, clock)
        total = time.perf_counter() - t0
    finally:
        loop.evaluate = evaluate
    epochs = clock.ends[-1] - clock.started
    return epochs / args.epochs, total - epochs


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, help="trajectory file (default: synthetic, 100/50/50)")
    p.add_argument("--epochs", type=int, default=10, help="epochs per timed run")
    p.add_argument("--rounds", type=int, default=3, help="interleaved rounds (best of)")
    p.add_argument("--eval-every", type=int, default=10, help="the eval_every variant's N")
    p.add_argument("--threads", type=int, default=2, help="the threads variant's T")
    p.add_argument("--decoder", choices=("conv", "fc"), default="conv")
    p.add_argument("--project", type=int, default=3000, help="epochs of the projected run")
    args = p.parse_args()
    if args.epochs % args.eval_every:
        p.error("--epochs must be a multiple of --eval-every")
    variants = [
        Variant("before (no_grad eval every epoch, 1 thread)", 1, 1, False),
        Variant("+ inference_mode validation", 1, 1, True),
        Variant(f"+ eval_every {args.eval_every}", 1, args.eval_every, True),
        Variant(f"+ {args.threads} threads", args.threads, args.eval_every, True),
    ]
    print(f"torch {torch.__version__}, {os.cpu_count()} CPUs, SINDy-2, {args.decoder} decoder, "
          f"batch 500, {args.epochs} epochs per run, best of {args.rounds} interleaved rounds")
    with tempfile.TemporaryDirectory() as tmp:
        data = args.data or synthetic_data(Path(tmp) / "synthetic.h5")
        print(f"data: {args.data or 'synthetic (random images), 100/50/50 trajectories x 10'}")
        best: dict[str, tuple[float, float]] = {}
        for r in range(args.rounds):
            for v in variants:
                per_epoch, fixed = run_variant(v, args, data, Path(tmp) / "run")
                old = best.get(v.name, (float("inf"), float("inf")))
                best[v.name] = (min(old[0], per_epoch), min(old[1], fixed))
                print(f"  round {r + 1}: {v.name:<46} {1e3 * per_epoch:7.1f} ms/epoch "
                      f"(load average {load()})", flush=True)
    first = prev = best[variants[0].name][0]
    print(f"\nbest ms per epoch; x: speed-up over the row above and over 'before'; projected "
          f"{args.project}-epoch run = {args.project} epochs + set-up and final save "
          f"(before on this machine: {BEFORE_MINUTES} min)")
    print(f"{'variant':<46} {'ms/epoch':>9} {'x above':>8} {'x before':>9} {'projected':>10}")
    for v in variants:
        per_epoch, fixed = best[v.name]
        minutes = (args.project * per_epoch + fixed) / 60
        print(f"{v.name:<46} {1e3 * per_epoch:9.1f} {prev / per_epoch:8.2f} "
              f"{first / per_epoch:9.2f} {minutes:7.1f} min")
        prev = per_epoch
    print(f"load average at end: {load()}")


if __name__ == "__main__":
    main()
