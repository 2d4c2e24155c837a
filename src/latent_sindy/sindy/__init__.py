"""Sparse identification of nonlinear dynamics (SINDy) parts: libraries, sparse regression, fits.

``latent_sindy.sindy.grammar`` holds the serialisable library specs (and the registry of the
derived-variable nodes worlds add), ``latent_sindy.sindy.terms`` the compiler from a spec to
terms and names, ``latent_sindy.sindy.torch_library`` the differentiable libraries Θ(z, u),
``latent_sindy.sindy.named_libraries`` the libraries chosen by name;
``latent_sindy.sindy.optimizers`` the sparsifier (:class:`STLSQ`),
``latent_sindy.sindy.ensemble`` its bagged form for noisy data (:class:`EnsembleSTLSQ`),
``latent_sindy.sindy.stepwise`` backward elimination for libraries whose terms are dependent
on the data (:class:`StepwiseSR`), ``latent_sindy.sindy.trimmed`` any of them fitted to the
rows a smooth library explains (:class:`Trimmed`: limits, contacts); ``latent_sindy.sindy.fit``
the fits to state transitions and, in a windowed form for noisy data, to whole trajectories;
``latent_sindy.sindy.selection`` a sparsifier's setting chosen on held-out rollouts.
The package works on libraries and arrays only: it imports neither :mod:`latent_sindy.models`
(which builds on it) nor any world (worlds register their named libraries and nodes here).

    >>> from latent_sindy.sindy import CandidateLibrary, Identity, Polynomial, Sine, SindyLibrary
    >>> CandidateLibrary(n_state=16, n_control=3, order=2).n_terms
    226
    >>> SindyLibrary(Polynomial("z,u", 2) + Sine("z") + Identity("u2") * Sine("u1"), 16, 3).n_terms
    227
"""

from latent_sindy.sindy.ensemble import EnsembleSTLSQ
from latent_sindy.sindy.fit import fit_state_data, fit_trajectory_data, window_regression_data
from latent_sindy.sindy.grammar import (
    Constant,
    Cosine,
    DerivedVariables,
    Identity,
    LibrarySpec,
    Polynomial,
    Product,
    Sine,
    Sum,
    register_derived,
    spec_from_dict,
)
from latent_sindy.sindy.named_libraries import (
    NAMED_LIBRARIES,
    NamedLibrary,
    library_names,
    library_spec,
    named_library,
    poly_library,
    register_library,
)
from latent_sindy.sindy.optimizers import STLSQ
from latent_sindy.sindy.selection import Selection, rollout_error, select_on_rollouts
from latent_sindy.sindy.stepwise import StepwiseSR
from latent_sindy.sindy.torch_library import (
    VALID_ORDERS,
    CandidateLibrary,
    LibrarySubset,
    SindyLibrary,
)
from latent_sindy.sindy.trimmed import Trimmed

__all__ = [
    "NAMED_LIBRARIES",
    "STLSQ",
    "VALID_ORDERS",
    "CandidateLibrary",
    "Constant",
    "Cosine",
    "DerivedVariables",
    "EnsembleSTLSQ",
    "Identity",
    "LibrarySpec",
    "LibrarySubset",
    "NamedLibrary",
    "Polynomial",
    "Product",
    "Selection",
    "SindyLibrary",
    "Sine",
    "StepwiseSR",
    "Sum",
    "Trimmed",
    "fit_state_data",
    "fit_trajectory_data",
    "library_names",
    "library_spec",
    "named_library",
    "poly_library",
    "register_derived",
    "register_library",
    "rollout_error",
    "select_on_rollouts",
    "spec_from_dict",
    "window_regression_data",
]
