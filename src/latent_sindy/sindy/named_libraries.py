"""Candidate libraries chosen by name: the core's generic ``poly`` and those world plug-ins
register (:func:`register_library`, from a plug-in's module).

A library is composed from the grammar (:mod:`latent_sindy.sindy.grammar`) by whoever knows
the system; a name only lets a command line or a run folder say which composition it means.
:class:`NamedLibrary` is what a name stands for: how its spec is built from the model's
order and its own options (a frozen dataclass, given as ``KEY=VALUE`` pairs), and what it
needs of the latent and the actions. A name that is not registered yet loads the installed
world plug-ins once (:func:`latent_sindy.plugins.load_plugins`), so a run folder or a command
line that names a world's library works without importing the world first.

    >>> library_spec("poly", order=3) == poly_library(3)
    True
    >>> "poly" in library_names()  # the core's and the installed worlds'
    True
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from latent_sindy.configs import from_json, from_pairs
from latent_sindy.errors import UserError
from latent_sindy.plugins import load_plugins
from latent_sindy.sindy.grammar import Cosine, LibrarySpec, Polynomial, Sine

__all__ = ["NAMED_LIBRARIES", "NamedLibrary", "NoOptions", "library_names", "library_spec",
           "named_library", "poly_library", "register_library"]


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


@dataclass(frozen=True)
class NoOptions:
    """The options of a library that takes none."""


@dataclass(frozen=True)
class NamedLibrary:
    """What a library's name stands for: its builder and what it needs.

    ``build(order, include_sine, options)`` returns the spec for the model's polynomial
    ``order``, whether ``sin(z)`` is asked for, and ``options``, an instance of
    :attr:`options` (the library's own settings, checked by that dataclass)."""

    build: Callable[[int, bool, Any], LibrarySpec]
    options: type = NoOptions
    """A frozen dataclass of the library's own settings (``--library-options KEY=VALUE``;
    its ``__post_init__`` refuses what it cannot build, with UserError)."""
    orders: tuple[int, ...] = (1, 2, 3, 4)
    """The polynomial orders it takes."""
    actions: int = 0
    """The fewest action coordinates it needs."""
    pose_latent: bool = False
    """Whether it writes the dynamics on a pose latent: the first four latent coordinates
    are (x, y, cos fθ, sin fθ), as the state and moments encoders and a coordinates pose
    head give them (models refuse other latents)."""
    latent_frequency: str | None = None
    """The name of its option that, set to 0, takes the pose latent's angle frequency f
    (the moments encoders' ``moment_order``, chosen from the data where that is 0); None:
    no option follows the latent."""
    about: str = ""
    """One line on what it holds, for error messages and docs."""

    def __post_init__(self) -> None:
        if not (dataclasses.is_dataclass(self.options) and isinstance(self.options, type)):
            raise TypeError(f"NamedLibrary options must be a dataclass type, got {self.options!r}")
        if self.latent_frequency is not None and self.latent_frequency not in {
                f.name for f in dataclasses.fields(self.options)}:
            raise TypeError(f"latent_frequency {self.latent_frequency!r} is not an option of "
                            f"{self.options.__name__}")

    def settings(self, given: Sequence[str] | Mapping[str, Any] | Any, where: str) -> Any:
        """The options dataclass from ``KEY=VALUE`` pairs, a mapping, or an instance."""
        if isinstance(given, self.options):
            return given
        if isinstance(given, Mapping):
            return from_json(self.options, dict(given), where)
        if isinstance(given, str):
            given = (given,)
        return from_pairs(self.options, tuple(given), where)

    def pairs(self, options: Any) -> tuple[str, ...]:
        """``options`` as the ``KEY=VALUE`` pairs of its fields that differ from their
        defaults, in field order (JSON values, which :meth:`settings` reads back exactly)."""
        default = self.options()
        return tuple(f"{f.name}={json.dumps(getattr(options, f.name))}"
                     for f in dataclasses.fields(options)
                     if getattr(options, f.name) != getattr(default, f.name))


#: The named libraries; the core's own here, worlds add theirs with :func:`register_library`.
NAMED_LIBRARIES: dict[str, NamedLibrary] = {
    "poly": NamedLibrary(lambda order, include_sine, options: poly_library(order, include_sine),
                         about="monomials of [z, u] up to the order with the constant, + sin z"),
}


def register_library(name: str, library: NamedLibrary) -> None:
    """Register ``library`` under ``name``. Registering one with the same builder again (a
    reloaded module) replaces it; another under a taken name is an error."""
    taken = NAMED_LIBRARIES.get(name)

    def key(lib: NamedLibrary) -> tuple[Any, Any]:
        return (getattr(lib.build, "__module__", None), getattr(lib.build, "__qualname__", None))

    if taken is not None and key(taken) != key(library):
        raise ValueError(f"library {name!r} is taken by {key(taken)[0]}.{key(taken)[1]}: "
                         f"register {key(library)[1]} under another name")
    NAMED_LIBRARIES[name] = library


def library_names() -> tuple[str, ...]:
    """Every named library's name, world plug-ins loaded first."""
    load_plugins()
    return tuple(NAMED_LIBRARIES)


def named_library(name: str) -> NamedLibrary:
    """The library registered as ``name`` (world plug-ins loaded when it is not yet);
    UserError naming the known ones where there is none."""
    if name not in NAMED_LIBRARIES:
        load_plugins()
    found = NAMED_LIBRARIES.get(name)
    if found is None:
        raise UserError(f"library {name!r} is unknown: use one of "
                        f"{', '.join(NAMED_LIBRARIES)} (the installed worlds' included)")
    return found


def library_spec(name: str, order: int = 2, include_sine: bool = True,
                 options: Sequence[str] | Mapping[str, Any] | Any = ()) -> LibrarySpec:
    """The spec of the library ``name`` at ``order``, with ``sin(z)`` if ``include_sine``,
    and its ``options`` (``KEY=VALUE`` pairs, a mapping or its options dataclass)."""
    library = named_library(name)
    if order not in library.orders:
        raise UserError(f"library {name!r} takes order {', '.join(map(str, library.orders))}, "
                        f"not {order}")
    return library.build(order, include_sine,
                         library.settings(options, f"library {name!r} options"))
