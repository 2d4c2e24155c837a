"""The pushing world's gymnasium registration: the environment id and :func:`register_env`,
without importing gymnasium until asked (the package and :mod:`.panda_push` both use it).

    import gymnasium as gym
    env = gym.make(register_env())
"""

ENV_ID = "latent_sindy/PandaPush-v0"

__all__ = ["ENV_ID", "register_env"]


def register_env() -> str:
    """Register the gymnasium environment (once); returns its id."""
    from gymnasium.envs.registration import register, registry

    if ENV_ID not in registry:
        register(id=ENV_ID, entry_point="latent_sindy.worlds.push.panda_push:PandaPushEnv")
    return ENV_ID
