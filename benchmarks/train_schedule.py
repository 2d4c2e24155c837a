"""Whole training epochs at the paper's schedule shape, before and after each trainer change.

SINDy-2 with the conv decoder (the study's model) on 100 training and 50 validation
trajectories of 10 pushes: 1000 single-step training windows in two batches of 500 and 500
validation windows, through :func:`latent_sindy.training.train` itself (run folder, metrics
CSV, a checkpoint every 10 epochs: everything a real run does). The variants add one change
each to the row above:

  * before: the trainer as it was (validation every epoch under ``torch.no_grad``, 1 thread);
  * inference_mode: validation under ``torch.inference_mode`` (the trainer's code now);
  * eval_every N: validation every N epochs and at the last (``--eval-every``);
  * malloc keeps memory: glibc's malloc keeps freed blocks for reuse instead of returning
    them to the OS and page-faulting them back at every step (the trainer's code now);
  * native forward of the last transposed conv: the conv decoder's 16 -> 1 channel layer
    computes its forward with PyTorch's own kernel (oneDNN pads the one output channel) and
    its backward with oneDNN's (the model's code now);
  * pool before ReLU: the encoder max-pools before its ReLUs (a quarter of the values) and
    the ReLUs work in place (the model's code now);
  * threads T: T torch threads (the CLI's ``--threads``), first with libgomp's default wait
    policy (idle OpenMP threads spin), then with ``OMP_WAIT_POLICY=PASSIVE`` (they sleep; the
    CLI sets it);
  * batch split: ``--parallel batch`` (the default with several threads): each batch cut into
    T slices whose gradients T threads of one torch thread each compute at once, then added;
  * trajectory batches: ``--batching trajectories`` (the default at window 1): batches of 50
    whole trajectories whose 11 frames are encoded and reconstructed once each (11 encodes and
    21 decodes per trajectory instead of 20 and 30), at 1 and at T threads. Every other row
    batches windows, as the trainer did before.

Every variant runs in a fresh process and trains ``2 * --epochs`` epochs (``--epochs`` a
multiple of ``--eval-every``) from the same seed; the first half warms up (memory, oneDNN's
kernels), the second half is timed from the trainer's progress callbacks. Variants are
interleaved over ``--rounds`` rounds and each keeps its fastest round, the figure least
disturbed by other jobs on the machine. Set-up and the final save and plot are timed apart
and added once to the projection of a ``--project``-epoch run; process start-up (imports,
about 5 s) is not. Minor page faults, kernel (sys) time and the process's CPU time (user +
sys, all threads) per timed epoch are printed too: with one thread, CPU time is the figure
least disturbed by other jobs (it leaves out the time spent waiting for a core).

    .venv/bin/python benchmarks/train_schedule.py --rounds 3
    .venv/bin/python benchmarks/train_schedule.py --data data/push.h5 --epochs 20
    .venv/bin/python benchmarks/train_schedule.py --only 6 7   # 1 against 2 threads
    .venv/bin/python benchmarks/train_schedule.py --only 6 8 7 9   # windows vs trajectories
    .venv/bin/python benchmarks/train_schedule.py --only 8 9 10   # ... and the batch split
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from latent_sindy.data import write_sequences
from latent_sindy.models import AutoencoderConfig, ModelConfig, SindyConfig, autoencoder
from latent_sindy.training import TrainConfig, core, loop, train
from latent_sindy.worlds.push.config import ACTION_HIGH, ACTION_LOW, PushEnvConfig
from latent_sindy.worlds.push.data import push_data

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
    write_sequences(path, push_data(images, actions, poses, splits, PushEnvConfig(),
                                          seed=0))
    return path


class Clock:
    """A training progress that records when training started and when each epoch ended,
    with the process's page faults and kernel time at the end of epoch ``mark``."""

    def __init__(self, mark: int) -> None:
        self.mark = mark
        self.started = 0.0
        self.ends: list[float] = []
        self.usage: list[resource.struct_rusage] = []

    def start(self, total: int, initial: int) -> None:
        self.started = time.perf_counter()

    def update(self, epoch: int, metrics: Mapping[str, float | None]) -> None:
        self.ends.append(time.perf_counter())
        if epoch in (self.mark, 2 * self.mark):
            self.usage.append(resource.getrusage(resource.RUSAGE_SELF))

    def note(self, text: str) -> None: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class Variant:
    name: str
    threads: int
    eval_every: int
    inference_mode: bool
    keep_memory: bool
    omp_passive: bool = False
    native_last: bool = False
    pool_first: bool = False
    batching: str = "windows"
    parallel: str = "ops"


def variants(args: argparse.Namespace) -> list[Variant]:
    t, n = args.threads, args.eval_every
    return [
        Variant("before (no_grad eval every epoch, 1 thread)", 1, 1, False, False),
        Variant("+ inference_mode validation", 1, 1, True, False),
        Variant(f"+ eval_every {n}", 1, n, True, False),
        Variant("+ malloc keeps freed memory", 1, n, True, True),
        Variant(f"+ {t} threads (OpenMP threads spin)", t, n, True, True),
        Variant("+ native forward, last transposed conv", 1, n, True, True, False, True),
        Variant("+ pool before ReLU, in-place ReLUs", 1, n, True, True, False, True, True),
        Variant(f"+ {t} threads, OMP_WAIT_POLICY=PASSIVE", t, n, True, True, True, True, True),
        Variant("+ trajectory batches, 1 thread", 1, n, True, True, False, True, True,
                "trajectories"),
        Variant(f"+ trajectory batches, {t} threads, PASSIVE", t, n, True, True, True, True,
                True, "trajectories"),
        Variant(f"+ batch split across {t} threads (--parallel batch)", t, n, True, True, True,
                True, True, "trajectories", "batch"),
    ]


def old_layers(native_last: bool, pool_first: bool) -> None:
    """Put back the autoencoder's layers as they were before these changes (this process)."""
    from torch import nn

    if not native_last:  # oneDNN's transposed convolution forward, as nn.ConvTranspose2d
        autoencoder._ImageConvTranspose2d.forward = nn.ConvTranspose2d.forward
    if pool_first:
        return
    enc_init, dec_init = autoencoder.Encoder.__init__, autoencoder.Decoder.__init__

    def encoder(self, cfg):  # the course's order: conv, ReLU, pool; ReLUs out of place
        enc_init(self, cfg)
        net = self.net
        net[1], net[2], net[4], net[5] = nn.ReLU(), nn.MaxPool2d(2), nn.ReLU(), nn.MaxPool2d(2)

    def decoder(self, cfg):
        dec_init(self, cfg)
        for m in self.modules():
            if isinstance(m, nn.ReLU):
                m.inplace = False

    autoencoder.Encoder.__init__, autoencoder.Decoder.__init__ = encoder, decoder


def run_variant(v: Variant, args: argparse.Namespace, data: Path, out: Path) -> dict:
    """Train once in this process: seconds per timed epoch, fixed seconds (set-up before
    the first epoch + final save and plot), page faults and kernel seconds per timed epoch."""
    torch.set_num_threads(v.threads)
    if not v.inference_mode:  # the trainer as it was: validation under no_grad
        core.evaluate = torch.no_grad()(core.evaluate.__wrapped__)
    if not v.keep_memory:  # the trainer as it was: glibc's default malloc thresholds
        loop.keep_freed_memory = lambda: None
    old_layers(v.native_last, v.pool_first)
    model = ModelConfig(observation=AutoencoderConfig(decoder_kind=args.decoder),
                        dynamics=SindyConfig(order=2))
    cfg = TrainConfig(data=data, out=out, model=model, epochs=2 * args.epochs,
                      batch_size=500, prune_every=300, prune_below=1e-3,
                      eval_every=v.eval_every, batching=v.batching, parallel=v.parallel,
                      overwrite=True)
    clock = Clock(args.epochs)
    t0 = time.perf_counter()
    train(cfg, clock)
    end = time.perf_counter()
    timed = clock.ends[-1] - clock.ends[args.epochs - 1]
    (a, b), n = clock.usage, args.epochs
    return {"epoch_s": timed / n, "fixed_s": clock.started - t0 + end - clock.ends[-1],
            "faults": (b.ru_minflt - a.ru_minflt) / n, "sys_s": (b.ru_stime - a.ru_stime) / n,
            "cpu_s": (b.ru_utime + b.ru_stime - a.ru_utime - a.ru_stime) / n}


def run_child(k: int, args: argparse.Namespace, data: Path, out: Path) -> dict:
    cmd = [sys.executable, __file__, "--child", str(k), "--data", str(data), "--out", str(out),
           "--epochs", str(args.epochs), "--eval-every", str(args.eval_every),
           "--threads", str(args.threads), "--decoder", args.decoder]
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if variants(args)[k].omp_passive:  # read when torch loads libgomp: set per process
        env["OMP_WAIT_POLICY"] = "PASSIVE"
    done = subprocess.run(cmd, capture_output=True, text=True, check=False, env=env)
    if done.returncode:
        raise SystemExit(f"variant {k} failed:\n{done.stderr}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, help="trajectory file (default: synthetic, 100/50/50)")
    p.add_argument("--epochs", type=int, default=10, help="epochs per timed run")
    p.add_argument("--rounds", type=int, default=3, help="interleaved rounds (best of)")
    p.add_argument("--eval-every", type=int, default=10, help="the eval_every variant's N")
    p.add_argument("--threads", type=int, default=2, help="the threads variant's T")
    p.add_argument("--decoder", choices=("conv", "fc"), default="conv")
    p.add_argument("--project", type=int, default=3000, help="epochs of the projected run")
    p.add_argument("--only", type=int, nargs="+", help="run only these rows (0 = before)")
    p.add_argument("--child", type=int, help=argparse.SUPPRESS)
    p.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.epochs % args.eval_every:
        p.error("--epochs must be a multiple of --eval-every")
    vs = variants(args)
    if args.child is not None:
        print(json.dumps(run_variant(vs[args.child], args, args.data, args.out)))
        return
    print(f"torch {torch.__version__}, {os.cpu_count()} CPUs, SINDy-2, {args.decoder} decoder, "
          f"batch 500, {args.epochs} timed epochs (after {args.epochs} warm-up) per run, best "
          f"of {args.rounds} interleaved rounds, each run in a fresh process")
    with tempfile.TemporaryDirectory() as tmp:
        data = args.data or synthetic_data(Path(tmp) / "synthetic.h5")
        print(f"data: {args.data or 'synthetic (random images), 100/50/50 trajectories x 10'}")
        best: dict[int, dict] = {}
        rows = args.only or range(len(vs))
        for r in range(args.rounds):
            for k in rows:
                v = vs[k]
                got = run_child(k, args, data, Path(tmp) / "run")
                if k not in best or got["epoch_s"] < best[k]["epoch_s"]:
                    best[k] = got | {"fixed_s": min(got["fixed_s"],
                                                    best.get(k, got)["fixed_s"]),
                                     "cpu_s": min(got["cpu_s"], best.get(k, got)["cpu_s"])}
                else:
                    best[k]["cpu_s"] = min(got["cpu_s"], best[k]["cpu_s"])
                print(f"  round {r + 1}: {v.name:<46} {1e3 * got['epoch_s']:7.1f} ms/epoch "
                      f"{1e3 * got['cpu_s']:7.1f} CPU ms (load average {load()})", flush=True)
    first = prev = best[rows[0]]["epoch_s"]
    print(f"\nbest ms per epoch; x: speed-up over the row above and over the first row; projected "
          f"{args.project}-epoch run = {args.project} epochs + set-up and final save "
          f"(before on this machine: {BEFORE_MINUTES} min); page faults and kernel time per "
          "epoch of that best run; CPU ms: the least CPU time (all threads) per epoch of any "
          "round")
    print(f"{'variant':<46} {'ms/epoch':>9} {'x above':>8} {'x first':>9} {'projected':>10} "
          f"{'faults':>7} {'sys ms':>7} {'CPU ms':>7}")
    for k in rows:
        v, b = vs[k], best[k]
        minutes = (args.project * b["epoch_s"] + b["fixed_s"]) / 60
        print(f"{v.name:<46} {1e3 * b['epoch_s']:9.1f} {prev / b['epoch_s']:8.2f} "
              f"{first / b['epoch_s']:9.2f} {minutes:6.1f} min {b['faults']:7.0f} "
              f"{1e3 * b['sys_s']:7.1f} {1e3 * b['cpu_s']:7.1f}")
        prev = b["epoch_s"]
    print(f"load average at end: {load()}")


if __name__ == "__main__":
    main()
