"""The planar pushing world: a Franka Panda arm pushing a block, seen from above (PyBullet).

Importing this package loads neither PyBullet nor gymnasium; :func:`register_env` registers the
gymnasium environment ``latent_sindy/PandaPush-v0`` (done by :class:`PandaPushEnv`'s module).
"""

from latent_sindy.worlds.push.config import PAPER_GOAL, PAPER_START, CameraConfig, PushEnvConfig
from latent_sindy.worlds.push.registration import ENV_ID, register_env


def __getattr__(name: str):
    if name == "PandaPushEnv":  # the simulator loads only when the environment is asked for
        from latent_sindy.worlds.push.panda_push import PandaPushEnv

        return PandaPushEnv
    raise AttributeError(name)


__all__ = ["ENV_ID", "PAPER_GOAL", "PAPER_START", "CameraConfig", "PandaPushEnv",
           "PushEnvConfig", "register_env"]
