"""Differentiable SINDy candidate libraries Θ(z, u) in torch: the modules of a spec.

:class:`SindyLibrary` builds the module of a spec (:mod:`latent_sindy.sindy.grammar`) for given
sizes, from the terms :func:`~latent_sindy.sindy.terms.compile_terms` lists;
:class:`LibrarySubset` evaluates some of its terms; :class:`CandidateLibrary` is the classic
library (monomials of ``[z, u]`` up to ``order``, then ``sin(z)``, optionally ``cos(z)``).
Evaluation is one gather and multiply per column of the term table, so the hot path has no
Python loop over terms, and a subset of terms is the same code on a subset of the rows.

    >>> spec = Polynomial("z,u", degree=2) + Sine("z") + Identity("u2") * Cosine("u1")
    >>> lib = SindyLibrary(spec, n_state=16, n_control=3)
    >>> lib.n_terms, lib.names[-1]
    (227, 'u2 cos(u1)')
    >>> theta = lib(torch.zeros(5, 16), torch.zeros(5, 3))  # (5, 227)
    >>> CandidateLibrary(n_state=16, n_control=3, order=2).n_terms
    226
"""

from __future__ import annotations

import numbers
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import torch
from torch import nn

from latent_sindy.sindy.grammar import LibrarySpec, spec_from_dict
from latent_sindy.sindy.named_libraries import poly_library
from latent_sindy.sindy.terms import BoundDerived, compile_terms

__all__ = ["VALID_ORDERS", "CandidateLibrary", "LibrarySubset", "SindyLibrary"]

VALID_ORDERS = (1, 2, 3, 4)

TermIndex = Sequence[int] | torch.Tensor


class _ProductTerms(nn.Module):
    """Terms given as rows of feature indices into F = [z, u, derived, 1, trig...]; evaluates
    them.

    ``table`` (p, width) long buffer; ``trig`` lists the trig columns of F after the constant
    as ``(variable index into [z, u, derived], "sin" | "cos", frequency)``, sines first;
    ``derived`` computes the derived variables from [z, u], or is None.
    """

    table: torch.Tensor  # (p, width) indices into the feature vector F
    _sin_idx: torch.Tensor  # (n_sin,) indices into [z, u, derived]
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
        derived: BoundDerived | None = None,
    ) -> None:
        super().__init__()
        self.n_state = n_state
        self.n_control = n_control
        self.derived = derived
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
        self._one = n_state + n_control + (len(derived.node.names) if derived else 0)

    @property
    def n_terms(self) -> int:
        return int(self.table.shape[0])

    @property
    def constant_column(self) -> int:
        """F's column of the constant 1: the variables [z, u, derived] come before it."""
        return self._one

    @property
    def degrees(self) -> torch.Tensor:
        """(p,) long: factors per term (``1`` has 0, ``z0 z1^2`` 3, ``z0 sin(u1)`` 2): the
        terms' complexity, for :class:`~latent_sindy.sindy.StepwiseSR`."""
        return (self.table != self._one).sum(dim=1).cpu()

    @property
    def n_features(self) -> int:
        """Columns of F = [z, u, derived, 1, trig...]."""
        return self._one + 1 + len(self.trig)

    def _features(self, z: torch.Tensor, u: torch.Tensor | None) -> torch.Tensor:
        """F = [z, u, derived, 1, sin(x[sin_idx]), cos(x[cos_idx])]: (..., n_features)."""
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
        if self.derived is not None:
            parts += [v.unsqueeze(-1) for v in self.derived(torch.cat(parts, dim=-1))]
        parts.append(z.new_ones((*z.shape[:-1], 1)))
        base = torch.cat(parts, dim=-1)  # (..., nz + nu (+ derived) + 1)
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
            parent.derived,
        )
        self.register_buffer("terms", terms.clone(), persistent=False)


class SindyLibrary(_ProductTerms):
    """The torch library of a spec for ``n_state`` states and ``n_control`` controls.

    Args:
        spec: a :class:`LibrarySpec` (or its :meth:`~LibrarySpec.to_dict` form).
        n_state: nz, state variables ``z0 .. z{nz-1}``.
        n_control: nu, control inputs ``u0 .. u{nu-1}`` (may be 0).

    Attributes:
        spec: the spec (rebuilds this library with the same sizes).
        names: term names in column order, pysindy style.
        n_terms: p, the number of columns of Θ.
        trig: ``(variable index into [z, u, derived], "sin" | "cos", frequency)`` of F's trig
            columns.
        derived: the spec's derived variables bound to the sizes, or None.

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
        compiled = compile_terms(spec, n_state, n_control)
        rows = compiled.rows
        width = len(rows[0]) if rows else 1
        super().__init__(
            n_state,
            n_control,
            torch.tensor(rows, dtype=torch.long).reshape(len(rows), width),
            compiled.names,
            compiled.trig,
            compiled.derived,
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

    The spec :func:`~latent_sindy.sindy.named_libraries.poly_library` ``(order, include_sine,
    include_cosine)``; the monomials have the order, names and values of
    ``pysindy.PolynomialLibrary(degree=order, include_bias=True)``.

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
