"""latent-sindy: sparse, interpretable latent dynamics learned from images, for pushing.

Importing the package registers the gymnasium environment ``latent_sindy/PandaPush-v0``.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("latent-sindy")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+unknown"

from latent_sindy import envs  # noqa: F401  (registers the environment)
