"""Learned models: latent dynamics (SINDy, linear, MLP) behind one ``step``/``rollout`` interface,
the image autoencoder, and the latent model joining them with the training loss.

>>> from latent_sindy.models import LinearConfig
>>> LinearConfig().build(nz=16, nu=3).step(torch.zeros(8, 16), torch.zeros(8, 3)).shape
torch.Size([8, 16])
"""

from latent_sindy.models.autoencoder import Autoencoder, AutoencoderConfig
from latent_sindy.models.dynamics import (
    DYNAMICS_CONFIGS,
    DYNAMICS_KINDS,
    DynamicsConfig,
    LatentDynamics,
    LinearConfig,
    LinearDynamics,
    MlpConfig,
    MlpDynamics,
    SindyConfig,
    SindyDynamics,
    SparseDynamics,
    SparseSindyDynamics,
    make_dynamics,
)
from latent_sindy.models.latent_model import (
    ENCODER_CONFIGS,
    LOSS_TERMS,
    EncoderConfig,
    LatentModel,
    LossWeights,
    ModelConfig,
)
from latent_sindy.models.state import StateConfig

__all__ = [
    "DYNAMICS_CONFIGS",
    "DYNAMICS_KINDS",
    "ENCODER_CONFIGS",
    "LOSS_TERMS",
    "Autoencoder",
    "AutoencoderConfig",
    "DynamicsConfig",
    "EncoderConfig",
    "LatentDynamics",
    "LatentModel",
    "LinearConfig",
    "LinearDynamics",
    "LossWeights",
    "MlpConfig",
    "MlpDynamics",
    "ModelConfig",
    "SindyConfig",
    "SindyDynamics",
    "SparseDynamics",
    "SparseSindyDynamics",
    "StateConfig",
    "make_dynamics",
]
