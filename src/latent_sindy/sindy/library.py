"""Differentiable SINDy candidate libraries Θ(z, u) in torch, composed from small parts.

A library is described by a *spec*, a small frozen dataclass tree that is independent of the
model's sizes and serialises to JSON (:meth:`to_dict` / :func:`spec_from_dict`):

* :class:`Polynomial` ``(variables, degree, bias)``: every monomial of the variables up to
  ``degree`` (the constant ``1`` when ``bias``), in the order and with the names of
  ``pysindy.PolynomialLibrary``;
* :class:`Sine`, :class:`Cosine` ``(variables, frequency)``: ``sin(f x)`` / ``cos(f x)`` of
  each variable (named ``sin(x)``, ``sin(4 x)``);
* :class:`Identity` ``(variables)``: the variables themselves;
* :class:`Constant` ``()``: the term ``1`` (``(Constant() + a) * b`` keeps ``b``'s terms);
* ``a + b`` (:class:`Sum`): the terms of ``a``, then those of ``b``;
* ``a * b`` (:class:`Product`): every product of a term of ``a`` with a term of ``b``
  (row-major: for each term of ``a``, every term of ``b``), each distinct product once.

Variables are named ``z0 .. z{nz-1}`` (state) and ``u0 .. u{nu-1}`` (control); ``"z"`` and
``"u"`` stand for the whole group. :class:`SindyLibrary` builds the torch module for given
sizes; :class:`CandidateLibrary` is the classic library (monomials of ``[z, u]`` up to
``order``, then ``sin(z)``, optionally ``cos(z)``), and :data:`LIBRARY_PRESETS` names specs.

Every term is one row of an integer table of feature indices into the feature vector
``F = [x, 1, sin(f x_a), .., cos(f x_b), ..]`` (``x = [z, u]``, or ``[z, u, a, n]`` with the
pushed face's variables of a :class:`FaceFrame`, :func:`frame_library`; the trig columns are
listed in ``trig`` as ``(variable index, "sin" | "cos", frequency)``, sines first); a term
is the product of the features its row names, shorter rows padded with the constant.
Evaluation is one gather and multiply per table column, so the hot path has no Python loop
over terms, and a subset of terms is the same code on a subset of the rows. Term names follow
pysindy: ``1``, ``z0 u2``, ``z3^2``, ``sin(z1)``, ``u2 cos(u1)``, ``z2 sin(4 u1)`` (monomial
factors first, by variable, then trig ones).

    >>> spec = Polynomial("z,u", degree=2) + Sine("z") + Identity("u2") * Cosine("u1")
    >>> lib = SindyLibrary(spec, n_state=16, n_control=3)
    >>> lib.n_terms, lib.names[-1]
    (227, 'u2 cos(u1)')
    >>> theta = lib(torch.zeros(5, 16), torch.zeros(5, 3))  # (5, 227)
    >>> CandidateLibrary(n_state=16, n_control=3, order=2).n_terms
    226
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import numbers
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import torch
from torch import nn

from latent_sindy.errors import UserError

__all__ = [
    "LIBRARY_PRESETS",
    "VALID_ORDERS",
    "CandidateLibrary",
    "Constant",
    "Cosine",
    "FaceFrame",
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
    "frame_library",
    "library_preset",
    "poly_library",
    "push_library",
    "spec_from_dict",
]

VALID_ORDERS = (1, 2, 3, 4)

TermIndex = Sequence[int] | torch.Tensor

# A factor of a term: (variable index into x = [z, u], function, frequency); a term is a
# sorted tuple. Monomial factors have frequency 1.
_IDENTITY, _SIN, _COS = 0, 1, 2
_FN_NAMES = {_SIN: "sin", _COS: "cos"}
_FN_CODES = {"sin": _SIN, "cos": _COS}
_Factor = tuple[int, int, float]
_Term = tuple[_Factor, ...]

_VARIABLE = re.compile(r"^([zu])(\d+)?$|^([an])$")
#: The pushed face's variables a :class:`FaceFrame` defines, after [z, u] in that order.
FACE_VARIABLES = ("a", "n")


def _factor_key(f: _Factor) -> tuple[bool, int, int, float]:
    """Monomial factors first by variable, then trig factors by variable, sine before cosine,
    then by frequency."""
    return (f[1] != _IDENTITY, f[0], f[1], f[2])


def _trig_order(f: _Factor) -> tuple[int, int, float]:
    """Trig columns of F: sines first, each by variable, then by frequency."""
    return (f[1], f[0], f[2])


def _canonical(factors: Sequence[_Factor]) -> _Term:
    return tuple(sorted(factors, key=_factor_key))


# ---------------------------------------------------------------- specs


def _as_variables(value: str | Sequence[str]) -> tuple[str, ...]:
    """``"z,u"``, ``"z u1"`` or ``("z", "u1")`` -> ``("z", "u1")``, names checked."""
    names = tuple(re.split(r"[,\s]+", value.strip())) if isinstance(value, str) else tuple(value)
    if not names or names == ("",):
        raise UserError("a library part needs at least one variable: name e.g. 'z', 'u' or 'u1'")
    for name in names:
        if not isinstance(name, str) or not _VARIABLE.match(name):
            raise UserError(
                f"library variable {name!r} is not valid: use 'z' or 'u' (the whole group), "
                "one variable such as 'z3' or 'u1', or a face variable 'a' or 'n' (FaceFrame)"
            )
    return names


class _SpecOps:
    """``+`` and ``*`` for every spec; subclasses are frozen dataclasses with a ``kind``."""

    kind: ClassVar[str]

    def __add__(self, other: LibrarySpec) -> Sum:
        if not isinstance(other, _SpecOps):
            return NotImplemented
        return Sum((*_summands(self), *_summands(other)))  # type: ignore[arg-type]

    def __mul__(self, other: LibrarySpec) -> Product:
        if not isinstance(other, _SpecOps):
            return NotImplemented
        return Product((*_multiplicands(self), *_multiplicands(other)))  # type: ignore[arg-type]

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict that :func:`spec_from_dict` turns back into this spec."""
        out: dict[str, Any] = {"kind": self.kind}
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            value = getattr(self, f.name)
            if isinstance(value, tuple) and value and isinstance(value[0], _SpecOps):
                out[f.name] = [v.to_dict() for v in value]
            elif isinstance(value, tuple):
                out[f.name] = list(value)
            else:
                out[f.name] = value
        return out


@dataclass(frozen=True)
class _Group(_SpecOps):
    """A leaf over a group of variables."""

    variables: tuple[str, ...] = ("z",)
    """Variable names: ``"z"``/``"u"`` (all states / controls) or ``"z3"``, ``"u1"``; a string
    ``"z,u"`` is split."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "variables", _as_variables(self.variables))

    def __str__(self) -> str:
        return f"{self.kind}({','.join(self.variables)})"


@dataclass(frozen=True)
class Polynomial(_Group):
    """Monomials of ``variables`` of degree 1 to ``degree``, after the constant if ``bias``."""

    kind: ClassVar[str] = "poly"
    variables: tuple[str, ...] = ("z", "u")
    degree: int = 2
    """Highest total degree (at least 1)."""
    bias: bool = True
    """Start with the constant term ``1``."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if (
            isinstance(self.degree, bool)
            or not isinstance(self.degree, numbers.Integral)
            or (self.degree < 1)
        ):
            raise UserError(
                f"polynomial library degree {self.degree!r} is not valid: use an integer >= 1"
            )
        object.__setattr__(self, "degree", int(self.degree))
        object.__setattr__(self, "bias", bool(self.bias))

    def __str__(self) -> str:
        bias = "" if self.bias else ", no bias"
        return f"poly({','.join(self.variables)}; {self.degree}{bias})"


@dataclass(frozen=True)
class _Trig(_Group):
    frequency: float = 1.0
    """f of ``sin(f x)`` / ``cos(f x)``: a finite number > 0 (sin(-x) = -sin(x) adds nothing).
    A square block's pose features turn 4 times per revolution, so its push geometry needs
    ``sin(4 ψ)``."""

    def __post_init__(self) -> None:
        super().__post_init__()
        f = self.frequency
        if isinstance(f, bool) or not isinstance(f, numbers.Real) or not (
                math.isfinite(f) and f > 0):
            raise UserError(f"{self.kind} library frequency {f!r} is not valid: use a finite "
                            "number > 0 such as 1 or 4")
        object.__setattr__(self, "frequency", float(f))

    def __str__(self) -> str:
        freq = "" if self.frequency == 1 else f"; {self.frequency:g}"
        return f"{self.kind}({','.join(self.variables)}{freq})"


@dataclass(frozen=True)
class Sine(_Trig):
    """``sin(f x)`` of every variable ``x`` of ``variables`` (f = ``frequency``)."""

    kind: ClassVar[str] = "sin"


@dataclass(frozen=True)
class Cosine(_Trig):
    """``cos(f x)`` of every variable ``x`` of ``variables`` (f = ``frequency``)."""

    kind: ClassVar[str] = "cos"


@dataclass(frozen=True)
class Constant(_SpecOps):
    """The single term ``1``: ``(Constant() + a) * b`` is ``b`` and ``a * b``."""

    kind: ClassVar[str] = "one"

    def __str__(self) -> str:
        return "1"


@dataclass(frozen=True)
class Identity(_Group):
    """The variables themselves (degree-1 monomials, no constant)."""

    kind: ClassVar[str] = "identity"
    variables: tuple[str, ...] = ("u",)


@dataclass(frozen=True)
class Sum(_SpecOps):
    """Concatenation: the terms of every part, in order (``a + b``)."""

    kind: ClassVar[str] = "sum"
    parts: tuple[LibrarySpec, ...]

    def __post_init__(self) -> None:
        _check_children(self, "parts", "sum")

    def __str__(self) -> str:
        return " + ".join(str(p) for p in self.parts)


@dataclass(frozen=True)
class Product(_SpecOps):
    """Tensor product: every product of one term of each factor (``a * b``), row-major; a
    product met again (``z2 · z3`` after ``z3 · z2``) is kept only where it first appears."""

    kind: ClassVar[str] = "product"
    factors: tuple[LibrarySpec, ...]

    def __post_init__(self) -> None:
        _check_children(self, "factors", "product")

    def __str__(self) -> str:
        return " * ".join(f"({f})" if isinstance(f, Sum) else str(f) for f in self.factors)


@dataclass(frozen=True)
class FaceFrame(_SpecOps):
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
    body: LibrarySpec
    angle: str = "u1"
    orientation: tuple[str, str] = ("z2", "z3")
    frequency: float = 4.0
    sense: int = 1
    offset: float = 0.0

    def __post_init__(self) -> None:
        if isinstance(self.body, Mapping):
            object.__setattr__(self, "body", spec_from_dict(self.body))
        if not isinstance(self.body, _SpecOps):
            raise UserError(f"a face frame holds a library spec, got {self.body!r}")
        angle = _as_variables(self.angle)
        orientation = _as_variables(self.orientation)
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

    def to_dict(self) -> dict[str, Any]:
        out = super().to_dict()
        out["body"] = self.body.to_dict()
        return out

    def __str__(self) -> str:
        c, s = self.orientation
        sign = "" if self.sense == 1 else "-"
        offset = f" {'-' if self.offset < 0 else '+'} {abs(self.offset):.4g}" if self.offset else ""
        theta = f"atan2({s}, {c}) / {self.frequency:g}"
        if sign or offset:
            theta = f"({sign}atan2({s}, {c}){offset}) / {self.frequency:g}"
        return (f"face_frame(a = {self.angle} - {theta} wrapped to ±π/{self.frequency:g}, "
                f"n = {self.angle} - a)[{self.body}]")


LibrarySpec = Polynomial | Sine | Cosine | Identity | Constant | Sum | Product | FaceFrame
_LEAVES: dict[str, type[_SpecOps]] = {
    c.kind: c for c in (Polynomial, Sine, Cosine, Identity, Constant, FaceFrame)}


def _check_children(spec: Sum | Product, field: str, what: str) -> None:
    children = getattr(spec, field)
    if isinstance(children, list):
        object.__setattr__(spec, field, children := tuple(children))
    if not isinstance(children, tuple) or not children:
        raise UserError(f"a library {what} needs a non-empty tuple of parts, got {children!r}")
    for c in children:
        if not isinstance(c, _SpecOps):
            raise UserError(f"a library {what} holds specs such as Polynomial(...), got {c!r}")


def _summands(spec: _SpecOps) -> tuple[LibrarySpec, ...]:
    return spec.parts if isinstance(spec, Sum) else (spec,)  # type: ignore[return-value]


def _multiplicands(spec: _SpecOps) -> tuple[LibrarySpec, ...]:
    return spec.factors if isinstance(spec, Product) else (spec,)  # type: ignore[return-value]


def spec_from_dict(d: Mapping[str, Any] | LibrarySpec) -> LibrarySpec:
    """Rebuild a spec from :meth:`to_dict` output (a spec is returned as it is)."""
    if isinstance(d, _SpecOps):
        return d  # type: ignore[return-value]
    if not isinstance(d, Mapping) or "kind" not in d:
        raise UserError(f"a library spec is a dict with a 'kind' key, got {d!r}")
    fields = {k: v for k, v in d.items() if k != "kind"}
    kind = d["kind"]
    if kind in ("sum", "product"):
        key = "parts" if kind == "sum" else "factors"
        if set(fields) != {key} or not isinstance(fields[key], Sequence):
            raise UserError(f"a library {kind} spec has exactly one list field {key!r}, got {d!r}")
        children = tuple(spec_from_dict(c) for c in fields[key])
        return Sum(children) if kind == "sum" else Product(children)
    cls = _LEAVES.get(kind)
    if cls is None:
        kinds = ", ".join([*_LEAVES, "sum", "product"])
        raise UserError(f"library part kind {kind!r} is unknown: use one of {kinds}")
    allowed = {f.name for f in dataclasses.fields(cls)}
    if set(fields) - allowed:
        raise UserError(
            f"library part {kind!r} has unknown fields {sorted(set(fields) - allowed)}: "
            f"allowed {sorted(allowed)}"
        )
    if "variables" in fields and not isinstance(fields["variables"], str):
        fields["variables"] = tuple(fields["variables"])
    return cls(**fields)  # type: ignore[return-value]


# ---------------------------------------------------------------- presets


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


def push_library(
    order: int = 2, angle: int = 1, length: int = 2, include_sine: bool = True
) -> LibrarySpec:
    """:func:`poly_library` plus the push's geometry: the push length times the sine and the
    cosine of the push angle, alone and times each state variable.

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
    orient = _as_variables(orientation)
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
    orient = _as_variables(orientation)
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


#: Named spec builders; their keyword arguments are the preset's parameters.
LIBRARY_PRESETS: dict[str, Callable[..., LibrarySpec]] = {
    "poly": poly_library,
    "push": push_library,
    "face": face_library,
    "frame": frame_library,
}


def library_preset(name: str, **params: Any) -> LibrarySpec:
    """The spec of preset ``name`` (see :data:`LIBRARY_PRESETS`) with ``params``."""
    try:
        build = LIBRARY_PRESETS[name]
    except KeyError:
        raise UserError(
            f"library preset {name!r} is unknown: use one of {', '.join(LIBRARY_PRESETS)}"
        ) from None
    try:
        return build(**params)
    except TypeError as e:
        raise UserError(f"library preset {name!r}: {e}") from None


# ---------------------------------------------------------------- terms of a spec


def _face_of(spec: LibrarySpec) -> FaceFrame | None:
    """The spec's face frame (one, or equal ones), or None."""
    found: set[FaceFrame] = set()

    def walk(node: LibrarySpec) -> None:
        if isinstance(node, FaceFrame):
            found.add(dataclasses.replace(node, body=Constant()))
            walk(node.body)
        for child in getattr(node, "parts", ()) + getattr(node, "factors", ()):
            walk(child)

    walk(spec)
    if len(found) > 1:
        raise UserError(f"library {spec} defines the face variables twice, differently: use "
                        "one FaceFrame around the whole library")
    return next(iter(found), None)


def _resolve(names: tuple[str, ...], n_state: int, n_control: int,
             face: FaceFrame | None = None) -> list[int]:
    """Variable names -> sorted, distinct indices into x = [z, u] (then a, n with a face)."""
    out: set[int] = set()
    for name in names:
        m = _VARIABLE.match(name)
        assert m is not None  # checked when the spec was made
        if m.group(3) is not None:
            if face is None:
                raise UserError(f"library variable {name!r} is a face variable: wrap the "
                                "library in FaceFrame(...) (library preset 'frame') to define it")
            out.add(n_state + n_control + FACE_VARIABLES.index(name))
            continue
        group, idx = m.group(1), m.group(2)
        size, offset = (n_state, 0) if group == "z" else (n_control, n_state)
        if idx is None:
            out.update(range(offset, offset + size))
        elif int(idx) < size:
            out.add(offset + int(idx))
        else:
            what = "n_state" if group == "z" else "n_control"
            raise UserError(
                f"library variable {name} needs {what} > {idx}, but the model has {what}={size}: "
                f"use a variable below {group}{size}"
            )
    return sorted(out)


def _spec_terms(spec: LibrarySpec, n_state: int, n_control: int,
                face: FaceFrame | None = None) -> list[_Term]:
    if isinstance(spec, FaceFrame):
        return _spec_terms(spec.body, n_state, n_control, face)
    if isinstance(spec, Sum):
        return [t for part in spec.parts for t in _spec_terms(part, n_state, n_control, face)]
    if isinstance(spec, Product):
        terms: list[_Term] = [()]
        for factor in spec.factors:
            right = _spec_terms(factor, n_state, n_control, face)
            # Each distinct product once, where it first appears (z2 * z3 = z3 * z2).
            terms = list(dict.fromkeys(_canonical(a + b) for a in terms for b in right))
        return terms
    if isinstance(spec, Constant):
        return [()]
    variables = _resolve(spec.variables, n_state, n_control, face)
    if isinstance(spec, Polynomial):
        # pysindy's order: by degree, then itertools.combinations_with_replacement.
        return [
            tuple((v, _IDENTITY, 1.0) for v in combo)
            for degree in range(0 if spec.bias else 1, spec.degree + 1)
            for combo in itertools.combinations_with_replacement(variables, degree)
        ]
    if isinstance(spec, _Trig):
        return [((v, _FN_CODES[spec.kind], spec.frequency),) for v in variables]
    return [((v, _IDENTITY, 1.0),) for v in variables]


def _trig_name(fn: int, var: str, frequency: float) -> str:
    """``sin(u1)``, ``cos(4 u1)``, ``sin(0.5 z0)``."""
    return f"{_FN_NAMES[fn]}({var})" if frequency == 1 else f"{_FN_NAMES[fn]}({frequency:g} {var})"


def _term_name(term: _Term, var_names: Sequence[str]) -> str:
    """pysindy's name: ``1``, ``z0^2 u1``, ``u2 sin(u1)``, ``sin(z0)^2``, ``z2 sin(4 u1)``."""
    if not term:
        return "1"
    parts = []
    for (var, fn, freq), group in itertools.groupby(term):
        power = len(list(group))
        base = var_names[var] if fn == _IDENTITY else _trig_name(fn, var_names[var], freq)
        parts.append(base if power == 1 else f"{base}^{power}")
    return " ".join(parts)


# ---------------------------------------------------------------- torch modules


#: A face frame as the torch modules and the control kernel take it: (index of the push
#: angle in [z, u], indices of the orientation features c and s, frequency, sense, offset).
FaceIndices = tuple[int, int, int, float, int, float]


def face_variables(psi: torch.Tensor, c: torch.Tensor, s: torch.Tensor,
                   face: FaceIndices) -> tuple[torch.Tensor, torch.Tensor]:
    """(a, n) of :class:`FaceFrame` from the push angle ψ and the orientation features."""
    f, sense, offset = face[3], face[4], face[5]
    f_theta = sense * torch.atan2(s, c) + offset
    a = (torch.remainder(f * psi - f_theta + math.pi, 2 * math.pi) - math.pi) / f
    return a, psi - a


class _ProductTerms(nn.Module):
    """Terms given as rows of feature indices into F = [z, u, (a, n), 1, trig...]; evaluates
    them.

    ``table`` (p, width) long buffer; ``trig`` lists the trig columns of F after the constant
    as ``(variable index into [z, u, (a, n)], "sin" | "cos", frequency)``, sines first;
    ``face`` (:data:`FaceIndices`) defines the face variables (a, n), or None.
    """

    table: torch.Tensor  # (p, width) indices into the feature vector F
    _sin_idx: torch.Tensor  # (n_sin,) indices into [z, u]
    _cos_idx: torch.Tensor  # (n_cos,)
    _sin_freq: torch.Tensor  # (n_sin,) frequencies
    _cos_freq: torch.Tensor  # (n_cos,)

    def __init__(
        self,
        n_state: int,
        n_control: int,
        table: torch.Tensor,
        names: list[str],
        trig: Sequence[tuple[int, str, float]],
        face: FaceIndices | None = None,
    ) -> None:
        super().__init__()
        self.n_state = n_state
        self.n_control = n_control
        self.face = face
        self.register_buffer("table", table, persistent=False)
        self.names = names
        self.trig: tuple[tuple[int, str, float], ...] = tuple(
            (int(v), k, float(f)) for v, k, f in trig)
        kinds = [k for _, k, _ in self.trig]
        if kinds != sorted(kinds, reverse=True) or not set(kinds) <= {"sin", "cos"}:
            raise ValueError(f"trig columns must be sines then cosines, got {self.trig}")
        for kind in ("sin", "cos"):
            cols = [(v, f) for v, k, f in self.trig if k == kind]
            self.register_buffer(f"_{kind}_idx", torch.tensor(
                [v for v, _ in cols], dtype=torch.long), persistent=False)
            self.register_buffer(f"_{kind}_freq", torch.tensor(
                [f for _, f in cols], dtype=torch.float64), persistent=False)
            setattr(self, f"_{kind}_scaled", any(f != 1 for _, f in cols))
        # column of F holding the constant 1
        self._one = n_state + n_control + (len(FACE_VARIABLES) if face is not None else 0)

    @property
    def n_terms(self) -> int:
        return int(self.table.shape[0])

    @property
    def constant_column(self) -> int:
        """F's column of the constant 1: the variables [z, u, (a, n)] come before it."""
        return self._one

    @property
    def n_features(self) -> int:
        """Columns of F = [z, u, (a, n), 1, trig...]."""
        return self._one + 1 + len(self.trig)

    def _features(self, z: torch.Tensor, u: torch.Tensor | None) -> torch.Tensor:
        """F = [z, u, (a, n), 1, sin(x[sin_idx]), cos(x[cos_idx])]: (..., n_features)."""
        if z.shape[-1] != self.n_state:
            raise ValueError(
                f"library expects z with last dimension n_state={self.n_state}, "
                f"got shape {tuple(z.shape)}"
            )
        parts = [z]
        if self.n_control:
            if u is None or u.shape[-1] != self.n_control or u.shape[:-1] != z.shape[:-1]:
                got = None if u is None else tuple(u.shape)
                raise ValueError(
                    f"library expects u of shape {(*z.shape[:-1], self.n_control)} "
                    f"to match z {tuple(z.shape)}, got {got}"
                )
            parts.append(u.to(z.dtype))
        if self.face is not None:
            x = torch.cat(parts, dim=-1)
            a, n = face_variables(x[..., self.face[0]], x[..., self.face[1]],
                                  x[..., self.face[2]], self.face)
            parts += [a.unsqueeze(-1), n.unsqueeze(-1)]
        parts.append(z.new_ones((*z.shape[:-1], 1)))
        base = torch.cat(parts, dim=-1)  # (..., nz + nu (+ 2) + 1)
        if not self.trig:
            return base
        trig = [base]
        for fn, idx, freq, scaled in (
                (torch.sin, self._sin_idx, self._sin_freq, self._sin_scaled),
                (torch.cos, self._cos_idx, self._cos_freq, self._cos_scaled)):
            if idx.numel():
                x = base.index_select(-1, idx)
                if scaled:
                    x = x * freq.to(x.dtype)
                trig.append(fn(x))
        return torch.cat(trig, dim=-1)

    def _evaluate(
        self, z: torch.Tensor, u: torch.Tensor | None, table: torch.Tensor
    ) -> torch.Tensor:
        feats = self._features(z, u)  # (..., n_features)
        out = feats.index_select(-1, table[:, 0])  # (..., p)
        for k in range(1, table.shape[1]):  # at most width - 1 iterations
            out = out * feats.index_select(-1, table[:, k])
        return out

    def forward(self, z: torch.Tensor, u: torch.Tensor | None = None) -> torch.Tensor:
        """Θ(z, u): z (..., nz), u (..., nu) -> (..., p)."""
        return self._evaluate(z, u, self.table)

    def extra_repr(self) -> str:
        return f"n_state={self.n_state}, n_control={self.n_control}, n_terms={self.n_terms}"


class LibrarySubset(_ProductTerms):
    """The chosen terms of a :class:`SindyLibrary`, in the chosen order.

    ``subset(idx)(z, u)`` equals ``library(z, u)[..., idx]`` but computes only those terms
    (and only the trig features they use).
    """

    terms: torch.Tensor  # (p_sub,) indices into the parent's terms

    def __init__(self, parent: SindyLibrary, terms: torch.Tensor) -> None:
        rows = parent.table.index_select(0, terms.to(parent.table.device)).cpu()
        one = parent._one
        used = sorted({int(c) for c in rows.flatten() if c > one})  # trig columns used
        remap = torch.arange(parent.n_features)
        remap[used] = torch.arange(one + 1, one + 1 + len(used))
        super().__init__(
            parent.n_state,
            parent.n_control,
            remap[rows].to(parent.table.device),
            [parent.names[i] for i in terms.tolist()],
            [parent.trig[c - one - 1] for c in used],
            parent.face,
        )
        self.register_buffer("terms", terms.clone(), persistent=False)


class SindyLibrary(_ProductTerms):
    """The torch library of a spec for ``n_state`` states and ``n_control`` controls.

    Args:
        spec: a :data:`LibrarySpec` (or its :meth:`to_dict` form).
        n_state: nz, state variables ``z0 .. z{nz-1}``.
        n_control: nu, control inputs ``u0 .. u{nu-1}`` (may be 0).

    Attributes:
        spec: the spec (rebuilds this library with the same sizes).
        names: term names in column order, pysindy style.
        n_terms: p, the number of columns of Θ.
        trig: ``(variable index into [z, u], "sin" | "cos", frequency)`` of F's trig columns.

    Raises:
        UserError: a variable beyond the sizes, or a term that appears twice.
    """

    def __init__(self, spec: LibrarySpec | Mapping[str, Any], n_state: int, n_control: int) -> None:
        if n_state < 1 or n_control < 0:
            raise ValueError(
                f"need n_state >= 1 and n_control >= 0, got n_state={n_state}, "
                f"n_control={n_control}"
            )
        spec = spec_from_dict(spec)
        frame = _face_of(spec)
        terms = _spec_terms(spec, n_state, n_control, frame)
        var_names = [f"z{i}" for i in range(n_state)] + [f"u{j}" for j in range(n_control)]
        face: FaceIndices | None = None
        if frame is not None:
            psi, = _resolve((frame.angle,), n_state, n_control)
            ca, cb = (_resolve((v,), n_state, n_control)[0] for v in frame.orientation)
            face = (psi, ca, cb, frame.frequency, frame.sense, frame.offset)
            var_names += list(FACE_VARIABLES)
        names = [_term_name(t, var_names) for t in terms]
        first: dict[str, int] = {}
        for i, name in enumerate(names):  # equal terms have equal names
            if first.setdefault(name, i) != i:
                raise UserError(
                    f"library {spec} has the term {name!r} twice (or two frequencies that "
                    "print alike): remove the overlap between its parts"
                )
        one = len(var_names)
        # Trig columns of F: every (variable, function) some term uses, sines first.
        trig_keys = sorted({f for t in terms for f in t if f[1] != _IDENTITY}, key=_trig_order)
        column = {f: one + 1 + k for k, f in enumerate(trig_keys)}
        column.update({(v, _IDENTITY, 1.0): v for v in range(one)})
        width = max([1, *(len(t) for t in terms)])
        rows = [[column[f] for f in t] + [one] * (width - len(t)) for t in terms]
        super().__init__(
            n_state,
            n_control,
            torch.tensor(rows, dtype=torch.long).reshape(len(rows), width),
            names,
            [(v, _FN_NAMES[fn], freq) for v, fn, freq in trig_keys],
            face,
        )
        self.spec: LibrarySpec = spec

    def _term_tensor(self, terms: TermIndex) -> torch.Tensor:
        idx = torch.as_tensor(terms, dtype=torch.long).reshape(-1)
        p = self.n_terms
        if idx.numel() and (idx.min() < -p or idx.max() >= p):
            raise ValueError(
                f"term indices must lie in [-{p}, {p}) for this {p}-term library, "
                f"got min {int(idx.min())}, max {int(idx.max())}"
            )
        return torch.where(idx < 0, idx + p, idx)

    def forward(
        self,
        z: torch.Tensor,
        u: torch.Tensor | None = None,
        terms: TermIndex | None = None,
    ) -> torch.Tensor:
        """Θ(z, u): z (..., nz), u (..., nu) -> (..., p), or (..., len(terms)) for a subset.

        For repeated subset evaluation build the subset once with :meth:`subset`.
        """
        if terms is None:
            return self._evaluate(z, u, self.table)
        idx = self._term_tensor(terms).to(self.table.device)
        return self._evaluate(z, u, self.table.index_select(0, idx))

    def subset(self, terms: TermIndex) -> LibrarySubset:
        """A module evaluating only ``terms`` (indices into :attr:`names`), in that order."""
        return LibrarySubset(self, self._term_tensor(terms))

    def _combine(self, other: object, op: Callable[[Any, Any], LibrarySpec]) -> SindyLibrary:
        if not isinstance(other, SindyLibrary):
            return NotImplemented
        if (other.n_state, other.n_control) != (self.n_state, self.n_control):
            raise ValueError(
                f"cannot combine libraries of sizes (nz={self.n_state}, nu={self.n_control}) "
                f"and (nz={other.n_state}, nu={other.n_control}): build both for one model"
            )
        return SindyLibrary(op(self.spec, other.spec), self.n_state, self.n_control)

    def __add__(self, other: SindyLibrary) -> SindyLibrary:
        """Concatenation of the two libraries' terms."""
        return self._combine(other, lambda a, b: a + b)

    def __mul__(self, other: SindyLibrary) -> SindyLibrary:
        """Tensor product of the two libraries' terms."""
        return self._combine(other, lambda a, b: a * b)

    def extra_repr(self) -> str:
        return f"{super().extra_repr()}, spec={self.spec}"


class CandidateLibrary(SindyLibrary):
    """The classic library: monomials of [z, u] up to ``order``, then sin(z), then cos(z).

    The spec :func:`poly_library` ``(order, include_sine, include_cosine)``; the monomials have
    the order, names and values of ``pysindy.PolynomialLibrary(degree=order,
    include_bias=True)``.

    Args:
        n_state: nz, number of state (latent) variables, named ``z0 .. z{nz-1}``.
        n_control: nu, number of control inputs, named ``u0 .. u{nu-1}`` (may be 0).
        order: highest total degree of the monomials, one of 1, 2, 3, 4.
        include_sine: append ``sin(z_i)`` for every state variable.
        include_cosine: append ``cos(z_i)`` for every state variable (after the sines).
    """

    def __init__(
        self,
        n_state: int,
        n_control: int,
        order: int,
        include_sine: bool = True,
        include_cosine: bool = False,
    ) -> None:
        if (
            isinstance(order, bool)
            or not isinstance(order, numbers.Integral)
            or (order not in VALID_ORDERS)
        ):
            raise ValueError(
                f"library order must be one of {VALID_ORDERS}, got {order!r}; "
                "choose a polynomial degree from 1 to 4"
            )
        order = int(order)
        super().__init__(poly_library(order, include_sine, include_cosine), n_state, n_control)
        self.order = order
        self.include_sine = include_sine
        self.include_cosine = include_cosine
