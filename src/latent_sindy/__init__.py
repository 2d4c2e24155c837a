"""latent-sindy: sparse, interpretable latent dynamics (SINDy) learned from images.

The core (``sindy``, ``models``, ``data``, ``training``, ``control``) knows no world; worlds
(``latent_sindy.worlds``) plug in. Importing the package loads no simulator: the pushing
world's gymnasium environment ``latent_sindy/PandaPush-v0`` registers when that world is used.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("latent-sindy")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+unknown"
