"""The planner each world is controlled with by default.

The paper's push (an angle in the block's frame) keeps the course's MPPI settings; pushes in
any world direction (the symmetric world) need more exploration of the angle: a variance of
1.0 on ψ reached 12 of 12 goals with a state model where 0.3 reached 4 (the retired
benchmarks/world_designs.py, docs/notes/2026-12-06-benchmarks-retired.md). The study and
``latent-sindy control`` both plan with :func:`world_planner` unless told otherwise.

    world_planner(PushEnvConfig.named("symmetric")).samples  # 300
"""

from __future__ import annotations

from latent_sindy.control.mppi import MPPIConfig
from latent_sindy.worlds.push.config import PushEnvConfig

__all__ = ["PLANNERS", "world_planner"]

#: The default planner per push style (:attr:`PushEnvConfig.push`).
PLANNERS: dict[str, MPPIConfig] = {
    "paper": MPPIConfig(),
    "symmetric": MPPIConfig(samples=300, horizon=8, sigma=(0.2, 1.0, 0.05)),
}


def world_planner(env: PushEnvConfig) -> MPPIConfig:
    """The planner of a world: by the meaning of its push action."""
    return PLANNERS[env.push]
