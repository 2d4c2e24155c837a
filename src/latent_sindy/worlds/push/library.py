"""The pushing world's candidate libraries: the push's geometry, the pushed face's frame.

Importing this module (the world's plug-in does) registers with :mod:`latent_sindy.sindy`:

* the derived-variable node :class:`FaceFrame` (dict key ``"face_frame"``, the key run folders
  store), which defines the pushed face's variables ``a`` and ``n``;
* the named libraries ``"push"`` (:func:`push_library`), ``"face"`` (:func:`face_library`,
  options :class:`FaceOptions`) and ``"frame"`` (:func:`frame_library`, options
  :class:`FrameOptions`), which ``SindyConfig(library=...)`` and ``--library`` choose.

Actions are ``u = [p, ψ, ℓ]`` (contact offset, push angle, push length) and a pose latent is
``(x, y, cos fθ, sin fθ)`` (f the block's visible symmetry: 4 for a square).

    >>> from latent_sindy.sindy import SindyLibrary, library_spec
    >>> SindyLibrary(library_spec("frame", order=1, include_sine=False), 4, 3).n_terms
    57
"""

from __future__ import annotations

import math
import numbers
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import torch

from latent_sindy.errors import UserError
from latent_sindy.sindy import (
    Constant,
    Cosine,
    DerivedVariables,
    Identity,
    LibrarySpec,
    NamedLibrary,
    Polynomial,
    Sine,
    poly_library,
    register_derived,
    register_library,
)
from latent_sindy.sindy.grammar import variables

__all__ = [
    "FACE_VARIABLES",
    "FaceFrame",
    "FaceIndices",
    "FaceOptions",
    "FrameOptions",
    "face_library",
    "face_variables",
    "frame_library",
    "push_library",
]

#: The pushed face's variables a :class:`FaceFrame` defines, after [z, u] in that order.
FACE_VARIABLES = ("a", "n")

#: A face frame as :func:`face_variables` takes it: (index of the push angle in [z, u],
#: indices of the orientation features c and s, frequency, sense, offset).
FaceIndices = tuple[int, int, int, float, int, float]


def face_variables(psi: torch.Tensor, c: torch.Tensor, s: torch.Tensor,
                   face: FaceIndices) -> tuple[torch.Tensor, torch.Tensor]:
    """(a, n) of :class:`FaceFrame` from the push angle ψ and the orientation features."""
    f, sense, offset = face[3], face[4], face[5]
    f_theta = sense * torch.atan2(s, c) + offset
    a = (torch.remainder(f * psi - f_theta + math.pi, 2 * math.pi) - math.pi) / f
    return a, psi - a


@register_derived
@dataclass(frozen=True)
class FaceFrame(DerivedVariables):
    """``body``'s terms, with the variables of the pushed face defined for them: for a push in
    the world direction ψ = ``angle`` on a body whose orientation features are
    (c, s) = ``orientation`` = (cos fθ', sin fθ') (f = ``frequency``, the visible symmetry: 4
    for a square), with fθ = ``sense`` · atan2(s, c) + ``offset`` the orientation in the
    world's sense,

    * ``a`` = the push's angle from the pushed face's normal, ψ − θ wrapped into [−π/f, π/f)
      (the face met is the one whose outward normal is nearest the push direction);
    * ``n`` = ψ − a, that normal's world angle, so ``cos(n)``, ``sin(n)`` point along it.

    A push moves a block along the pushed face's normal and turns it by amounts that depend
    on where and at which angle the face is hit: few terms such as ``u2 cos(n)``,
    ``u2 a sin(n)`` and ``z3 u0 u2`` write it. ``sense`` = −1 and ``offset`` serve features
    read in a mirrored frame (an image whose axes swap the world's) or about another
    reference direction. ``a`` is discontinuous where the pushed face changes (a = ±π/f).
    """

    kind: ClassVar[str] = "face_frame"
    names: ClassVar[tuple[str, ...]] = FACE_VARIABLES
    body: LibrarySpec
    angle: str = "u1"
    orientation: tuple[str, str] = ("z2", "z3")
    frequency: float = 4.0
    sense: int = 1
    offset: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        angle = variables(self.angle)
        orientation = variables(self.orientation)
        if (len(angle) != 1 or not re.match(r"^u\d+$", angle[0]) or len(orientation) != 2
                or not all(re.match(r"^z\d+$", v) for v in orientation)
                or orientation[0] == orientation[1]):
            raise UserError(
                f"face frame: angle {self.angle!r} and orientation {self.orientation!r}: name "
                "one action such as 'u1' and two different states such as ('z2', 'z3')")
        object.__setattr__(self, "angle", angle[0])
        object.__setattr__(self, "orientation", orientation)
        f = self.frequency
        if isinstance(f, bool) or not isinstance(f, numbers.Real) or not (
                math.isfinite(f) and f > 0):
            raise UserError(f"face frame frequency {f!r}: use a finite number > 0 (4 for a "
                            "square block)")
        if self.sense not in (1, -1) or isinstance(self.sense, bool):
            raise UserError(f"face frame sense {self.sense!r}: use 1 or -1")
        if not (isinstance(self.offset, numbers.Real) and math.isfinite(self.offset)):
            raise UserError(f"face frame offset {self.offset!r}: use a finite angle (radians)")
        object.__setattr__(self, "frequency", float(f))
        object.__setattr__(self, "sense", int(self.sense))
        object.__setattr__(self, "offset", float(self.offset))

    def inputs(self) -> tuple[str, ...]:
        """ψ, then the orientation features (c, s)."""
        return (self.angle, *self.orientation)

    def evaluate(self, psi: torch.Tensor, c: torch.Tensor,
                 s: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(a, n) from ψ and (c, s)."""
        return face_variables(psi, c, s, (0, 0, 0, self.frequency, self.sense, self.offset))

    def numba_parameters(self) -> tuple[float, ...]:
        return (self.frequency, float(self.sense), self.offset)

    def numba_function(self, dtype: str) -> Any:
        from latent_sindy.worlds.push._face_kernel import FACE_VARIABLES_CFUNC

        return FACE_VARIABLES_CFUNC[dtype]

    def __str__(self) -> str:
        c, s = self.orientation
        sign = "" if self.sense == 1 else "-"
        offset = f" {'-' if self.offset < 0 else '+'} {abs(self.offset):.4g}" if self.offset else ""
        theta = f"atan2({s}, {c}) / {self.frequency:g}"
        if sign or offset:
            theta = f"({sign}atan2({s}, {c}){offset}) / {self.frequency:g}"
        return (f"face_frame(a = {self.angle} - {theta} wrapped to ±π/{self.frequency:g}, "
                f"n = {self.angle} - a)[{self.body}]")


def push_library(
    order: int = 2, angle: int = 1, length: int = 2, include_sine: bool = True
) -> LibrarySpec:
    """:func:`~latent_sindy.sindy.poly_library` plus the push's geometry: the push length times
    the sine and the cosine of the push angle, alone and times each state variable.

    ``angle`` and ``length`` are the action indices of the angle (radians) and the length:
    with the defaults the extra terms are ``u2 sin(u1)``, ``z0 u2 sin(u1)``, ..,
    ``u2 cos(u1)``, ``z0 u2 cos(u1)``, .. (2 (nz + 1) terms).
    """
    if angle == length or min(angle, length) < 0:
        raise UserError(
            f"push library: angle index {angle} and length index {length} must be different "
            "action indices >= 0"
        )
    direction = Sine(f"u{angle}") + Cosine(f"u{angle}")
    push = Identity(f"u{length}") * direction * Polynomial("z", 1, bias=True)
    return poly_library(order, include_sine) + push


def _check_contact_indices(library: str, offset: int, angle: int, length: int) -> None:
    if len({offset, angle, length}) < 3 or min(offset, angle, length) < 0:
        raise UserError(f"{library} library: offset {offset}, angle {angle} and length "
                        f"{length} must be different action indices >= 0")


def face_library(
    order: int = 1,
    offset: int = 0,
    angle: int = 1,
    length: int = 2,
    orientation: str | Sequence[str] = ("z2", "z3"),
    frequency: float = 4.0,
    offset_degree: int = 2,
) -> LibrarySpec:
    """A push made on a face: the state's monomials up to ``order``, plus the push length
    times the push direction or the orientation features, times what decides where the face
    is hit: the contact offset's powers and the push angle relative to the face.

    For a state s = (x, y, c, s) = (x, y, cos fθ, sin fθ) (f = ``frequency``, the block's
    visible symmetry: 4 for a square) and a push u = [p, ψ, ℓ] in a world direction ψ, the
    angle from the pushed face's normal enters as sin f(ψ - θ) = c sin fψ - s cos fψ and
    cos f(ψ - θ) = c cos fψ + s sin fψ. So the terms are

        ℓ · {sin ψ, cos ψ, c, s} · {1, p, .., p^offset_degree}
          · {1, c sin fψ, c cos fψ, s sin fψ, s cos fψ}

    (a translation along the push, and a turn, Δc ≈ -f s Δθ, Δs ≈ f c Δθ, both bent by where
    and at which angle the face is hit), each distinct product once. With the defaults: 8 + 54
    terms, such as
    ``u2 sin(u1)``, ``u0 u2 cos(u1)`` and ``z2^2 u2 sin(4 u1)``.

    ``offset``, ``angle`` and ``length`` are the action indices of p, ψ and ℓ;
    ``orientation`` names the state's orientation features. ``order`` > 1 repeats
    ``ℓ c``-type terms, which the library refuses.
    """
    _check_contact_indices("face", offset, angle, length)
    if isinstance(offset_degree, bool) or not isinstance(offset_degree, int) or (
            offset_degree < 0):
        raise UserError(f"face library: offset_degree {offset_degree!r}: use an integer >= 0")
    psi = f"u{angle}"
    orient = variables(orientation)
    relative = Constant() + Identity(orient) * (Sine(psi, frequency=frequency)
                                                + Cosine(psi, frequency=frequency))
    contact = (Constant() if offset_degree == 0
               else Polynomial(f"u{offset}", offset_degree, bias=True)) * relative
    push = Identity(f"u{length}") * (Sine(psi) + Cosine(psi) + Identity(orient)) * contact
    return Polynomial(("z", "u"), order, bias=True) + push


def frame_library(
    order: int = 1,
    offset: int = 0,
    angle: int = 1,
    length: int = 2,
    orientation: str | Sequence[str] = ("z2", "z3"),
    frequency: float = 4.0,
    degree: int = 3,
    sense: int = 1,
    angle_offset: float = 0.0,
) -> LibrarySpec:
    """A push written in the pushed face's frame (:class:`FaceFrame`): the state's monomials
    up to ``order``, plus the push length times the monomials of the contact offset p and of
    the angle a between the push and the face normal up to ``degree``, alone or times the
    face normal's direction or the orientation features:

        ℓ · {p, a, p², p a, a², .., a^degree}
        + ℓ · {cos n, sin n, c, s} · {1, p, a, p², p a, a², .., a^degree}

    (the block slides along the normal of the face it is pushed on, Δx = ℓ g(p, a) cos n −
    ℓ h(p, a) sin n, and turns by fΔθ = ℓ r(p, a): the first group, for a model that turns
    its orientation features by an angle, ``LatentDynamics(turn=True)``; Δc ≈ −s fΔθ,
    Δs ≈ c fΔθ for one that updates them). With the defaults 8 + 9 + 40 terms, such as
    ``u2 cos(n)``, ``u0 u2 a sin(n)``, ``u2 a^3`` and ``z3 u2 a^2``. Where the face library
    spends harmonics of 4(ψ − θ) on the relative angle, this one reads it.

    ``offset``, ``angle`` and ``length`` are the action indices of p, ψ (a world direction)
    and ℓ; ``orientation`` names the state's (cos fθ, sin fθ); ``sense`` and
    ``angle_offset`` map them to the world's orientation (:class:`FaceFrame`).
    """
    _check_contact_indices("frame", offset, angle, length)
    if isinstance(degree, bool) or not isinstance(degree, int) or degree < 0:
        raise UserError(f"frame library: degree {degree!r}: use an integer >= 0")
    orient = variables(orientation)
    ell = Identity(f"u{length}")
    directions = Cosine("n") + Sine("n") + Identity(orient)
    if degree == 0:
        push = ell * directions
    else:
        shape = (f"u{offset}", "a")
        push = (ell * Polynomial(shape, degree, bias=False)
                + ell * directions * Polynomial(shape, degree, bias=True))
    return FaceFrame(Polynomial(("z", "u"), order, bias=True) + push, angle=f"u{angle}",
                     orientation=orient, frequency=frequency, sense=sense,
                     offset=angle_offset)


def _check_frequency(frequency: float) -> None:
    if isinstance(frequency, bool) or not (math.isfinite(frequency) and frequency >= 0):
        raise UserError(f"frequency={frequency}: use a finite number > 0 (4 for a square "
                        "block), or 0 for the moments encoder's order")


@dataclass(frozen=True)
class FaceOptions:
    """The face library's options (``--library face --library-options KEY=VALUE``)."""

    frequency: float = 4.0
    """f of the orientation features (cos fθ, sin fθ), the block's visible symmetry (2π over
    its visible period; 4 for a square). The relative push angle enters as sin(f u1),
    cos(f u1) times those features. 0: the moments encoder's ``moment_order`` (the order its
    latent's features turn at; chosen from the data when that is 0)."""

    def __post_init__(self) -> None:
        _check_frequency(self.frequency)


@dataclass(frozen=True)
class FrameOptions:
    """The frame library's options (``--library frame --library-options KEY=VALUE``)."""

    frequency: float = 4.0
    """As the face library's: the block's visible symmetry, or 0 for the moments encoder's
    order."""
    degree: int = 3
    """Highest degree of its monomials (of the contact offset and the angle from the face
    normal)."""
    sense: int | None = None
    """The orientation features' sense against the world's, fθ = sense · atan2(z3, z2) +
    offset (-1 for features read in a mirrored image). None: the latent's own, which training
    states in the run's record: on the moments latent the data's camera's (a value given
    must match it), on a pose latent in world angles (the state, a coordinates pose head) 1.
    A model built from an unresolved config reads None as 1 and its offset as 0."""
    offset: float | None = None
    """That offset (radians); None: the latent's own, as ``sense`` (the moments latent's
    camera's, else 0)."""

    def __post_init__(self) -> None:
        _check_frequency(self.frequency)
        if self.frequency != 0 and (self.frequency < 3
                                    or self.frequency != round(self.frequency)):
            raise UserError(f"frequency={self.frequency:g}: its angle a is "
                            "measured from the nearest face normal of a block whose visible "
                            "symmetry is its number of faces (a uniform square: 4); use an "
                            "integer >= 3, or --library face / push")
        if isinstance(self.degree, bool) or not 0 <= self.degree <= 4:
            raise UserError(f"degree={self.degree}: use 0 to 4")
        if self.sense not in (None, 1, -1):
            raise UserError(f"sense={self.sense}: use 1 or -1")
        if self.offset is not None and not math.isfinite(self.offset):
            raise UserError(f"offset={self.offset}: use a finite angle (radians)")


def _push(order: int, include_sine: bool, options: Any) -> LibrarySpec:
    return push_library(order, angle=1, length=2, include_sine=include_sine)


def _face(order: int, include_sine: bool, options: FaceOptions) -> LibrarySpec:
    spec = face_library(order, frequency=options.frequency)
    return spec + Sine("z") if include_sine else spec


def _frame(order: int, include_sine: bool, options: FrameOptions) -> LibrarySpec:
    spec = frame_library(order, frequency=options.frequency, degree=options.degree,
                         sense=1 if options.sense is None else options.sense,
                         angle_offset=options.offset or 0.0)
    return spec + Sine("z") if include_sine else spec


#: Actions [p, ψ, ℓ]: the contact offset, the push angle and the push length.
_ACTIONS = 3

register_library("push", NamedLibrary(
    _push, actions=_ACTIONS,
    about="poly plus the push length times the sine and cosine of the push angle, alone and "
          "times each state"))
register_library("face", NamedLibrary(
    _face, FaceOptions, orders=(1,), actions=_ACTIONS, pose_latent=True,
    latent_frequency="frequency",
    about="on a pose latent, world-direction pushes: the push length times the push "
          "direction or the orientation features, times powers of the contact offset and the "
          "relative push angle (order 1: its push terms hold the higher-order products)"))
register_library("frame", NamedLibrary(
    _frame, FrameOptions, orders=(1,), actions=_ACTIONS, pose_latent=True,
    latent_frequency="frequency",
    about="as face, with the push written in the pushed face's frame"))
