"""Latent SINDy on data of your own: write it with h5py, fit, read the equations, plan.

The system: a bright disc on a plain background, moved by a 2-D velocity command and seen by
a 20x28 RGB camera. Nothing here is latent-sindy's but the last half: any images and actions
in the documented layout (docs/data.md) go the same way.

    python examples/own_data.py                 # about a minute and a half on 2 CPU cores
    python examples/own_data.py --epochs 2      # a smoke run
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import h5py
import numpy as np

from latent_sindy import LatentSINDy
from latent_sindy.control import MPPIConfig
from latent_sindy.data import read_sequences

H, W = 20, 28
SPEED = 0.2  # the disc moves SPEED * u per step


# ----------------------------------------------------------------------------- 1. the system
def render(p: np.ndarray) -> np.ndarray:
    """The camera image (3, H, W) uint8 of the disc at p = (x, y) in [-1, 1]²."""
    ys, xs = np.meshgrid(np.linspace(-1, 1, H), np.linspace(-1, 1, W), indexing="ij")
    disc = np.exp(-((xs - p[0]) ** 2 + (ys - p[1]) ** 2) / 0.2)
    return np.stack([40 + 215 * disc, 60 + 120 * disc, 90 + 30 * disc]).astype(np.uint8)


def move(p: np.ndarray, u: np.ndarray) -> np.ndarray:
    return np.clip(p + SPEED * np.clip(u, -1, 1), -0.8, 0.8)


# ----------------------------------------------------------------------------- 2. the data
def write_data(path: Path, sequences: int = 48, steps: int = 6, seed: int = 0) -> None:
    """Random velocity commands from random starts, written with h5py alone."""
    rng = np.random.default_rng(seed)
    images = np.zeros((sequences, steps + 1, 3, H, W), np.uint8)  # (N, T+1, C, H, W)
    actions = rng.uniform(-1, 1, (sequences, steps, 2)).astype(np.float32)  # (N, T, nu)
    for i in range(sequences):
        p = rng.uniform(-0.7, 0.7, 2)
        images[i, 0] = render(p)
        for t in range(steps):
            p = move(p, actions[i, t])
            images[i, t + 1] = render(p)
    with h5py.File(path, "w") as f:
        f["images"], f["actions"] = images, actions
        f.attrs["action_low"], f.attrs["action_high"] = [-1.0, -1.0], [1.0, 1.0]
        f.attrs["action_names"] = ["vx", "vy"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--epochs", type=int, default=300)
    parser.add_argument("--out", type=Path, default=None, help="run folder to save into")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="latent-sindy-example-"))
    write_data(work / "disc.h5")

    # ------------------------------------------------------------------------- 3. the model
    data = read_sequences(work / "disc.h5")  # (a split is drawn by seed: none was given)
    print(f"{data.n} sequences of {data.steps} steps, frames {data.frame_shape}, "
          f"splits {data.split_counts()}")
    model = LatentSINDy(latent_dim=2, seed=0)  # the defaults: nothing tuned to this system
    model.fit(data, epochs=args.epochs)

    # ------------------------------------------------------------------------- 4. equations
    print("\nthe latent dynamics found:")
    model.print()
    print(f"one-step R² on the test split: {model.score(data):.3f}")
    test = data.split("test")
    x, u = test.images[:, 0], test.actions[:, 0]
    still = np.mean((x - test.images[:, 1].astype(float)) ** 2)
    moved = np.mean((model.predict(x, u) - test.images[:, 1]) ** 2)
    print(f"one-step image error {moved:.1f} against {still:.1f} for 'nothing moves'")

    # ------------------------------------------------------------------------- 5. planning
    planner = model.planner(MPPIConfig(samples=200, horizon=4, sigma=0.5))
    start, goal = np.array([-0.6, -0.5]), np.array([0.5, 0.6])
    p, goal_image = start.copy(), render(goal)
    steps = 0
    while steps < 12 and np.linalg.norm(p - goal) >= 0.1:
        p, steps = move(p, planner.act(render(p), goal_image)), steps + 1
    print(f"\nplanning from {start} to {goal}: after {steps} steps the disc is "
          f"{np.linalg.norm(p - goal):.3f} from the goal (it started "
          f"{np.linalg.norm(start - goal):.3f} away)")
    if args.out is not None:
        print(f"saved {model.save(args.out)} (LatentSINDy.load reads it back)")


if __name__ == "__main__":
    main()
