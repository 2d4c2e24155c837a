"""What a pixel latent of a DeepMind Control task holds, and what it plans: one fit on random
episodes, a probe of the latent against the physics state, then test episodes planned by
MPPI against the learned reward beside random actions from the same starts.

The probe (the state is used here only to measure, never to train): a quadratic least-squares
map from the encoded latent to the state's features (cart position, cos and sin of the pole
angle, both velocities for the cartpole: each free hinge as cos and sin), fitted on the
training episodes and scored by R² on the validation ones (1: the latent holds that feature;
0: no better than its mean).

    python benchmarks/dmc_pixel_probe.py                               # 32x32, no weighting
    python benchmarks/dmc_pixel_probe.py --foreground-weight 10 --size 64 --epochs 40
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
import torch


def state_features(states: np.ndarray, periods: tuple) -> np.ndarray:
    cols = []
    for i, period in enumerate(periods):
        if period is None:
            cols.append(states[..., i])
        else:
            angle = 2 * math.pi * states[..., i] / period
            cols += [np.cos(angle), np.sin(angle)]
    return np.stack(cols, -1)


def quadratic(z: np.ndarray) -> np.ndarray:
    n = z.shape[-1]
    cols = [np.ones(z.shape[:-1]), *(z[..., i] for i in range(n)),
            *(z[..., i] * z[..., j] for i in range(n) for j in range(i, n))]
    return np.stack(cols, -1).reshape(-1, len(cols))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--task", default="cartpole-swingup")
    p.add_argument("--size", type=int, default=32)
    p.add_argument("--episodes", type=int, default=12, help="random episodes (every 6th "
                   "validates)")
    p.add_argument("--epochs", type=int, default=60)
    p.add_argument("--foreground-weight", type=float, default=0.0)
    p.add_argument("--lambda-reward", type=float, default=1.0, help="weight of the reward "
                   "head's error")
    p.add_argument("--latent-dim", type=int, default=6)
    p.add_argument("--encoder", default="conv", help="conv, keypoints, moments, ...")
    p.add_argument("--decoder", default=None, help="default: the encoder's kind where it is "
                   "a decoder's too, else sprite")
    p.add_argument("--samples", type=int, default=1000)
    p.add_argument("--lambda", dest="lambda_", type=float, default=0.1)
    p.add_argument("--evaluations", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--data", type=Path, default=None, help="cache of the random episodes")
    args = p.parse_args(argv)
    torch.set_num_threads(1)

    from latent_sindy import LatentSINDy
    from latent_sindy.control import MPPIConfig
    from latent_sindy.data import read_sequences, write_sequences
    from latent_sindy.models import AutoencoderConfig, LossWeights, ModelConfig, SindyConfig
    from latent_sindy.worlds.dmc.config import DmcConfig
    from latent_sindy.worlds.dmc.world import DmcWorld

    world = DmcWorld(DmcConfig(task=args.task, size=args.size, frames=2))
    steps = 1000 // world.config.action_repeat
    if args.data is not None and args.data.is_file():
        data = read_sequences(args.data)
    else:
        t0 = time.perf_counter()
        data = world.collect(args.episodes, steps, seed=args.seed)
        data = data.replace(split=(np.arange(data.n) % 6 == 5).astype(np.uint8))
        print(f"collected {data.n} random episodes in {time.perf_counter() - t0:.0f} s")
        if args.data is not None:
            write_sequences(args.data, data)
    decoder = args.decoder or (args.encoder if args.encoder in ("fc", "conv", "mlp")
                               else "sprite")
    model = ModelConfig(dynamics=SindyConfig(order=2, include_sine=True), reward_head=64,
                        observation=AutoencoderConfig(latent_dim=args.latent_dim,
                                                      encoder_kind=args.encoder,
                                                      decoder_kind=decoder))
    est = LatentSINDy(model=model, seed=args.seed,
                      loss=LossWeights(foreground_weight=args.foreground_weight,
                                       lambda_reward=args.lambda_reward))
    t0 = time.perf_counter()
    est.fit(data, epochs=args.epochs, window=4, batch_size=32)
    print(f"{args.task} {args.size}x{args.size}, foreground weight {args.foreground_weight}, "
          f"reward weight {args.lambda_reward}, latent {args.latent_dim}: fit "
          f"{time.perf_counter() - t0:.0f} s, "
          f"{int(np.count_nonzero(est.coefficients()))} active terms")

    z = est.encode(data.images.reshape(-1, *data.images.shape[2:]))
    z = np.asarray(z).reshape(data.n, -1, args.latent_dim)
    f = state_features(data.states, data.state_periods)
    train, val = data.split_ids == 0, data.split_ids == 1
    w = np.linalg.lstsq(quadratic(z[train]), f[train].reshape(-1, f.shape[-1]), rcond=None)[0]
    truth = f[val].reshape(-1, f.shape[-1])
    r2 = 1 - ((quadratic(z[val]) @ w - truth) ** 2).sum(0) / (
        (truth - truth.mean(0)) ** 2).sum(0)
    names = [n for n, q in zip(data.state_names, data.state_periods, strict=True)
             for n in ([n] if q is None else [f"cos {n}", f"sin {n}"])]
    print("probe R² on the validation episodes: "
          + ", ".join(f"{n} {v:.2f}" for n, v in zip(names, r2, strict=True)))

    cfg = MPPIConfig(samples=args.samples, horizon=12, sigma=0.3, lambda_=args.lambda_,
                     shift="repeat")
    env, rng = world.make_env(), np.random.default_rng(args.seed)
    for kind in ("planned", "random"):
        returns = []
        for e in range(args.evaluations):
            planner = est.planner(cfg, seed=e, objective="reward")
            planner.reset(None, e)
            obs, _ = env.reset(seed=1000 + e)
            total = 0.0
            for _ in range(steps):
                u = (planner.act(obs) if kind == "planned"
                     else rng.uniform(world.action_low, world.action_high))
                obs, r, *_ = env.step(np.asarray(u, np.float32))
                total += r
            returns.append(total)
        print(f"{kind:8s} test episodes: {', '.join(f'{r:.1f}' for r in returns)} "
              f"(mean {np.mean(returns):.1f})")
    env.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
