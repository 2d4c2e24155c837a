"""Learned models: latent dynamics (SINDy, linear, MLP) behind one ``step``/``rollout`` interface,
the image autoencoder (any image shape), and the latent model joining them with the training
loss. Nothing here knows a world: what a latent coordinate means comes from the config.

    dynamics/     one file per kind with its config (base: the interface, SparseDynamics)
    encoders.py   conv, keypoints, moments          decoders.py   fc, conv, sprite
    autoencoder.py  AutoencoderConfig + Autoencoder  state.py      the true state as latent
    autoencoder_parts.py  each encoder and decoder kind's own settings (tagged by kind)
    autoencoder_flags.py  the same settings flat: the command line's
    pose_head.py  a readout of the pose features     latent_model.py  ModelConfig, the loss
    continuous_model.py  the continuous-time model: its loss on frames and their derivatives
    costs.py      weights of a quadratic latent cost
    reward_head.py  r̂(z, u), a reward predicted along the latent rollout

>>> from latent_sindy.models import LinearConfig
>>> LinearConfig().build(nz=16, nu=3).step(torch.zeros(8, 16), torch.zeros(8, 3)).shape
torch.Size([8, 16])
"""

from latent_sindy.models.autoencoder import Autoencoder, AutoencoderConfig
from latent_sindy.models.continuous_model import ContinuousLatentModel
from latent_sindy.models.costs import cost_weights
from latent_sindy.models.dynamics import (
    DYNAMICS_CONFIGS,
    DYNAMICS_KINDS,
    CompiledSindy,
    DynamicsConfig,
    LatentDynamics,
    LinearConfig,
    LinearDynamics,
    MlpConfig,
    MlpDynamics,
    SindyConfig,
    SindyDynamics,
    SparseDynamics,
    make_dynamics,
)
from latent_sindy.models.latent_model import (
    LOSS_TERMS,
    OBSERVATION_CONFIGS,
    LatentModel,
    LossWeights,
    ModelConfig,
    ObservationConfig,
)
from latent_sindy.models.state import StateConfig

__all__ = [
    "DYNAMICS_CONFIGS",
    "DYNAMICS_KINDS",
    "LOSS_TERMS",
    "OBSERVATION_CONFIGS",
    "Autoencoder",
    "AutoencoderConfig",
    "CompiledSindy",
    "ContinuousLatentModel",
    "DynamicsConfig",
    "LatentDynamics",
    "LatentModel",
    "LinearConfig",
    "LinearDynamics",
    "LossWeights",
    "MlpConfig",
    "MlpDynamics",
    "ModelConfig",
    "ObservationConfig",
    "SindyConfig",
    "SindyDynamics",
    "SparseDynamics",
    "StateConfig",
    "cost_weights",
    "make_dynamics",
]
