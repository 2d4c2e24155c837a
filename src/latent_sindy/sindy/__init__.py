"""Sparse identification of nonlinear dynamics (SINDy) parts: libraries, sparse regression, fits.

``latent_sindy.sindy.library`` holds the composable, differentiable libraries Θ(z, u) and
their serialisable specs; ``latent_sindy.sindy.optimizers`` the sparsifier (:class:`STLSQ`);
``latent_sindy.sindy.fit`` the fits to state transitions. The package works on libraries and
arrays only: it does not import :mod:`latent_sindy.models` (which builds on it).

    >>> from latent_sindy.sindy import CandidateLibrary, Identity, Polynomial, Sine, SindyLibrary
    >>> CandidateLibrary(n_state=16, n_control=3, order=2).n_terms
    226
    >>> SindyLibrary(Polynomial("z,u", 2) + Sine("z") + Identity("u2") * Sine("u1"), 16, 3).n_terms
    227
"""

from latent_sindy.sindy.fit import FitResult, fit_gradient, fit_state_data
from latent_sindy.sindy.library import (
    LIBRARY_PRESETS,
    VALID_ORDERS,
    CandidateLibrary,
    Constant,
    Cosine,
    FaceFrame,
    Identity,
    LibrarySpec,
    LibrarySubset,
    Polynomial,
    Product,
    SindyLibrary,
    Sine,
    Sum,
    face_library,
    face_variables,
    frame_library,
    library_preset,
    poly_library,
    push_library,
    spec_from_dict,
)
from latent_sindy.sindy.optimizers import STLSQ

__all__ = [
    "LIBRARY_PRESETS",
    "STLSQ",
    "VALID_ORDERS",
    "CandidateLibrary",
    "Constant",
    "Cosine",
    "FaceFrame",
    "FitResult",
    "Identity",
    "LibrarySpec",
    "LibrarySubset",
    "Polynomial",
    "Product",
    "SindyLibrary",
    "Sine",
    "Sum",
    "face_library",
    "face_variables",
    "fit_gradient",
    "fit_state_data",
    "frame_library",
    "library_preset",
    "poly_library",
    "push_library",
    "spec_from_dict",
]
