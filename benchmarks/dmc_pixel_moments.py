"""Cartpole-swingup from pixels with nothing learned in the encoder: the pose of the coloured
object that differs from the background, read by image moments, its change between the two
stacked frames, and the action held between them; SINDy (trimmed) and a reward head on that
latent, MPPI against the head. Where the pixel latents stand against the physics state
(``dmc_states.py``) once the encoder is not the question.

Per seed: random-action episodes of 64×64 RGB frames (``--size``; two stacked, repeat 8).
The latent is read by the dmc world's :class:`~latent_sindy.worlds.dmc.reader.ColourPoseReader`
fitted on the training frames (background, the object's colour; the mode of the colour's
weight is the cart, the direction from it to the rest of the weight the pole's angle φ): the
mode's x, (cos φ, sin φ), the changes of both over the last control step per second, and
the action held over it (without it, a change between two frames is not a state:
``dmc_states.py --velocity difference``). Rows where the object is out of view (the
reader's ``seen``: the mode's peak below half its median, or in the outer eighth of the
image's width) are left out of the fits. With ``--smooth`` the training episodes' positions
(x, φ) are smoothed over that many frames before the fits (the changes taken again from
them; frames near one out of view left out too): the error of a camera spoils a one-step fit
(``dmc_states.py --position-noise``); the planner still reads the raw frames. With
``--window`` the fit is the windowed one instead (each latent's change over that many steps
against the library summed over them, windows whose frames are all in view:
``SindyDynamics.fit_trajectory_data``), where a frame's error enters at a window's two ends
only; ``--turn`` turns (cos φ, sin φ) by one equation's angle; ``--prune-ties`` leaves out
the terms with sin² φ. ``--gain`` filters what the planner reads through the model as the
library's read-latent planner does (``auto``: the gain chosen on the training episodes);
``--edge`` moves the reader's seen limit; ``--iterations`` gives MPPI several updates a
command. The reader finds the cart's edges and the pole's pivot (the reader's default);
``--box-reader`` reads as the rows recorded before it did (the centroid of the cart's box),
``--mode-reader`` as the rows before those (the colour's mode).
Prints the share of those rows, the probe of φ against the physics angle (only to measure),
each seed's planned returns beside random actions' from the same starts, and the mean.

    python benchmarks/dmc_pixel_moments.py                                   # 5 seeds
    python benchmarks/dmc_pixel_moments.py --smooth 5                        # smoothed fit
    python benchmarks/dmc_pixel_moments.py --window 5 --episodes 60          # windowed fit
    python benchmarks/dmc_pixel_moments.py --seeds 0 --episodes 10 --evaluations 2
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).parent))
from dmc_states import PUBLISHED, fit_reward, smoothed


def smoothed_latent(z: torch.Tensor, window: int, dt: float) -> torch.Tensor:
    """An episode's latents z (T+1, 6) with the positions (x, φ) smoothed over ``window``
    frames (``dmc_states.smoothed``) and the changes taken again from the smoothed ones."""
    phi = np.unwrap(np.arctan2(z[:, 2].numpy(), z[:, 1].numpy()))
    q = smoothed(np.stack([z[:, 0].numpy(), phi], -1), window)
    change = np.diff(q, axis=0, prepend=q[:1]) / dt
    out = z.clone()
    out[:, 0], out[:, 1], out[:, 2] = (torch.from_numpy(q[:, 0]), torch.from_numpy(np.cos(q[:, 1])),
                                       torch.from_numpy(np.sin(q[:, 1])))
    out[:, 3], out[:, 4] = torch.from_numpy(change[:, 0]), torch.from_numpy(change[:, 1])
    return out


def held_phase(trace: np.ndarray, repeat: int) -> str:
    """One planned episode from its physics: (reward, |u|, x, angle) a command."""
    r, u, x, angle = trace.T
    up = np.cos(angle) > 0.95
    if not up.any():
        return f"return {r.sum():.1f}: the pole never stood"
    first = int(np.argmax(up))
    return (f"return {r.sum():.1f}: the pole first up at {first * repeat} environment steps "
            f"(reward {r[:first].sum():.1f} before), then up {up[first:].mean():.0%} of the "
            f"time, reward {r[first:].mean() / repeat:.3f} a step, cart |x| "
            f"{np.abs(x[first:]).mean():.2f} m, |u| {u[first:].mean():.2f}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    p.add_argument("--episodes", type=int, default=30, help="random episodes to fit on")
    p.add_argument("--evaluations", type=int, default=4, help="planned episodes a seed")
    p.add_argument("--size", type=int, default=64, help="frame side in pixels")
    p.add_argument("--order", type=int, default=3, help="SINDy's polynomial order")
    p.add_argument("--min-share", type=float, default=0.01, help="STLSQ's threshold")
    p.add_argument("--trim", type=float, default=0.3, help="share of rows left out")
    p.add_argument("--smooth", type=int, default=0, metavar="WINDOW", help="smooth the "
                   "training episodes' positions over this many frames (odd) before the fits")
    p.add_argument("--window", type=int, default=1, metavar="STEPS", help="fit each "
                   "latent's change over this many steps to the library summed over them "
                   "(windows whose frames are all in view): a camera's error averages out")
    p.add_argument("--turn", action="store_true", help="the model turns (cos φ, sin φ) by an "
                   "angle its first equation gives, instead of updating each")
    p.add_argument("--prune-ties", action="store_true", help="leave out the library's terms "
                   "with sin² φ (cos² + sin² = 1 makes them sums of others)")
    p.add_argument("--ensemble", type=int, default=0, metavar="MODELS", help="select SINDy's "
                   "terms by bagging (EnsembleSTLSQ of this many bootstrap fits, a term kept "
                   "where more than half kept it, then refitted on all rows); 0: one STLSQ")
    p.add_argument("--support", type=float, default=0.0, metavar="WEIGHT", help="MPPI's "
                   "reward less WEIGHT times how far a predicted latent lies outside the "
                   "range of the training latents in view (standardised units): plans stay "
                   "where the camera sees and the model has data; 0: none")
    p.add_argument("--support-only", type=int, nargs="+", default=None, metavar="I",
                   help="the support's penalty on these latent coordinates only (0: x)")
    p.add_argument("--samples", type=int, default=1000)
    p.add_argument("--horizon", type=int, default=12, help="MPPI's horizon (steps)")
    p.add_argument("--lambda", dest="lambda_", type=float, default=0.1)
    p.add_argument("--sigma", type=float, default=0.3, help="MPPI's noise variance")
    p.add_argument("--iterations", type=int, default=1, help="MPPI updates a command")
    p.add_argument("--mode-reader", action="store_true", help="read the cart at the colour's "
                   "mode (the reader's body=None), as the rows recorded before its box did")
    p.add_argument("--box-reader", action="store_true", help="read the cart at the centroid "
                   "of its box and the pole from there (the reader's edges=False), as the rows "
                   "recorded before the reader found the cart's edges did")
    p.add_argument("--edge", type=float, default=0.75, help="the reader sees the cart only "
                   "where its |x| (image coordinates, -1 to 1) is below this")
    p.add_argument("--trace", action="store_true", help="after each planned test episode, "
                   "print from the physics state when the pole first stood (cos > 0.95), the "
                   "reward a step after it, the cart's mean |x| and the mean |u| there")
    p.add_argument("--gain", default="1", help="the planner's filter gain: a number in "
                   "(0, 1] (1, the default: each reading as it is), or auto: chosen on the "
                   "training episodes as the library's ReadLatent does (filter_gain)")
    args = p.parse_args(argv)
    torch.set_num_threads(1)

    from latent_sindy.control.costs import RewardCost
    from latent_sindy.control.mppi import MPPI, MPPIConfig, latent_step
    from latent_sindy.control.read_latent import filter_gain, filter_step
    from latent_sindy.models import SindyConfig
    from latent_sindy.sindy import STLSQ, EnsembleSTLSQ, Trimmed
    from latent_sindy.worlds.dmc.config import DmcConfig
    from latent_sindy.worlds.dmc.reader import ColourPoseReader
    from latent_sindy.worlds.dmc.world import DmcWorld

    world = DmcWorld(DmcConfig(task="cartpole-swingup", size=args.size, frames=2))
    steps, size = 1000 // world.config.action_repeat, world.config.size
    mppi_cfg = MPPIConfig(samples=args.samples, horizon=args.horizon, sigma=args.sigma,
                          lambda_=args.lambda_, shift="repeat", iterations=args.iterations)
    print(f"cartpole-swingup from {size}x{size} pixels (two frames, repeat 8): "
          f"{args.episodes} random episodes ({args.episodes * 1000} environment steps) a "
          f"seed; latent: x, cos φ, sin φ, ẋ, φ̇ (frame differences), previous u; SINDy "
          f"order {args.order}, trimmed share {args.trim}; MPPI K {args.samples} H {args.horizon} "
          f"Σ {args.sigma} λ {args.lambda_}, {args.iterations} update(s) a command; reader "
          f"edge {args.edge}, filter gain {args.gain}")
    means = []
    for seed in args.seeds:
        t0 = time.perf_counter()
        data = world.collect(args.episodes, steps, seed=seed)
        dt = float(data.dt)
        images = torch.from_numpy(data.images)  # (E, T+1, 6, S, S)
        reader = ColourPoseReader(
            size, edge=args.edge, body=None if args.mode_reader else (4.0, 2.0),
            edges=not args.box_reader).fit(
            images[:, :, 3:].reshape(-1, 3, size, size))
        actions = torch.from_numpy(data.actions).double()
        read = [reader.episode(images[e], actions[e], dt) for e in range(data.n)]
        Z, seen = torch.stack([z for z, _ in read]), torch.stack([v for _, v in read])
        if args.smooth > 1:  # the fit's latents only; a frame near one out of view is out
            Z = torch.stack([smoothed_latent(z, args.smooth, dt) for z in Z])
            seen = -F.max_pool1d(-seen[:, None].double(), args.smooth, 1,
                                 args.smooth // 2)[:, 0] > 0.5
        rows = (seen[:, :-1] & seen[:, 1:]).reshape(-1)
        angle = np.arctan2(Z[..., 2].numpy(), Z[..., 1].numpy()) + math.pi / 2
        err = np.angle(np.exp(1j * (angle - data.states[..., 1])))[seen.numpy()]
        mean, sd = Z[seen].mean(0), Z[seen].std(0)
        mean[1:3], sd[1:3] = 0.0, 1.0  # (cos φ, sin φ) stay on the circle
        Zs = (Z - mean) / sd
        Zt = Zs[:, :-1].reshape(-1, 6)[rows]
        U = actions.reshape(-1, 1)[rows]
        R = torch.from_numpy(data.rewards).reshape(-1)[rows]
        head, share = fit_reward(Zt.float(), U.float(), R, 64, 3000, seed)
        model = SindyConfig(order=args.order, include_sine=False).build(
            6, 1, circle=(1, 2), turn=args.turn)
        if args.prune_ties:
            model.prune_circle_ties()
        inner = STLSQ(min_share=args.min_share)
        if args.ensemble:
            inner = EnsembleSTLSQ(inner, n_models=args.ensemble, z_min=0.0, seed=seed)
        model.fit_trajectory_data(Zs, actions, args.window, Trimmed(
            inner, share=args.trim), valid=seen,
            restrict_to_mask=args.prune_ties)
        with torch.no_grad():
            gain = float(args.gain) if args.gain != "auto" else filter_gain(
                model, Zs.float(), actions.float(), seen, (1, 2))[0]
        low, high = Zs[seen].min(0).values.float(), Zs[seen].max(0).values.float()
        if args.support_only is not None:
            free = [i for i in range(len(low)) if i not in args.support_only]
            low[free], high[free] = -math.inf, math.inf
        fit_s = time.perf_counter() - t0
        env, rng = world.make_env(), np.random.default_rng(seed)
        result = {}
        for kind in ("planned", "random"):
            returns = []
            for e in range(args.evaluations):
                obs, _ = env.reset(seed=10_000 + 100 * seed + e)
                mppi = MPPI(latent_step(model), RewardCost(head, (low, high), args.support),
                            mppi_cfg, [-1.0], [1.0], seed=seed * 1000 + e)
                u, total, zf, trace = np.zeros(1), 0.0, None, []
                for _ in range(steps):
                    if kind == "planned":
                        z, seen_now = reader.latent(torch.from_numpy(obs)[None],
                                                    torch.from_numpy(u)[None], dt)
                        zs = ((z[0] - mean) / sd).float()
                        if zf is not None and gain < 1.0:  # the library planner's filter
                            with torch.no_grad():
                                pred = model(zf[None], torch.from_numpy(u).float()[None])[0]
                            zs = filter_step(pred, zs, seen_now[0], gain, (1, 2))
                        if zf is not None or bool(seen_now[0]):
                            zf = zs
                        u = mppi.command(zs)[0].numpy()
                        u = u.astype(np.float64)
                    else:
                        u = rng.uniform(-1.0, 1.0, 1)
                    obs, r, *_ = env.step(u.astype(np.float32))
                    total += r
                    if args.trace and kind == "planned":
                        trace.append((r, abs(u[0]), *env.state()[:2]))
                returns.append(total)
                if args.trace and kind == "planned":
                    print("    " + held_phase(np.array(trace), world.config.action_repeat))
            result[kind] = returns
        env.close()
        means.append(float(np.mean(result["planned"])))
        print(f"seed {seed}: planned {', '.join(f'{r:.1f}' for r in result['planned'])} "
              f"(mean {means[-1]:.1f}), random actions {np.mean(result['random']):.1f}; "
              f"{model.n_active()} active terms; filter gain {gain}; "
              f"{rows.double().mean():.2f} of the rows in "
              f"view; angle error in view median {np.degrees(np.median(np.abs(err))):.1f}°, "
              f"90th percentile {np.degrees(np.percentile(np.abs(err), 90)):.1f}°; reward "
              f"error {share:.3f} of its variance; data and fits {fit_s:.0f} s, "
              f"{time.perf_counter() - t0:.0f} s in all", flush=True)
        if seed == args.seeds[0]:
            print("    latent: z0 x, z1 cos φ, z2 sin φ, z3 ẋ, z4 φ̇, z5 previous u "
                  "(standardised but z1, z2)")
            for line in model.equations():
                print("    " + line)
    sd_all = np.std(means, ddof=1) if len(means) > 1 else float("nan")
    print(f"mean return over {len(means)} seeds {np.mean(means):.1f} (sd {sd_all:.1f})")
    print("published at 100k environment steps (cartpole-swingup): "
          + "; ".join(f"{k} {v}" for k, v in PUBLISHED.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
