"""Control in latent space: MPPI over any latent model's batched ``step``, its costs, a planner
toward goal images, the world interface and the one closed loop every world runs through
(policies ``reset(goal, seed)`` and ``act(observation)``, :mod:`.episodes`). The online
model-based loop that plans against a learned reward is :mod:`latent_sindy.model_based`.

>>> from latent_sindy.control import MPPI, MPPIConfig, latent_step
>>> mppi = MPPI(latent_step(model), z_goal, MPPIConfig())
>>> action, info = mppi.command(z)
"""

from latent_sindy.control.collect import collect_random
from latent_sindy.control.costs import ImageCost, LatentCost, PoseCost, RewardCost, StateCost
from latent_sindy.control.episodes import (
    Episode,
    ImagePolicy,
    Observation,
    Policy,
    run_closed_loop,
    run_episode,
    run_loop,
    success_rates,
)
from latent_sindy.control.mppi import MPPI, DynamicsStep, MPPIConfig, MPPIInfo, latent_step
from latent_sindy.control.planner import ImagePlanner
from latent_sindy.control.sindy_step import SindyKernelStep
from latent_sindy.control.world import Task, World

__all__ = [
    "MPPI",
    "DynamicsStep",
    "Episode",
    "ImageCost",
    "ImagePlanner",
    "ImagePolicy",
    "LatentCost",
    "MPPIConfig",
    "MPPIInfo",
    "Observation",
    "Policy",
    "PoseCost",
    "RewardCost",
    "SindyKernelStep",
    "StateCost",
    "Task",
    "World",
    "collect_random",
    "latent_step",
    "run_closed_loop",
    "run_episode",
    "run_loop",
    "success_rates",
]
