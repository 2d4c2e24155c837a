"""The DeepMind Control suite seen through its cameras (entry point ``dmc`` of
``latent_sindy.worlds``; needs the ``dmc`` extra: ``pip install 'latent-sindy[dmc]'``).

Any task of the suite by name (``cartpole-swingup``, ``reacher-easy``, ...), images of a side
you choose with the last frames stacked as channels, actions repeated as PlaNet did, the
task's own reward summed over the repeat, and the physics state as the true state.
:mod:`.reader` reads a cart-pole's (or any coloured body's with a part hanging from it) pose
from frames by image moments, nothing learned.

    latent-sindy collect --world dmc --world-config task=cartpole-swingup size=64 \\
        --trajectories 100 --steps 20 --out data/cartpole.h5
"""
