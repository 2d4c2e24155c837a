"""Library presets: spec builders found by name, the core's generic ``poly`` and those worlds
register (:func:`register_preset`, from a world plug-in's module).

A name that is not registered yet loads the installed world plug-ins once
(:func:`latent_sindy.plugins.load_plugins`), so a run folder or a command line that names a
world's library works without importing the world first.

    >>> library_preset("poly", order=3) == poly_library(3)
    True
    >>> preset_names()  # the core's and the installed worlds'
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from latent_sindy.errors import UserError
from latent_sindy.plugins import load_plugins
from latent_sindy.sindy.grammar import Cosine, LibrarySpec, Polynomial, Sine

__all__ = ["LIBRARY_PRESETS", "has_preset", "library_preset", "poly_library", "preset_names",
           "register_preset"]


def poly_library(
    order: int = 2, include_sine: bool = True, include_cosine: bool = False
) -> LibrarySpec:
    """The classic library: monomials of ``[z, u]`` up to ``order`` with the constant, then
    ``sin(z)`` and ``cos(z)`` if asked (what :class:`CandidateLibrary` builds)."""
    spec: LibrarySpec = Polynomial(("z", "u"), order, bias=True)
    if include_sine:
        spec = spec + Sine("z")
    if include_cosine:
        spec = spec + Cosine("z")
    return spec


#: Named spec builders; their keyword arguments are the preset's parameters. The core's own
#: here; worlds add theirs with :func:`register_preset` (see :func:`preset_names`).
LIBRARY_PRESETS: dict[str, Callable[..., LibrarySpec]] = {"poly": poly_library}


def register_preset(name: str, builder: Callable[..., LibrarySpec]) -> None:
    """Register ``builder`` (keyword parameters -> a spec) as the preset ``name``. Registering
    the same function again (a reloaded module) replaces it; another under a taken name is an
    error."""
    taken = LIBRARY_PRESETS.get(name)
    key = (getattr(builder, "__module__", None), getattr(builder, "__qualname__", None))
    if taken is not None and (taken.__module__, taken.__qualname__) != key:
        raise ValueError(f"library preset {name!r} is taken by {taken.__module__}."
                         f"{taken.__qualname__}: register {key[1]} under another name")
    LIBRARY_PRESETS[name] = builder


def preset_names() -> tuple[str, ...]:
    """Every preset's name, world plug-ins loaded first."""
    load_plugins()
    return tuple(LIBRARY_PRESETS)


def library_preset(name: str, **params: Any) -> LibrarySpec:
    """The spec of preset ``name`` with ``params`` (the builder's keyword arguments)."""
    if name not in LIBRARY_PRESETS:
        load_plugins()
    build = LIBRARY_PRESETS.get(name)
    if build is None:
        raise UserError(
            f"library preset {name!r} is unknown: use one of {', '.join(LIBRARY_PRESETS)} (the "
            "installed worlds' included)"
        )
    try:
        return build(**params)
    except TypeError as e:
        raise UserError(f"library preset {name!r}: {e}") from None


def has_preset(name: str) -> bool:
    """Whether ``name`` is a registered preset (world plug-ins loaded when it is not yet)."""
    if name not in LIBRARY_PRESETS:
        load_plugins()
    return name in LIBRARY_PRESETS
