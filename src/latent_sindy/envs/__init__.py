"""The planar pushing world: a gymnasium environment around a PyBullet scene."""

from gymnasium.envs.registration import register, registry

from latent_sindy.envs.config import PAPER_GOAL, PAPER_START, CameraConfig, PushEnvConfig
from latent_sindy.envs.panda_push import PandaPushEnv

ENV_ID = "latent_sindy/PandaPush-v0"

if ENV_ID not in registry:
    register(id=ENV_ID, entry_point="latent_sindy.envs.panda_push:PandaPushEnv")

__all__ = ["ENV_ID", "PAPER_GOAL", "PAPER_START", "CameraConfig", "PandaPushEnv", "PushEnvConfig"]
