"""Any Gymnasium environment seen through its own ``rgb_array`` frames (entry point ``gym`` of
``latent_sindy.worlds``): ``gym.make(id, render_mode="rgb_array")``, each frame resized to a
square of a side you choose (optionally gray, the last frames stacked as channels), the
environment's own reward summed over an action's repeat, its observation vector as the true
state, and the model-based loop and study of the dmc world (:mod:`latent_sindy.study.model_based`)
against that reward. Classic-control rendering needs pygame: ``pip install
'latent-sindy[gym]'``. Importing this package does not import gymnasium.

    latent-sindy collect --world gym --world-config id=Pendulum-v1 size=64 \\
        --trajectories 10 --steps 200 --out data/pendulum.h5
    latent-sindy reproduce --world gym --world-config id=Pendulum-v1 --scale tiny --out /tmp/g
"""

from latent_sindy.worlds.gym.config import GymConfig
from latent_sindy.worlds.gym.world import GymWorld

__all__ = ["GymConfig", "GymWorld"]
