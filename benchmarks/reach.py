"""How many random pushes the arm can make, and how long the reach answer takes.

Each push: a block pose uniform in a region (the sampling workspace, or all of the table the
episode allows, ``bounds``) with theta uniform in [-pi, pi], and an action uniform in the
world's box. The arm's search for the push's start (``PushWorld.push_start``: the search a push
makes, and the closed loop's reach answer) says whether it would be made; nothing is
simulated. ``--hand-tilts`` replaces the arm's postures (``arm.HAND_TILTS``) to compare with
earlier ones.

    PYTHONPATH=src python benchmarks/reach.py --world symmetric --pushes 300 --seed 0
    PYTHONPATH=src python benchmarks/reach.py --hand-tilts 0 0.15    # the arm before issue 24
    PYTHONPATH=src python benchmarks/reach.py --smoke   # 12 pushes a region (the tests)
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from latent_sindy.script_args import parse_with_smoke
from latent_sindy.worlds.push import arm
from latent_sindy.worlds.push import world as world_module
from latent_sindy.worlds.push.config import PushEnvConfig
from latent_sindy.worlds.push.episodes import wilson_interval
from latent_sindy.worlds.push.world import PushWorld


def rate(k: int, n: int) -> str:
    lo, hi = wilson_interval(k, n)
    return f"{100 * k / n:5.1f} % [{100 * lo:.1f}, {100 * hi:.1f}] ({k}/{n})" if n else "n/a"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--world", default="symmetric", choices=["symmetric", "paper", "marked"])
    ap.add_argument("--pushes", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--hand-tilts", type=float, nargs="+", default=None)
    ap.add_argument("--max-start-distance", type=float, default=None,
                    help="try starts up to this far from the base (default: the arm's)")
    args = parse_with_smoke(ap, argv, {"pushes": 12})
    if args.hand_tilts is not None:
        arm.HAND_TILTS = tuple(args.hand_tilts)
    if args.max_start_distance is not None:
        world_module.MAX_START_DISTANCE = args.max_start_distance
    cfg = PushEnvConfig.named(args.world)
    world = PushWorld(cfg)
    print(f"world {args.world}, hand tilts {arm.HAND_TILTS}, starts tried up to "
          f"{world_module.MAX_START_DISTANCE} m, {args.pushes} pushes per region, seed {args.seed}")
    # (x, y) boxes, and "far": 0.72-0.9 m from the base within 0.6 rad of its x axis
    regions = {"workspace": (cfg.workspace_low[:2], cfg.workspace_high[:2]),
               "bounds": (cfg.bounds_low, cfg.bounds_high), "far": None}
    for k, (name, box) in enumerate(regions.items()):
        rng = np.random.default_rng([args.seed, k])
        made, dist, ms, reach = [], [], [], []
        for _ in range(args.pushes):
            if box is None:
                r, bearing = rng.uniform(0.72, 0.9), rng.uniform(-0.6, 0.6)
                xy = r * np.array([np.cos(bearing), np.sin(bearing)])
            else:
                xy = rng.uniform(*box)
            pose = np.array([*xy, rng.uniform(-np.pi, np.pi)])
            action = rng.uniform(cfg.action_low, cfg.action_high)
            t0 = time.perf_counter()
            start = world.push_start(action[0], action[1], pose=pose)
            ms.append(1e3 * (time.perf_counter() - t0))
            made.append(start is not None)
            if start is not None:
                reach.append(np.hypot(*start))
            dist.append(np.hypot(*pose[:2]))
        made, dist, ms = np.array(made), np.array(dist), np.array(ms)
        bands = [(0.0, 0.4), (0.4, 0.7), (0.7, 9.0)]
        by_band = "  ".join(f"r {a:.1f}-{b:.1f} m: {rate(int(made[m].sum()), int(m.sum()))}"
                            for a, b in bands if (m := (dist >= a) & (dist < b)).any())
        print(f"{name:10s} made {rate(int(made.sum()), len(made))}\n  {by_band}\n"
              f"  reach answer {ms[made].mean():.1f} ms (made), "
              f"{ms[~made].mean() if (~made).any() else float('nan'):.1f} ms (out of reach); "
              f"starts made {min(reach):.3f}-{max(reach):.3f} m from the base")
    world.close()


if __name__ == "__main__":
    main()
