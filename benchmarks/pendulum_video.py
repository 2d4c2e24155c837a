"""Training speed of the SINDy autoencoder's pendulum model (continuous time, second order) on
the pendulum video benchmark, at the published sizes.

The data is :func:`latent_sindy.worlds.pendulum.video.pendulum_video` (51×51 images, exact
first and second derivatives, 500 frames per trajectory). The model is the published one:
latent dimension 1, fully connected encoder and decoder 128-64-32 with sigmoid activations,
z'' = Θ(z, z') Ξ over polynomials of (z, z') to order 3 plus sin of each (12 terms). One step
is the loss (the encoder's z, ż, z̈ and the decoder's x̂, ẍ̂ by forward mode) + backward +
Adam update on a batch of ``--batch`` frames (published: 1000), through the one training loop
(``training.fit_loop.train_epoch``). It reports the median and the fastest step over
``--steps`` timed steps (after one warm-up step), and the time an epoch of the training split
would take at the median (the published run: 5001 + 1001 epochs).

    .venv/bin/python benchmarks/pendulum_video.py --train 100 --steps 10 --threads 1
    .venv/bin/python benchmarks/pendulum_video.py --train 20 --steps 5 --device cuda
    .venv/bin/python benchmarks/pendulum_video.py --smoke     # one trajectory, batch 50 (the tests)
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

from latent_sindy.script_args import parse_with_smoke


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--train", type=int, default=100, help="training trajectories (paper 100)")
    ap.add_argument("--batch", type=int, default=1000, help="frames per step (paper 1000)")
    ap.add_argument("--steps", type=int, default=10, help="timed steps")
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    ap.add_argument("--device", default="cpu", help="cpu or cuda")
    args = parse_with_smoke(ap, argv, {"train": 1, "batch": 50, "steps": 2})

    import torch

    from latent_sindy.configs import from_json
    from latent_sindy.data.windows import Normalizer
    from latent_sindy.models import AutoencoderConfig, LossWeights, ModelConfig
    from latent_sindy.models.dynamics import ContinuousSindyConfig
    from latent_sindy.training import TrainConfig
    from latent_sindy.training.fit_loop import Gradients, train_epoch
    from latent_sindy.training.prepare import derivative_samples, new_model
    from latent_sindy.training.record import run_record
    from latent_sindy.worlds.pendulum.video import pendulum_video

    torch.set_num_threads(args.threads)
    t0 = time.perf_counter()
    data = pendulum_video(n_train=args.train, n_val=1, n_test=1, seed=0)
    made = time.perf_counter() - t0
    model_cfg = ModelConfig(
        dynamics=ContinuousSindyConfig(derivative_order=2, order=3, include_sine=True),
        observation=AutoencoderConfig(latent_dim=1, encoder_kind="mlp", decoder_kind="mlp"))
    cfg = TrainConfig(model=model_cfg, lr=1e-4, weight_decay=0.0, batch_size=args.batch,
                      loss=LossWeights(lambda_pred_x=5e-4, lambda_pred_z=5e-5,
                                       lambda_l1=1e-5 / 12),
                      prune_below=0.1, prune_every=500, epochs=6002, refine_epochs=1001,
                      device=args.device)
    record = run_record(cfg, data)
    model, opt, gen = new_model(from_json(ModelConfig, record["model"], "model"), cfg,
                                torch.device(args.device))
    norm = Normalizer.from_dict(record["normalizer"])
    samples = derivative_samples(data.split("train"), norm, 2, cfg).to(args.device)
    x = samples.frames  # (N F, 3, 1, 51, 51)
    grads = Gradients(model, 1)
    times = []
    for k in range(args.steps + 1):
        idx = torch.randperm(len(x), generator=gen)[: args.batch].to(args.device)
        if args.device == "cuda":
            torch.cuda.synchronize()
        s = time.perf_counter()
        train_epoch(grads, opt, samples.pick(idx), cfg, args.batch, gen, 1)
        if args.device == "cuda":
            torch.cuda.synchronize()
        if k:  # the first step warms up
            times.append(time.perf_counter() - s)
    median = statistics.median(times)
    steps_per_epoch = -(-len(x) // args.batch)
    print(json.dumps({
        "device": args.device, "threads": args.threads, "train_frames": len(x),
        "batch": args.batch, "data_s": round(made, 2), "step_median_s": round(median, 4),
        "step_best_s": round(min(times), 4), "steps_per_epoch": steps_per_epoch,
        "epoch_s_at_median": round(median * steps_per_epoch, 2),
        # the published epoch: 100 trajectories of 500 frames, 50 steps of 1000
        "published_epoch_s": round(median * 50, 1),
        "published_run_h": round(median * 50 * 6002 / 3600, 1),
        "params": sum(p.numel() for p in model.parameters()),
    }))


if __name__ == "__main__":
    main()
