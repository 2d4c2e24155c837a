"""Does batching by trajectories train as well as batching by windows? Same seeds and epochs.

Trains SINDy-2 with the conv decoder (the study's image model) once per seed and per
``--batching`` (windows: the trainer as it was; trajectories: every frame encoded and
reconstructed once) and prints, per run, what model selection kept: the epoch, its
validation objective, the test split's loss terms on single-step windows (the study's
``loss/*``, :func:`latent_sindy.training.core.evaluate`), the active SINDy terms, and the
training time (wall and process CPU). Runs go one after another in this process, on
``--threads`` torch threads.

    .venv/bin/python benchmarks/batching.py --data data/push.h5 --seeds 0 1
    .venv/bin/python benchmarks/batching.py --data data/push.h5 --epochs 600 --batch-size 500 \
        --prune-every 60 --eval-every 10
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import torch

from latent_sindy.data import read_sequences
from latent_sindy.data.windows import WindowDataset
from latent_sindy.models import AutoencoderConfig, ModelConfig, SindyConfig
from latent_sindy.training import TrainConfig, load_run, train
from latent_sindy.training.core import Sequences, evaluate


def load() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, required=True, help="trajectory file")
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--epochs", type=int, default=60)
    p.add_argument("--batch-size", type=int, default=64)
    p.add_argument("--prune-every", type=int, default=6)
    p.add_argument("--eval-every", type=int, default=1)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--batchings", nargs="+", default=["windows", "trajectories"])
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    data = read_sequences(args.data)
    print(f"torch {torch.__version__}, {args.threads} thread(s); SINDy-2, conv decoder; "
          f"{args.epochs} epochs, batch {args.batch_size}, pruning every "
          f"{args.prune_every}, validation every {args.eval_every}; data {args.data} "
          f"({data.split_counts()})")
    print(f"{'seed':>4} {'batching':<13} {'kept':>5} {'val obj':>9} {'test obj':>9} "
          f"{'recon':>8} {'pred_x':>8} {'pred_z':>9} {'active':>7} {'wall s':>7} "
          f"{'CPU s':>7}  load")
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            for batching in args.batchings:
                model = ModelConfig(observation=AutoencoderConfig(decoder_kind="conv"),
                                    dynamics=SindyConfig(order=2))
                cfg = TrainConfig(data=args.data, out=Path(tmp) / f"{batching}{seed}",
                                  model=model, epochs=args.epochs, batch_size=args.batch_size,
                                  prune_every=args.prune_every, prune_below=1e-3,
                                  eval_every=args.eval_every, seed=seed, batching=batching)
                t0, c0 = time.perf_counter(), time.process_time()
                run = train(cfg)
                wall, cpu = time.perf_counter() - t0, time.process_time() - c0
                loaded = load_run(run)
                record = json.loads((run / "config.json").read_text())["kept"]
                x, u = WindowDataset(data.split("test"), 1, loaded.normalizer).tensors()
                test = evaluate(loaded.model, Sequences(x, u), cfg.loss)
                dyn = loaded.model.dynamics
                print(f"{seed:>4} {batching:<13} {record['epoch']:>5} "
                      f"{record['val_objective']:9.5f} {test['objective']:9.5f} "
                      f"{test['recon']:8.5f} {test['pred_x']:8.5f} {test['pred_z']:9.2e} "
                      f"{dyn.n_active():>7} {wall:7.1f} {cpu:7.1f}  {load()}", flush=True)


if __name__ == "__main__":
    main()
