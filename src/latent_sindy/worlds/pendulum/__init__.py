"""The pendulum worlds: the controlled pendulum seen by a camera, and the pendulum video.

``PendulumWorld`` (plug-in ``pendulum``) is gymnasium's Pendulum-v1 rendered to two stacked
48×48 frames, to swing up and balance; ``pendulum_video`` (plug-in ``pendulum-video``) is the
SINDy autoencoder's benchmark with exact image derivatives. Importing this package loads
neither gymnasium nor the environment; ``PendulumImageEnv`` loads when first asked for.
``study.compare_swing_ups`` fits image models and swings up with latent MPPI from images
(``python -m latent_sindy.worlds.pendulum.study --help``).

    from latent_sindy.worlds.pendulum import PendulumWorld, pendulum_video
    data = PendulumWorld().collect(sequences=100, steps=10, seed=0)
    video = pendulum_video(n_train=20, n_val=2, n_test=2, steps=100)
"""

from latent_sindy.worlds.pendulum.config import PendulumConfig
from latent_sindy.worlds.pendulum.criteria import swing_up_success, upright, upright_fraction
from latent_sindy.worlds.pendulum.plugin import VIDEO, WORLD
from latent_sindy.worlds.pendulum.video import pendulum_video
from latent_sindy.worlds.pendulum.world import PendulumWorld


def __getattr__(name: str):
    if name == "PendulumImageEnv":  # gymnasium loads only when the environment is asked for
        from latent_sindy.worlds.pendulum.env import PendulumImageEnv

        return PendulumImageEnv
    raise AttributeError(name)


__all__ = ["VIDEO", "WORLD", "PendulumConfig", "PendulumImageEnv", "PendulumWorld",
           "pendulum_video", "swing_up_success", "upright", "upright_fraction"]
