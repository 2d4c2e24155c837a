"""Cartpole-swingup from pixels with nothing learned in the encoder: the pose of the coloured
object that differs from the background, read by image moments, its change between the two
stacked frames, and the action held between them; SINDy (trimmed) and a reward head on that
latent, MPPI against the head. Where the pixel latents stand against the physics state
(``dmc_states.py``) once the encoder is not the question.

Per seed: random-action episodes of 64×64 RGB frames (``--size``; two stacked, repeat 8).
From the training frames: the background (per-pixel median) and the object's colour (the
mean direction of the 0.5% largest differences from it). A frame's weight map is the
squared positive part of its difference along that colour (a shadow, darker, weighs
nothing); its mode (the peak of the map blurred by σ 2 px, refined by mean shift in a
σ-2-px window; pixels of a 64×64 frame, scaled with the size) is the body the rest hangs
from, and the direction φ from the mode to the centroid of the weight farther than 4 px
from it is the turn of what hangs from it. The latent: the mode's x, (cos φ, sin φ), the
changes of both over the last control step per second, and the action held over it
(without it, a change between two frames is not a state: ``dmc_states.py --velocity
difference``). Rows where the object is out of view (the mode's peak below half its
median, or in the outer eighth of the image's width) are left out of the fits. With
``--smooth`` the training episodes' positions (x, φ) are smoothed over that many frames
before the fits (the changes taken again from them; frames near one out of view left out
too): the error of a camera spoils a one-step fit (``dmc_states.py --position-noise``); the
planner still reads the raw frames.
Prints the share of those rows, the probe of φ against the physics angle (only to measure),
each seed's planned returns beside random actions' from the same starts, and the mean.

    python benchmarks/dmc_pixel_moments.py                                   # 5 seeds
    python benchmarks/dmc_pixel_moments.py --smooth 5                        # smoothed fit
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


class ColourMoments:
    """Pose (x, y of the mode, cos φ, sin φ) and peak of the object in frames (B, 3, H, W),
    values in [0, 1]; see the module's description."""

    def __init__(self, size: int, sigma: float = 2.0, inner: float = 4.0) -> None:
        """``sigma`` and ``inner`` in pixels of a 64×64 frame (scaled with ``size``)."""
        from latent_sindy.models.encoders import image_coordinates

        self.xs, self.ys = image_coordinates(size, size)
        self.pixel = float(self.xs[1] - self.xs[0])
        self.sigma, self.inner = sigma * size / 64, inner * size / 64
        self.reach = math.ceil(3 * self.sigma)
        k = torch.arange(-self.reach, self.reach + 1, dtype=torch.float32)
        g = torch.exp(-k**2 / (2 * self.sigma**2))
        self.kernel = g / g.sum()

    def fit(self, frames: torch.Tensor) -> ColourMoments:
        self.background = frames.median(0).values
        d = frames[::3] - self.background
        n2 = d.square().sum(1)
        top = n2 > torch.quantile(n2.flatten()[::17], 0.995)
        colour = d.permute(0, 2, 3, 1)[top].mean(0)
        self.colour = colour / colour.norm()
        return self

    def _distance2(self, mx: torch.Tensor, my: torch.Tensor) -> torch.Tensor:
        """(B, H, W) squared distance of each pixel from the points (mx, my) (B,)."""
        return ((self.xs[None, None] - mx[:, None, None]) ** 2
                + (self.ys[None, :, None] - my[:, None, None]) ** 2)

    def __call__(self, frames: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        xs, ys, k = self.xs, self.ys, self.kernel
        w = torch.relu(((frames - self.background) * self.colour[:, None, None]).sum(1)) ** 2
        n = self.reach
        b = F.conv2d(F.conv2d(w[:, None], k.view(1, 1, 1, -1), padding=(0, n)),
                     k.view(1, 1, -1, 1), padding=(n, 0))[:, 0]
        peak, at = b.flatten(1).max(1)
        mx, my = xs[at % w.shape[2]], ys[at // w.shape[2]]
        for _ in range(5):
            r2 = self._distance2(mx, my)
            wg = w * torch.exp(-r2 / (2 * (self.sigma * self.pixel) ** 2))
            m = wg.sum((1, 2)).clamp_min(1e-12)
            mx, my = (wg.sum(1) * xs).sum(1) / m, (wg.sum(2) * ys).sum(1) / m
        r2 = self._distance2(mx, my)
        wo = w * (r2 > (self.inner * self.pixel) ** 2)
        m = wo.sum((1, 2)).clamp_min(1e-12)
        dx = ((wo.sum(1) * xs).sum(1) / m - mx).double()
        dy = ((wo.sum(2) * ys).sum(1) / m - my).double()
        # the unit vector in float64: rounded in float32, cos² + sin² = 1 would hold only to
        # 1e-7, and the regression fits that rounding with huge cancelling coefficients
        r = torch.hypot(dx, dy).clamp_min(1e-12)
        return torch.stack([mx.double(), my.double(), dx / r, dy / r], -1), peak


def latent(moments: ColourMoments, obs: torch.Tensor, previous: torch.Tensor, dt: float):
    """(B, 6) latent of stacked observations obs (B, 6, H, W) uint8 and the actions held
    between their frames previous (B, 1); and (B,) the current frame's peak."""
    x = obs.float() / 255
    now, peak = moments(x[:, 3:])
    before, _ = moments(x[:, :3])
    return pose_latent(now, before, previous, dt), peak


def pose_latent(now: torch.Tensor, before: torch.Tensor, previous: torch.Tensor, dt: float
                ) -> torch.Tensor:
    """(B, 6) latent from the poses (B, 4) of :class:`ColourMoments` of the current and the
    earlier frame and the actions held between them (B, 1)."""
    turn = torch.atan2(before[:, 2] * now[:, 3] - before[:, 3] * now[:, 2],
                       before[:, 2] * now[:, 2] + before[:, 3] * now[:, 3])
    z = torch.stack([now[:, 0], now[:, 2], now[:, 3], (now[:, 0] - before[:, 0]) / dt,
                     turn / dt], -1)
    return torch.cat([z, previous.double()], -1)


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
    p.add_argument("--samples", type=int, default=1000)
    p.add_argument("--lambda", dest="lambda_", type=float, default=0.1)
    args = p.parse_args(argv)
    torch.set_num_threads(1)

    from latent_sindy.control.costs import RewardCost
    from latent_sindy.control.mppi import MPPI, MPPIConfig, latent_step
    from latent_sindy.models import SindyConfig
    from latent_sindy.sindy import STLSQ, Trimmed
    from latent_sindy.worlds.dmc.config import DmcConfig
    from latent_sindy.worlds.dmc.world import DmcWorld

    world = DmcWorld(DmcConfig(task="cartpole-swingup", size=args.size, frames=2))
    steps, size = 1000 // world.config.action_repeat, world.config.size
    mppi_cfg = MPPIConfig(samples=args.samples, horizon=12, sigma=0.3, lambda_=args.lambda_,
                          shift="repeat")
    print(f"cartpole-swingup from {size}x{size} pixels (two frames, repeat 8): "
          f"{args.episodes} random episodes ({args.episodes * 1000} environment steps) a "
          f"seed; latent: x, cos φ, sin φ, ẋ, φ̇ (frame differences), previous u; SINDy "
          f"order {args.order}, trimmed share {args.trim}; MPPI K {args.samples} H 12 "
          f"λ {args.lambda_}")
    means = []
    for seed in args.seeds:
        t0 = time.perf_counter()
        data = world.collect(args.episodes, steps, seed=seed)
        dt = float(data.dt)
        images = torch.from_numpy(data.images)  # (E, T+1, 6, S, S)
        moments = ColourMoments(size).fit(images[:, :, 3:].reshape(-1, 3, size, size).float()
                                          / 255)
        actions = torch.from_numpy(data.actions).double()
        previous = torch.cat([torch.zeros_like(actions[:, :1]), actions], 1)
        zs, peaks = [], []
        for e in range(data.n):  # each frame read once: a frame's "before" is the last "now"
            now, p_e = moments(images[e, :, 3:].float() / 255)
            first, _ = moments(images[e, :1, :3].float() / 255)
            zs.append(pose_latent(now, torch.cat([first, now[:-1]]), previous[e], dt))
            peaks.append(p_e)
        Z, peak = torch.stack(zs), torch.stack(peaks)
        seen = (peak > 0.5 * peak.median()) & (Z[..., 0].abs() < 0.75)
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
        Zt, Zn = Zs[:, :-1].reshape(-1, 6)[rows], Zs[:, 1:].reshape(-1, 6)[rows]
        U = actions.reshape(-1, 1)[rows]
        R = torch.from_numpy(data.rewards).reshape(-1)[rows]
        head, share = fit_reward(Zt.float(), U.float(), R, 64, 3000, seed)
        model = SindyConfig(order=args.order, include_sine=False).build(6, 1, circle=(1, 2))
        model.fit_state_data(Zt, U, Zn, optimizer=Trimmed(STLSQ(min_share=args.min_share),
                                                          share=args.trim))
        fit_s = time.perf_counter() - t0
        env, rng = world.make_env(), np.random.default_rng(seed)
        result = {}
        for kind in ("planned", "random"):
            returns = []
            for e in range(args.evaluations):
                obs, _ = env.reset(seed=10_000 + 100 * seed + e)
                mppi = MPPI(latent_step(model), RewardCost(head), mppi_cfg, [-1.0], [1.0],
                            seed=seed * 1000 + e)
                u, total = np.zeros(1), 0.0
                for _ in range(steps):
                    if kind == "planned":
                        z, _ = latent(moments, torch.from_numpy(obs)[None],
                                      torch.from_numpy(u)[None], dt)
                        u = mppi.command(((z[0] - mean) / sd).float())[0].numpy()
                        u = u.astype(np.float64)
                    else:
                        u = rng.uniform(-1.0, 1.0, 1)
                    obs, r, *_ = env.step(u.astype(np.float32))
                    total += r
                returns.append(total)
            result[kind] = returns
        env.close()
        means.append(float(np.mean(result["planned"])))
        print(f"seed {seed}: planned {', '.join(f'{r:.1f}' for r in result['planned'])} "
              f"(mean {means[-1]:.1f}), random actions {np.mean(result['random']):.1f}; "
              f"{model.n_active()} active terms; {rows.double().mean():.2f} of the rows in "
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
