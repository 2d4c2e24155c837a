"""Collection speed: transitions per second with 1 and 2 workers, and render cost.

Prints, for this machine:
  * stored transitions per second of `collect` (wall clock, process start-up and discarded
    attempts included) with 1 and 2 workers;
  * ms per observation render in the camera-only world (what `observe` does) against the
    same image rendered in the full simulated scene (arm included), in one process;
  * ms per simulated push and per episode reset, and a reset (world rebuilt) with the arm's
    visual meshes loaded (as before) against without them (as now), interleaved.

    .venv/bin/python benchmarks/collect.py --trajectories 12 --steps 10
    .venv/bin/python benchmarks/collect.py --smoke      # tiny sizes, seconds (the tests)
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from latent_sindy.script_args import parse_with_smoke
from latent_sindy.worlds.push.collect import CollectionPlan, collect
from latent_sindy.worlds.push.panda_push import PandaPushEnv
from latent_sindy.worlds.push.world import PushWorld


def time_collection(trajectories: int, steps: int, workers: int) -> tuple[float, float]:
    plan = CollectionPlan(trajectories=trajectories, steps=steps, seed=0)
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        path = collect(Path(d) / "bench.h5", plan, workers=workers)
        wall = time.perf_counter() - t0
        from latent_sindy.data import read_sequences

        attempts = sum(read_sequences(path).record["collection"]["attempts"])
    return trajectories * steps / wall, attempts / trajectories


def time_renders(repeats: int) -> tuple[float, float]:
    w = PushWorld(arm_visuals=True)  # the full scene with the arm drawn
    w.reset((0.5, 0.0, 0.0), (0.7, 0.0, 0.0))
    w.observe()
    t0 = time.perf_counter()
    for _ in range(repeats):
        w.observe()
    fast = (time.perf_counter() - t0) / repeats * 1e3
    t0 = time.perf_counter()
    for _ in range(max(1, repeats // 20)):
        w.observe_full_scene()
    full = (time.perf_counter() - t0) / max(1, repeats // 20) * 1e3
    w.close()
    return fast, full


def time_rebuilds(n: int) -> tuple[float, float]:
    """ms per world rebuild with and without the arm's visual meshes (interleaved)."""
    worlds = {v: PushWorld(arm_visuals=v) for v in (True, False)}
    times: dict[bool, list[float]] = {True: [], False: []}
    for _ in range(n):
        for v, w in worlds.items():
            t0 = time.perf_counter()
            w.reset((0.5, 0.0, 0.0), (0.7, 0.0, 0.0))
            times[v].append(time.perf_counter() - t0)
    for w in worlds.values():
        w.close()
    return 1e3 * float(np.median(times[True])), 1e3 * float(np.median(times[False]))


def time_pushes(n: int) -> tuple[float, float, float]:
    env = PandaPushEnv()
    rng = np.random.default_rng(0)
    resets, pushes, steps = [], [], []
    for i in range(n):
        t0 = time.perf_counter()
        env.reset(seed=i, options={"start": (0.5, 0.0, 0.0)})
        resets.append(time.perf_counter() - t0)
        s0 = env.world.sim_steps
        t0 = time.perf_counter()
        env.step(rng.uniform(env.action_space.low, env.action_space.high))
        pushes.append(time.perf_counter() - t0)
        steps.append(env.world.sim_steps - s0)
    env.close()
    return 1e3 * float(np.mean(pushes)), 1e3 * float(np.mean(resets)), float(np.mean(steps))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trajectories", type=int, default=12)
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--render-repeats", type=int, default=400)
    ap.add_argument("--pushes", type=int, default=20, help="timed pushes and world rebuilds")
    args = parse_with_smoke(ap, argv, {"trajectories": 2, "steps": 2, "workers": [1],
                                       "render_repeats": 20, "pushes": 2})

    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}")
    push_ms, reset_ms, sim_steps = time_pushes(args.pushes)
    print(f"one push: {push_ms:.1f} ms ({sim_steps:.0f} simulation steps at 240 Hz); "
          f"one episode reset (world rebuilt): {reset_ms:.1f} ms")
    with_meshes, without = time_rebuilds(args.pushes)
    print(f"world rebuild: {with_meshes:.1f} ms with the arm's visual meshes, {without:.1f} ms "
          f"without (x{with_meshes / without:.1f} faster; median of {args.pushes}, "
          "interleaved)")
    fast, full = time_renders(args.render_repeats)
    print(f"observation render: {fast:.2f} ms camera world vs {full:.2f} ms full scene "
          f"(x{full / fast:.0f} faster)")
    print(f"\n{'workers':>8} {'transitions/s':>14} {'attempts/traj':>14}")
    base = None
    for w in args.workers:
        rate, attempts = time_collection(args.trajectories, args.steps, w)
        base = base or rate
        print(f"{w:>8} {rate:>14.1f} {attempts:>14.2f}   (x{rate / base:.2f} vs 1 worker)")


if __name__ == "__main__":
    main()
