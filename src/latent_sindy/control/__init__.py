"""Control in latent space: MPPI over any latent model's batched ``step``, and its costs.

>>> from latent_sindy.control import MPPI, MPPIConfig, latent_step
>>> mppi = MPPI(latent_step(model), z_goal, MPPIConfig(nu=3))
>>> action, info = mppi.command(z)
"""

from latent_sindy.control.costs import ImageCost, LatentCost, PoseCost, StateCost
from latent_sindy.control.mppi import MPPI, DynamicsStep, MPPIConfig, MPPIInfo, latent_step
from latent_sindy.control.sindy_step import SparseSindyStep

__all__ = [
    "MPPI",
    "DynamicsStep",
    "ImageCost",
    "LatentCost",
    "MPPIConfig",
    "MPPIInfo",
    "PoseCost",
    "SparseSindyStep",
    "StateCost",
    "latent_step",
]
