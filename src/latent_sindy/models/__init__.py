"""Learned models: latent dynamics (SINDy, linear, MLP) behind one ``step``/``rollout`` interface.

>>> from latent_sindy.models import make_dynamics
>>> make_dynamics("linear", nz=16, nu=3).step(torch.zeros(8, 16), torch.zeros(8, 3)).shape
torch.Size([8, 16])
"""

from latent_sindy.models.dynamics import (
    DYNAMICS_KINDS,
    LatentDynamics,
    LinearDynamics,
    MlpDynamics,
    SindyDynamics,
    SparseSindyDynamics,
    make_dynamics,
)

__all__ = [
    "DYNAMICS_KINDS",
    "LatentDynamics",
    "LinearDynamics",
    "MlpDynamics",
    "SindyDynamics",
    "SparseSindyDynamics",
    "make_dynamics",
]
