"""latent-sindy: sparse, interpretable latent dynamics (SINDy) learned from images.

    from latent_sindy import LatentSINDy, SequenceData
    model = LatentSINDy(latent_dim=2, order=2).fit(SequenceData(images, actions, ...))

The core (``sindy``, ``models``, ``data``, ``training``, ``control``, ``api``) knows no world;
worlds (``latent_sindy.worlds``) plug in by name. Importing the package loads no simulator.
"""

from latent_sindy.version import __version__

__all__ = ["LatentSINDy", "Phase", "Restarts", "SequenceData", "UserError", "__version__"]


def __getattr__(name: str):
    # The estimator pulls in torch and the training stack: loaded when first asked for.
    if name == "LatentSINDy":
        from latent_sindy.api import LatentSINDy

        return LatentSINDy
    if name in ("Phase", "Restarts"):
        from latent_sindy.training import session

        return getattr(session, name)
    if name == "SequenceData":
        from latent_sindy.data import SequenceData

        return SequenceData
    if name == "UserError":
        from latent_sindy.errors import UserError

        return UserError
    raise AttributeError(f"module 'latent_sindy' has no attribute {name!r}")
