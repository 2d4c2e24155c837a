"""Does the SINDy autoencoder's pendulum model recover z'' = -sin z from the pendulum video, and
how often? A command-line client of :mod:`latent_sindy.worlds.pendulum.video_study`, which
trains the published model (latent dimension 1, fully connected 128-64-32 sigmoid encoder and
decoder, z'' = Θ(z, z') Ξ over polynomials of (z, z') to order 3 plus sin of each) for each of
``--seeds`` (the model's seed; the data is always the benchmark's seed 0) on a schedule cheap
enough for a 2-core CPU, and prints per seed the equation, whether its active set is exactly
{sin z}, the coefficient, the test FVU of x, ẍ and z̈ and the time, then a summary beside the
published and the replicated rows.

The images pass a fixed linear compression first: the first ``--components`` principal
components of the training frames (2601 pixels -> k coordinates, fitted once). Being linear,
it maps ẋ and ẍ exactly (``--derivatives exact``), and central differences of the coordinates
are those of the frames (``--derivatives central``, taken at the video's own dt = 0.02 before
keeping every ``frames_every``-th frame). The FVUs are measured in pixel space, the truncation
included.

    .venv/bin/python benchmarks/pendulum_recovery.py --seeds 0..2 --schedule scalefree
    .venv/bin/python benchmarks/pendulum_recovery.py --seeds 0..9 --derivatives central
    .venv/bin/python benchmarks/pendulum_recovery.py --seeds 0,1 --omega2 1.44

The data is cached in /tmp (pendulum_pca_K_EVERY_DERIVATIVES.npz) after its first making.
The same study with a report: ``latent-sindy reproduce --world pendulum-video``.
Results and what each schedule gave: RESULTS.md, "The pendulum video (issue 22)".
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict
from pathlib import Path

from latent_sindy.worlds.pendulum.video_pca import as_sequences, load_or_make
from latent_sindy.worlds.pendulum.video_study import (
    SCHEDULES,
    VideoStudyConfig,
    VideoStudyResult,
    seed_line,
    train_seed,
)


def seeds_of(text: str) -> list[int]:
    if ".." in text:
        a, b = text.split("..")
        return list(range(int(a), int(b) + 1))
    return [int(v) for v in text.split(",")]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0..9", help="model seeds: 0..9 or 0,3,5")
    ap.add_argument("--schedule", default="scalefree", choices=sorted(SCHEDULES))
    ap.add_argument("--derivatives", default="exact", choices=["exact", "central"])
    ap.add_argument("--components", type=int, default=48, help="principal components kept")
    ap.add_argument("--epochs", type=int, default=None, help="override the schedule's epochs")
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    ap.add_argument("--device", default="cpu", choices=["auto", "cpu", "cuda"],
                    help="where the models train")
    ap.add_argument("--omega2", type=float, default=1.0,
                    help="ω² of the video's pendulum, θ̈ = −ω² sin θ (the benchmark's: 1)")
    ap.add_argument("--starts", default="own_time", choices=["own_time", "benchmark"],
                    help="at ω² ≠ 1: the benchmark's starts in the pendulum's own time, or "
                         "drawn as for ω² = 1")
    ap.add_argument("--out", type=Path, default=None, help="append one JSON line per seed")
    args = ap.parse_args()

    import torch

    cfg = VideoStudyConfig(seeds=tuple(seeds_of(args.seeds)), schedule=args.schedule,
                           derivatives=args.derivatives, components=args.components,
                           epochs=args.epochs, device=args.device, threads=args.threads,
                           omega2=args.omega2, starts=args.starts)
    torch.set_num_threads(cfg.threads)
    s = cfg.resolved_schedule()
    t0 = time.perf_counter()
    video = load_or_make(Path("/tmp"), cfg.components, s.frames_every, cfg.derivatives,
                         omega2=cfg.omega2, starts=cfg.starts)
    data, lo, span = as_sequences(video)
    print(f"data: {video.coords.shape} in {time.perf_counter() - t0:.1f} s; schedule "
          f"{args.schedule}: {json.dumps(asdict(s))}; derivatives {args.derivatives}",
          flush=True)
    result = VideoStudyResult(cfg, [])
    for seed in cfg.seeds:
        r = train_seed(seed, s, data, cfg.components, video, lo, span, cfg.device, cfg.omega2)
        result.rows.append(r)
        print(seed_line(r), flush=True)
        if args.out:
            with args.out.open("a") as fh:
                fh.write(json.dumps({"schedule": args.schedule, "derivatives":
                                     args.derivatives, "components": args.components,
                                     **asdict(s), **r}) + "\n")
    print("\n".join(result.lines()))


if __name__ == "__main__":
    main()
