"""The installed package's version (written into every data file and run folder)."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("latent-sindy")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+unknown"
