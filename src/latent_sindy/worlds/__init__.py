"""Worlds: the systems latent-sindy learns and controls, each a plug-in of the world interface.

``push`` is the Panda pushing world (PyBullet). A world package may import the core; the core
never imports a world.
"""
