"""How well the dmc world's :class:`~latent_sindy.worlds.dmc.reader.ColourPoseReader` reads the
cart-pole, against the physics state: the reader as it is (the cart's edges, the pole's pivot
fitted) beside ``edges=False`` (the centroid of the cart's box, the pivot at it).

Two sets of 64×64 frames (``--size``): random-action episodes of the task (the training
frames of the reader too), and a sweep of poses set by hand (the cart at five places, the
pole at every degree), where nothing moves between frames. Per reader: the share of frames
seen; the cart's x error in pixels (against the best line through the physics x, frames
both readers see); the angle's error (its median removed: a constant offset is a change of
coordinates, not an error) as median, 90th percentile and largest; the turn rate between
two frames against the physics angle's (rad/s); and, on the sweep, the error with the pole
upright at each cart place (what varies with the cart is what a model must fit).

    python benchmarks/dmc_reader_accuracy.py
    python benchmarks/dmc_reader_accuracy.py --episodes 30 --seed 0
    python benchmarks/dmc_reader_accuracy.py --smoke      # tiny sizes, seconds (the tests)
"""

from __future__ import annotations

import argparse
import math

import numpy as np
import torch

from latent_sindy.script_args import parse_with_smoke

PLACES = (-0.83, -0.31, 0.0, 0.17, 0.64)


def _sweep(world, step: int = 1) -> tuple[torch.Tensor, np.ndarray]:
    """Frames (N, 3, S, S) of the cart at PLACES and the pole at every ``step`` degrees;
    (N, 2) x, θ."""
    env = world.make_env()
    env.reset(seed=0)
    frames, poses = [], []
    for x in PLACES:
        for deg in range(-180, 180, step):
            state = env.state()
            state[:2] = (x, math.radians(deg))
            frames.append(env.picture_of(state)[-3:])
            poses.append((x, math.radians(deg)))
    env.close()
    return torch.from_numpy(np.stack(frames)), np.array(poses)


def _angle_error(pose: torch.Tensor, theta: np.ndarray) -> np.ndarray:
    """Degrees, the reader's φ (from the image's x axis) against the physics θ (from up)."""
    phi = np.arctan2(pose[:, 3].numpy(), pose[:, 2].numpy()) + math.pi / 2
    return np.degrees(np.angle(np.exp(1j * (phi - theta))))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--episodes", type=int, default=10, help="random episodes")
    p.add_argument("--seed", type=int, default=3)
    p.add_argument("--size", type=int, default=64)
    p.add_argument("--sweep-step", type=int, default=1, metavar="DEGREES",
                   help="the sweep's pole angles this many degrees apart")
    args = parse_with_smoke(p, argv, {"episodes": 1, "sweep_step": 30})
    torch.set_num_threads(1)

    from latent_sindy.worlds.dmc.config import DmcConfig
    from latent_sindy.worlds.dmc.reader import ColourPoseReader
    from latent_sindy.worlds.dmc.world import DmcWorld

    world = DmcWorld(DmcConfig(task="cartpole-swingup", size=args.size, frames=2))
    data = world.collect(args.episodes, 1000 // world.config.action_repeat, seed=args.seed)
    E, T1 = data.images.shape[:2]
    frames = torch.from_numpy(data.images[:, :, 3:]).reshape(-1, 3, args.size, args.size)
    states = data.states.reshape(-1, data.states.shape[-1])
    sweep, poses = _sweep(world, args.sweep_step)
    print(f"cartpole-swingup, {args.size}x{args.size}: {len(frames)} frames of {E} random "
          f"episodes (seed {args.seed}); a sweep of {len(sweep)} poses")
    readers = {"edges (the default)": ColourPoseReader(args.size).fit(frames),
               "box (edges=False)": ColourPoseReader(args.size, edges=False).fit(frames)}
    read = {name: r.read(frames) for name, r in readers.items()}
    both = np.logical_and.reduce([s.numpy() for _, s in read.values()])
    for name, reader in readers.items():
        pose, seen = read[name]
        s = seen.numpy()
        x = pose[:, 0].numpy() / reader.pixel
        line = np.polyfit(states[both, 0], x[both], 1)
        x_err = np.abs(x[both] - np.polyval(line, states[both, 0]))
        a = _angle_error(pose, states[:, 1])[s]
        a = np.abs(a - np.median(a))
        phi = np.arctan2(pose[:, 3].numpy(), pose[:, 2].numpy()).reshape(E, T1)
        dt = float(data.dt)
        turn = np.angle(np.exp(1j * np.diff(phi, axis=1))) / dt
        truth = np.angle(np.exp(1j * np.diff(data.states[..., 1], axis=1))) / dt
        pair = s.reshape(E, T1)[:, 1:] & s.reshape(E, T1)[:, :-1]
        t_err = np.abs(turn[pair] - truth[pair] - np.median(turn[pair] - truth[pair]))
        sp, ss = reader.read(sweep)
        sa = _angle_error(sp, poses[:, 1])
        sa_c = np.abs(sa - np.median(sa))
        upright = np.abs(np.degrees(poses[:, 1])) <= 3
        by_place = [float(np.mean(sa[upright & (poses[:, 0] == x)])) for x in PLACES]
        extra = f"; pivot {reader.pivot[0]:.3f}, {reader.pivot[1] / reader.pixel:+.2f} px" \
            if reader.found_edges else ""
        print(f"{name}: seen {s.mean():.3f}{extra}\n"
              f"    random frames: x error {np.median(x_err):.3f} px median, "
              f"{np.percentile(x_err, 90):.3f} 90th pct, {x_err.max():.2f} largest; angle "
              f"error {np.median(a):.2f}°, {np.percentile(a, 90):.2f}°, {a.max():.1f}°; turn "
              f"rate error {np.median(t_err):.3f}, {np.percentile(t_err, 90):.3f}, "
              f"{t_err.max():.2f} rad/s\n"
              f"    sweep: seen {ss.double().mean():.3f}; angle error {np.median(sa_c):.2f}°, "
              f"{np.percentile(sa_c, 90):.2f}°, {sa_c.max():.2f}°; upright at x = "
              + ", ".join(f"{x:+.2f}: {e:+.2f}°" for x, e in zip(PLACES, by_place,
                                                               strict=True))
              + f" (spread {max(by_place) - min(by_place):.2f}°)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
