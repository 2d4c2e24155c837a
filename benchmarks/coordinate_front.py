"""Training on the principal-component front's coordinates against the frames, one process.

The recipe's model (mlp networks behind 48 principal components, continuous time, order 2)
on the raw pendulum video (51x51 frames, every 5th of 500, exact derivatives): its training
samples as frames (``DerivativeSamples``) and as their coordinates on the front
(``CoordinateSamples``, what training uses). Timed: one training step (loss, backward, AdamW
step) on the same batches of 100, the two kinds alternating; printed: the median step of
each, their ratio, and the largest relative difference of the loss terms.

    python benchmarks/coordinate_front.py [--steps 60] [--omega2 1.44]
"""

from __future__ import annotations

import argparse
import statistics
import time


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=60)
    p.add_argument("--omega2", type=float, default=1.44)
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)

    import torch

    from latent_sindy import LatentSINDy, Restarts
    from latent_sindy.data.windows import Normalizer
    from latent_sindy.training import TrainConfig
    from latent_sindy.training.prepare import derivative_samples, training_tensors
    from latent_sindy.training.recipe import pixel_spread, recipe_loss
    from latent_sindy.worlds.pendulum.video import pendulum_video

    torch.set_num_threads(args.threads)
    video = pendulum_video(omega2=args.omega2, frames_every=5)
    est = LatentSINDy(latent_dim=1, time="continuous", derivative_order=2, seed=0)
    est.fit(video, epochs=1, phases=[], restarts=Restarts(0))  # the recipe's model, fitted
    model = est.model_
    cfg = TrainConfig(batch_size=100, loss=recipe_loss(pixel_spread(video)))
    norm = Normalizer.from_trajectories(video)
    coords = training_tensors(model, video, norm, cfg, torch.device("cpu"), fresh=False).train
    frames = derivative_samples(video.split("train"), norm, 2, cfg)
    opt = torch.optim.AdamW(model.parameters(), lr=1e-6)
    gen = torch.Generator().manual_seed(0)
    times = {"frames": [], "coordinates": []}
    worst = 0.0
    for _ in range(args.steps):
        idx = torch.randperm(frames.n, generator=gen)[:100]
        terms = {}
        for name, samples in (("frames", frames), ("coordinates", coords)):
            batch = samples.pick(idx)
            t0 = time.perf_counter()
            opt.zero_grad()
            out = batch.loss(model, cfg.loss, None)
            out["total"].backward()
            times[name].append(time.perf_counter() - t0)
            terms[name] = {k: float(v.detach()) for k, v in out.items()}
        worst = max(worst, *(abs(terms["coordinates"][k] / v - 1)
                             for k, v in terms["frames"].items() if v))
    f, c = (statistics.median(times[k]) * 1e3 for k in ("frames", "coordinates"))
    print(f"median training step (batch 100, {args.threads} thread(s)): frames {f:.1f} ms, "
          f"coordinates {c:.1f} ms: {f / c:.2f}x")
    print(f"largest relative difference of a loss term over {args.steps} batches: {worst:.1e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
