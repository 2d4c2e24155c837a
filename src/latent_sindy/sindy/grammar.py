"""The grammar of candidate libraries: specs, small frozen dataclass trees that are independent
of the model's sizes and serialise to JSON (:meth:`LibrarySpec.to_dict` / :func:`spec_from_dict`).

* :class:`Polynomial` ``(variables, degree, bias)``: every monomial of the variables up to
  ``degree`` (the constant ``1`` when ``bias``), in the order and with the names of
  ``pysindy.PolynomialLibrary``;
* :class:`Sine`, :class:`Cosine` ``(variables, frequency)``: ``sin(f x)`` / ``cos(f x)`` of
  each variable (named ``sin(x)``, ``sin(4 x)``);
* :class:`Identity` ``(variables)``: the variables themselves;
* :class:`Constant` ``()``: the term ``1`` (``(Constant() + a) * b`` keeps ``b``'s terms);
* ``a + b`` (:class:`Sum`): the terms of ``a``, then those of ``b``;
* ``a * b`` (:class:`Product`): every product of a term of ``a`` with a term of ``b``
  (row-major: for each term of ``a``, every term of ``b``), each distinct product once;
* a :class:`DerivedVariables` node: its ``body``'s terms, which may use variables the node
  computes from ``[z, u]``. The core defines no such node; a world registers its own
  (:func:`register_derived`) under the dict key its runs store.

Variables are named ``z0 .. z{nz-1}`` (state) and ``u0 .. u{nu-1}`` (control); ``"z"`` and
``"u"`` stand for the whole group; any other name is a registered derived variable.

    >>> spec = Polynomial("z,u", degree=2) + Sine("z") + Identity("u2") * Cosine("u1")
    >>> spec_from_dict(spec.to_dict()) == spec
    True
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, TypeVar

from latent_sindy.errors import UserError
from latent_sindy.plugins import load_plugins

__all__ = [
    "Constant",
    "Cosine",
    "DerivedVariables",
    "Identity",
    "LibrarySpec",
    "Polynomial",
    "Product",
    "Sine",
    "Sum",
    "derived_variables",
    "register_derived",
    "spec_from_dict",
    "variables",
]

_VARIABLE = re.compile(r"^([zu])(\d+)?$|^([A-Za-z_]\w*)$")

# Node kinds spec_from_dict reads (the core's leaves here; Sum and Product apart), and the
# derived variables' names with the node class that defines each: filled by register_derived.
_KINDS: dict[str, type[LibrarySpec]] = {}
_DERIVED: dict[str, type[DerivedVariables]] = {}


def derived_variables() -> dict[str, str]:
    """The registered derived variables: name -> the node kind that defines it (world
    plug-ins loaded first)."""
    load_plugins()
    return {name: cls.kind for name, cls in _DERIVED.items()}


def _derived_owner(name: str) -> type[DerivedVariables] | None:
    """The node class that defines the derived variable ``name`` (plug-ins loaded if unknown)."""
    if name not in _DERIVED:
        load_plugins()
    return _DERIVED.get(name)


def variables(value: str | Sequence[str]) -> tuple[str, ...]:
    """``"z,u"``, ``"z u1"`` or ``("z", "u1")`` -> ``("z", "u1")``, names checked."""
    names = tuple(re.split(r"[,\s]+", value.strip())) if isinstance(value, str) else tuple(value)
    if not names or names == ("",):
        raise UserError("a library part needs at least one variable: name e.g. 'z', 'u' or 'u1'")
    for name in names:
        m = _VARIABLE.match(name) if isinstance(name, str) else None
        if m is None or (m.group(3) is not None and _derived_owner(name) is None):
            known = ", ".join(f"{n!r} ({c.__name__})" for n, c in _DERIVED.items()) or "none"
            raise UserError(
                f"library variable {name!r} is not valid: use 'z' or 'u' (the whole group), "
                f"one variable such as 'z3' or 'u1', or a registered derived variable: {known}"
            )
    return names


class LibrarySpec:
    """The base of every spec node: ``+`` and ``*``, and :meth:`to_dict`. Subclasses are frozen
    dataclasses with a ``kind`` (their dict key)."""

    kind: ClassVar[str]

    def __add__(self, other: LibrarySpec) -> Sum:
        if not isinstance(other, LibrarySpec):
            return NotImplemented
        return Sum((*_summands(self), *_summands(other)))

    def __mul__(self, other: LibrarySpec) -> Product:
        if not isinstance(other, LibrarySpec):
            return NotImplemented
        return Product((*_multiplicands(self), *_multiplicands(other)))

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict that :func:`spec_from_dict` turns back into this spec."""
        out: dict[str, Any] = {"kind": self.kind}
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            value = getattr(self, f.name)
            if isinstance(value, LibrarySpec):
                out[f.name] = value.to_dict()
            elif isinstance(value, tuple) and value and isinstance(value[0], LibrarySpec):
                out[f.name] = [v.to_dict() for v in value]
            elif isinstance(value, tuple):
                out[f.name] = list(value)
            else:
                out[f.name] = value
        return out


@dataclass(frozen=True)
class _Group(LibrarySpec):
    """A leaf over a group of variables."""

    variables: tuple[str, ...] = ("z",)
    """Variable names: ``"z"``/``"u"`` (all states / controls) or ``"z3"``, ``"u1"``; a string
    ``"z,u"`` is split."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "variables", variables(self.variables))

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
    Features of an angle with a visible symmetry of order f (2π / its period) need
    ``sin(f x)``."""

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
class Constant(LibrarySpec):
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
class Sum(LibrarySpec):
    """Concatenation: the terms of every part, in order (``a + b``)."""

    kind: ClassVar[str] = "sum"
    parts: tuple[LibrarySpec, ...]

    def __post_init__(self) -> None:
        _check_children(self, "parts", "sum")

    def __str__(self) -> str:
        return " + ".join(str(p) for p in self.parts)


@dataclass(frozen=True)
class Product(LibrarySpec):
    """Tensor product: every product of one term of each factor (``a * b``), row-major; a
    product met again (``z2 · z3`` after ``z3 · z2``) is kept only where it first appears."""

    kind: ClassVar[str] = "product"
    factors: tuple[LibrarySpec, ...]

    def __post_init__(self) -> None:
        _check_children(self, "factors", "product")

    def __str__(self) -> str:
        return " * ".join(f"({f})" if isinstance(f, Sum) else str(f) for f in self.factors)


@dataclass(frozen=True)
class DerivedVariables(LibrarySpec):
    """``body``'s terms, with the variables :attr:`names` defined for them: functions of
    ``[z, u]`` that the subclass computes (a world's, registered with :func:`register_derived`).

    A subclass is a frozen dataclass whose fields after ``body`` are its parameters, and
    implements :meth:`inputs` (the variables of ``[z, u]`` it reads, one each) and
    :meth:`evaluate` (torch). For the fused CPU control step it may also give
    :meth:`numba_function` and :meth:`numba_parameters`; without them that step runs in torch.
    In a library the derived variables come after ``[z, u]`` in the order of :attr:`names`.
    """

    kind: ClassVar[str] = "derived"
    names: ClassVar[tuple[str, ...]] = ()
    """The derived variables' names, such as ``("a", "n")``."""
    body: LibrarySpec

    def __post_init__(self) -> None:
        if isinstance(self.body, Mapping):
            object.__setattr__(self, "body", spec_from_dict(self.body))
        if not isinstance(self.body, LibrarySpec):
            raise UserError(f"a {self.kind} node holds a library spec, got {self.body!r}")

    def inputs(self) -> tuple[str, ...]:
        """The variables of ``[z, u]`` the definition reads, one variable each (``"u1"``)."""
        raise NotImplementedError

    def evaluate(self, *inputs: Any) -> tuple[Any, ...]:
        """The derived variables (tensors) from the :meth:`inputs` (tensors of one shape)."""
        raise NotImplementedError

    def numba_parameters(self) -> tuple[float, ...]:
        """The numbers :meth:`numba_function` reads, in its ``params``."""
        return ()

    def numba_function(self, dtype: str) -> Any:
        """A numba ``cfunc`` of signature
        :func:`latent_sindy.control.derived.derived_signature` ``(dtype)`` that writes
        the derived variables into the control kernel's feature rows, or None (the control
        step then runs in torch). ``dtype``: ``"float32"`` or ``"float64"``."""
        return None

    def __str__(self) -> str:
        return f"{self.kind}[{self.body}]"


_Derived = TypeVar("_Derived", bound=type[DerivedVariables])


def register_derived(cls: _Derived) -> _Derived:
    """Register a :class:`DerivedVariables` subclass by its ``kind`` (the dict key
    :func:`spec_from_dict` reads) and its variable names; usable as a class decorator.
    Registering the same class again (a reloaded module) replaces it."""
    if not (isinstance(cls, type) and issubclass(cls, DerivedVariables)) or not cls.names:
        raise TypeError(f"register_derived needs a DerivedVariables subclass with names, got "
                        f"{cls!r}")
    def same(other: type) -> bool:
        return (other.__module__, other.__qualname__) == (cls.__module__, cls.__qualname__)

    taken = _KINDS.get(cls.kind)
    if cls.kind in ("sum", "product") or (taken is not None and not same(taken)):
        raise ValueError(f"library node kind {cls.kind!r} is taken: give {cls.__name__} "
                         "another kind")
    for name in cls.names:
        m = _VARIABLE.match(name)
        owner = _DERIVED.get(name)
        if m is None or m.group(3) is None or (owner is not None and not same(owner)):
            raise ValueError(f"derived variable {name!r} of {cls.__name__}: use a name that is "
                             "not a state or control variable (z3, u1) nor another node's")
    _KINDS[cls.kind] = cls
    _DERIVED.update(dict.fromkeys(cls.names, cls))
    return cls


_KINDS.update({c.kind: c for c in (Polynomial, Sine, Cosine, Identity, Constant)})


def _check_children(spec: Sum | Product, field: str, what: str) -> None:
    children = getattr(spec, field)
    if isinstance(children, list):
        object.__setattr__(spec, field, children := tuple(children))
    if not isinstance(children, tuple) or not children:
        raise UserError(f"a library {what} needs a non-empty tuple of parts, got {children!r}")
    for c in children:
        if not isinstance(c, LibrarySpec):
            raise UserError(f"a library {what} holds specs such as Polynomial(...), got {c!r}")


def _summands(spec: LibrarySpec) -> tuple[LibrarySpec, ...]:
    return spec.parts if isinstance(spec, Sum) else (spec,)


def _multiplicands(spec: LibrarySpec) -> tuple[LibrarySpec, ...]:
    return spec.factors if isinstance(spec, Product) else (spec,)


def spec_from_dict(d: Mapping[str, Any] | LibrarySpec) -> LibrarySpec:
    """Rebuild a spec from :meth:`~LibrarySpec.to_dict` output (a spec is returned as it is).
    A kind no one registered loads the world plug-ins first (their nodes register then)."""
    if isinstance(d, LibrarySpec):
        return d
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
    if kind not in _KINDS:
        load_plugins()
    cls = _KINDS.get(kind)
    if cls is None:
        kinds = ", ".join([*_KINDS, "sum", "product"])
        raise UserError(f"library part kind {kind!r} is unknown: use one of {kinds}")
    allowed = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    if set(fields) - allowed:
        raise UserError(
            f"library part {kind!r} has unknown fields {sorted(set(fields) - allowed)}: "
            f"allowed {sorted(allowed)}"
        )
    # JSON has lists where specs have tuples (variables, a node's parameters).
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in fields.items()})
