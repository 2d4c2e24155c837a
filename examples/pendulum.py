"""Latent SINDy on the pendulum seen by a camera: collect, fit, read the equations, swing up.

The world is gymnasium's Pendulum-v1 drawn as a rod, two consecutive frames stacked so the
rate is visible (latent_sindy.worlds.pendulum). Random torques from random starts give the
data; a latent SINDy model is fitted to the images; MPPI in its latent space then tries to
swing the pendulum up from hanging toward the goal image, upright at rest, with a cost that
is not flat at the bottom: the distance to the goal's code along the data's codes
(latent_sindy.worlds.pendulum.graph_cost). At this small size the model is rough, and the
swing-up is shown, not promised; the measured study is latent_sindy.worlds.pendulum.study.

    python examples/pendulum.py                        # about a minute on 2 CPU cores
    python examples/pendulum.py --epochs 1 --steps 20  # a smoke run
"""

from __future__ import annotations

import argparse

import numpy as np

from latent_sindy import LatentSINDy
from latent_sindy.training import TrainConfig
from latent_sindy.worlds.pendulum import PendulumConfig, PendulumWorld
from latent_sindy.worlds.pendulum.study import LatentSwingUp, StudyConfig
from latent_sindy.worlds.pendulum.swing_up import run_swing_up


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", type=int, default=80)
    parser.add_argument("--epochs", type=int, default=20)
    parser.add_argument("--image-size", type=int, default=32, help="the world's default: 48")
    parser.add_argument("--steps", type=int, default=100, help="steps of the swing-up")
    args = parser.parse_args()

    # ------------------------------------------------------------- 1. data: random torques
    world = PendulumWorld(PendulumConfig(start="random", image_size=args.image_size))
    data = world.collect(sequences=args.sequences, steps=6, seed=0)
    print(f"{data.n} sequences of {data.steps} steps, frames {data.frame_shape} "
          f"(the rod a step ago and now), states {data.state_names}")

    # ------------------------------------------------------------- 2. the model
    model = LatentSINDy(latent_dim=3, order=2, seed=0, settings=TrainConfig(lr=3e-3))
    model.fit(data, epochs=args.epochs, batch_size=32)
    print("\nthe latent dynamics found:")
    model.print()
    print(f"one-step R² on the test split: {model.score(data):.3f}")

    # ------------------------------------------------------------- 3. swing up from hanging
    hanging = PendulumWorld(PendulumConfig(start="hanging", image_size=args.image_size))
    codes = model.encode(data.split("train").images.reshape(-1, *data.frame_shape))
    settings = StudyConfig(samples=500, horizon=30, sigma=1.0, lambda_=0.3,
                           nodes=min(600, len(codes) - 1), neighbours=min(8, len(codes) - 2))
    policy = LatentSwingUp(model, codes, settings)  # reads the image only
    (episode,) = run_swing_up(hanging, policy, episodes=1, steps=args.steps,
                              last=min(20, args.steps))
    print(f"\nswing-up from θ = {episode.task.start[0]:.2f}: upright (within 10°) "
          f"{100 * episode.upright_fraction:.0f}% of {args.steps} steps, highest point "
          f"|θ| = {np.abs(episode.states[:, 0]).min():.2f} rad, "
          f"success {episode.success}")


if __name__ == "__main__":
    main()
