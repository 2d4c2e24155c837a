"""MPPI closes the loop on the real pushing environment, with the simulator itself as the model.

The state is the block's pose (x, y, θ); the model's batched step replays every sample's push
in a second simulator (reset to the sample's pose, push, read the pose), so K and H are tiny.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from latent_sindy.control import MPPI, LatentCost, MPPIConfig
from latent_sindy.worlds.push.panda_push import PandaPushEnv
from latent_sindy.worlds.push.world import PushWorld

pytestmark = pytest.mark.slow


@pytest.mark.parametrize(
    ("start", "goal"),
    [((0.58, 0.08, 0.3), (0.7, 0.0, 0.0)), ((0.5, -0.05, -0.4), (0.62, 0.02, 0.0))],
)
def test_simulator_model_pushes_block_to_goal(start, goal) -> None:
    env, model_world = PandaPushEnv(), PushWorld()

    def simulate(z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """z (K, 3) poses, u (K, 3) pushes -> (K, 3) poses after the pushes."""
        out = []
        for pose, action in zip(z.tolist(), u.tolist(), strict=True):
            model_world.reset(pose, goal)
            model_world.push(*action)
            out.append(model_world.block_pose())
        return torch.tensor(np.array(out), dtype=z.dtype)

    try:
        _, info = env.reset(seed=0, options={"start": start, "goal": goal})
        assert 0.13 < info["distance"] < 0.15 and not info["is_success"]
        cost = LatentCost(torch.tensor(goal), Q=(1.0, 1.0, 0.0))  # position: the course criterion
        # H = 1: "repeat" carries the last plan over as the next nominal (warm start).
        cfg = MPPIConfig(samples=12, horizon=1, sigma=(0.1, 0.3, 0.1), lambda_=0.001,
                         u_init=(0.0, 0.0, 0.5), shift="repeat")
        mppi = MPPI(simulate, cost, cfg, env.config.action_low, env.config.action_high, seed=0)
        distances = [info["distance"]]
        for _ in range(4):
            u, plan = mppi.command(torch.tensor(info["pose"]))
            assert plan.discarded == 0
            _, _, terminated, _, info = env.step(u.numpy())
            distances.append(info["distance"])
            assert not terminated
            if info["is_success"]:
                break
        assert info["is_success"], f"distances to the goal: {distances}"
        assert distances[-1] < distances[0] - 0.05
    finally:
        env.close()
        model_world.close()
