"""Sparse identification of nonlinear dynamics (SINDy) parts: the candidate library and fitting.

``latent_sindy.sindy.library`` holds the differentiable library Θ(z, u);
``latent_sindy.sindy.fit`` fits a SINDy dynamics model to state data (import it by its module
path: it depends on ``latent_sindy.models``, which depends on this package).

    >>> from latent_sindy.sindy import CandidateLibrary
    >>> CandidateLibrary(n_state=16, n_control=3, order=2).n_terms
    226
"""

from latent_sindy.sindy.library import VALID_ORDERS, CandidateLibrary, LibrarySubset

__all__ = ["VALID_ORDERS", "CandidateLibrary", "LibrarySubset"]
