"""The term compiler: a spec (:mod:`latent_sindy.sindy.grammar`) and the model's sizes -> the
library's terms as rows of feature indices, with pysindy's names.

Every term is one row of an integer table of feature indices into the feature vector
``F = [x, 1, sin(f x_a), .., cos(f x_b), ..]``, with ``x = [z, u]``, then the derived
variables of the spec's :class:`~latent_sindy.sindy.grammar.DerivedVariables` node if it has
one. The trig columns are listed in ``trig`` as ``(variable index into x, "sin" | "cos",
frequency)``, sines first; a term is the product of the features its row names, shorter rows
padded with the constant. Term names follow pysindy: ``1``, ``z0 u2``, ``z3^2``, ``sin(z1)``,
``u2 cos(u1)``, ``z2 sin(4 u1)`` (monomial factors first, by variable, then trig ones).

    >>> compiled = compile_terms(Polynomial("z", 2) + Sine("u0"), n_state=2, n_control=1)
    >>> compiled.names
    ['1', 'z0', 'z1', 'z0^2', 'z0 z1', 'z1^2', 'sin(u0)']
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from latent_sindy.errors import UserError
from latent_sindy.sindy.grammar import (
    _DERIVED,
    _VARIABLE,
    Constant,
    DerivedVariables,
    LibrarySpec,
    Polynomial,
    Product,
    Sum,
    _Trig,
)

__all__ = ["BoundDerived", "CompiledTerms", "compile_terms"]

# A factor of a term: (variable index into x, function, frequency); a term is a sorted tuple.
# Monomial factors have frequency 1.
_IDENTITY, _SIN, _COS = 0, 1, 2
_FN_NAMES = {_SIN: "sin", _COS: "cos"}
_FN_CODES = {"sin": _SIN, "cos": _COS}
_Factor = tuple[int, int, float]
_Term = tuple[_Factor, ...]


def _factor_key(f: _Factor) -> tuple[bool, int, int, float]:
    """Monomial factors first by variable, then trig factors by variable, sine before cosine,
    then by frequency."""
    return (f[1] != _IDENTITY, f[0], f[1], f[2])


def _trig_order(f: _Factor) -> tuple[int, int, float]:
    """Trig columns of F: sines first, each by variable, then by frequency."""
    return (f[1], f[0], f[2])


def _canonical(factors: Sequence[_Factor]) -> _Term:
    return tuple(sorted(factors, key=_factor_key))


@dataclass(frozen=True)
class BoundDerived:
    """A library's derived-variable definition at its sizes: the node (its body dropped) and
    the indices into ``[z, u]`` of the variables it reads."""

    node: DerivedVariables
    inputs: tuple[int, ...]

    def __call__(self, x: Any) -> tuple[Any, ...]:
        """The derived variables from x = [z, u] (..., nz + nu): a tuple of (...) tensors."""
        return self.node.evaluate(*(x[..., i] for i in self.inputs))


@dataclass(frozen=True)
class CompiledTerms:
    """A spec's terms at given sizes."""

    rows: list[list[int]]
    """(p, width) feature indices into F; shorter terms padded with the constant's column."""
    names: list[str]
    trig: list[tuple[int, str, float]]
    """F's trig columns after the constant: (variable index into x, "sin" | "cos", frequency)."""
    derived: BoundDerived | None
    variable_names: list[str]
    """x's names: z0 .., u0 .., then the derived variables'; the constant is column len(x)."""


def _derived_of(spec: LibrarySpec) -> DerivedVariables | None:
    """The spec's derived-variable node (one, or equal ones), its body dropped, or None."""
    found: set[DerivedVariables] = set()

    def walk(node: LibrarySpec) -> None:
        if isinstance(node, DerivedVariables):
            found.add(dataclasses.replace(node, body=Constant()))
            walk(node.body)
        for child in getattr(node, "parts", ()) + getattr(node, "factors", ()):
            walk(child)

    walk(spec)
    if len(found) > 1:
        kinds = sorted({d.kind for d in found})
        raise UserError(f"library {spec} defines derived variables twice, differently: use "
                        f"one {' or '.join(kinds)} node around the whole library")
    return next(iter(found), None)


def _resolve(names: tuple[str, ...], n_state: int, n_control: int,
             derived: DerivedVariables | None = None) -> list[int]:
    """Variable names -> sorted, distinct indices into x = [z, u, derived]."""
    out: set[int] = set()
    for name in names:
        m = _VARIABLE.match(name)
        assert m is not None  # checked when the spec was made
        if m.group(3) is not None:
            if derived is None or name not in derived.names:
                owner = _DERIVED[name].__name__  # registered: checked when the spec was made
                raise UserError(f"library variable {name!r} is a derived variable: wrap the "
                                f"library in {owner}(...) to define it")
            out.add(n_state + n_control + derived.names.index(name))
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
                derived: DerivedVariables | None = None) -> list[_Term]:
    if isinstance(spec, DerivedVariables):
        return _spec_terms(spec.body, n_state, n_control, derived)
    if isinstance(spec, Sum):
        return [t for part in spec.parts for t in _spec_terms(part, n_state, n_control, derived)]
    if isinstance(spec, Product):
        terms: list[_Term] = [()]
        for factor in spec.factors:
            right = _spec_terms(factor, n_state, n_control, derived)
            # Each distinct product once, where it first appears (z2 * z3 = z3 * z2).
            terms = list(dict.fromkeys(_canonical(a + b) for a in terms for b in right))
        return terms
    if isinstance(spec, Constant):
        return [()]
    variables = _resolve(spec.variables, n_state, n_control, derived)  # type: ignore[attr-defined]
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


def _bind(node: DerivedVariables, n_state: int, n_control: int) -> BoundDerived:
    inputs = []
    for name in node.inputs():
        index = _resolve((name,), n_state, n_control)
        if len(index) != 1:
            raise UserError(f"{node.kind}: input {name!r} names {len(index)} variables; name "
                            "one, such as 'u1' or 'z2'")
        inputs.append(index[0])
    return BoundDerived(node, tuple(inputs))


def compile_terms(spec: LibrarySpec, n_state: int, n_control: int) -> CompiledTerms:
    """The terms of ``spec`` for ``n_state`` states and ``n_control`` controls.

    Raises:
        UserError: a variable beyond the sizes, or a term that appears twice.
    """
    node = _derived_of(spec)
    terms = _spec_terms(spec, n_state, n_control, node)
    var_names = [f"z{i}" for i in range(n_state)] + [f"u{j}" for j in range(n_control)]
    derived = None
    if node is not None:
        derived = _bind(node, n_state, n_control)
        var_names += list(node.names)
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
    trig = [(v, _FN_NAMES[fn], freq) for v, fn, freq in trig_keys]
    return CompiledTerms(rows, names, trig, derived, var_names)
