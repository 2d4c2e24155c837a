"""The pushing world's plug-in entry (``latent_sindy.worlds`` entry point ``push``).

Loading it registers what the core looks up by name (the push world's library presets and
derived variables) and provides :data:`WORLD`.
"""

WORLD = "push"  # replaced by the world object once the world interface lands
