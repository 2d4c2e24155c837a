"""Latent SINDy in the pushing world: a Panda arm pushes a block, seen by a 32x32 camera.

Collects random pushes in the PyBullet world, fits a latent SINDy model on the images, prints
its equations and pushes the block toward random goals with MPPI in the latent space, through
the same world interface any system of your own would implement.

    python examples/pushing.py                                     # minutes on 2 CPU cores
    python examples/pushing.py --trajectories 6 --steps 2 --epochs 1 --episodes 1 --max-steps 1
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from latent_sindy import LatentSINDy
from latent_sindy.control import ImagePolicy, run_closed_loop, success_rates
from latent_sindy.data import read_sequences
from latent_sindy.plugins import get_world
from latent_sindy.worlds.push.collect import CollectionPlan, collect


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trajectories", type=int, default=200)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--epochs", type=int, default=300)
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--max-steps", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()

    # ------------------------------------------------------------------------- 1. the data
    world = get_world("push")  # the symmetric pushing world (pushes from any face)
    path = Path(tempfile.mkdtemp(prefix="latent-sindy-push-")) / "push.h5"
    collect(path, CollectionPlan(args.trajectories, args.steps, seed=0, env=world.config),
            workers=args.workers)
    data = read_sequences(path)  # images, pushes (p, psi, ell), block poses as states
    print(f"{data.n} trajectories of {data.steps} pushes, splits {data.split_counts()}")

    # ------------------------------------------------------------------------- 2. the model
    model = LatentSINDy(latent_dim=16, order=2, seed=0).fit(data, epochs=args.epochs)
    lines = model.equations(precision=2)
    print(f"\nthe latent dynamics found (active terms only; first 3 of {len(lines)}):")
    print("\n".join(lines[:3]))
    print(f"one-step R² on the test split: {model.score(data):.3f}")

    # ------------------------------------------------------------------------- 3. control
    planner = model.planner(world.planner())  # the planner this world's study uses
    results = run_closed_loop(world, ImagePolicy(planner), episodes=args.episodes,
                              max_steps=args.max_steps, seed=0, until="course")
    for name, rate in success_rates(results).items():
        print(f"{name} criterion met in {rate:.0%} of {len(results)} random tasks")


if __name__ == "__main__":
    main()
