"""Differentiable SINDy candidate library Θ(z, u) in torch, with sparse (active-term) evaluation.

The library holds the candidate functions a SINDy model combines linearly: every monomial of
the concatenated variables ``[z0 .. z_{nz-1}, u0 .. u_{nu-1}]`` up to ``order`` (constant
included), in the same order and with the same names as
``pysindy.PolynomialLibrary(degree=order, include_bias=True)``, then ``sin(z_i)`` (and
optionally ``cos(z_i)``) of the state variables only.

Every term, the sines included, is stored as one row of an integer table of at most ``order``
indices into a feature vector ``F = [z, u, 1, sin z, cos z]``; a term is the product of the
features its row names (unused slots point at the constant ``1``). Evaluation is one gather
and multiply per slot, so the hot path has no Python loop over terms, and evaluating a subset
of terms is the same code on a subset of the rows.

    >>> lib = CandidateLibrary(n_state=16, n_control=3, order=2)
    >>> lib.n_terms
    226
    >>> theta = lib(torch.zeros(5, 16), torch.zeros(5, 3))  # (5, 226)
"""

from __future__ import annotations

import itertools
import numbers
from collections.abc import Sequence

import torch
from torch import nn

__all__ = ["VALID_ORDERS", "CandidateLibrary", "LibrarySubset"]

VALID_ORDERS = (1, 2, 3, 4)

TermIndex = Sequence[int] | torch.Tensor


def _monomial_name(variables: tuple[int, ...], var_names: Sequence[str]) -> str:
    """pysindy's name of the monomial multiplying ``variables`` (sorted, repeats allowed)."""
    if not variables:
        return "1"
    parts = []
    for var, group in itertools.groupby(variables):
        power = len(list(group))
        parts.append(var_names[var] if power == 1 else f"{var_names[var]}^{power}")
    return " ".join(parts)


class _ProductTerms(nn.Module):
    """Terms given as rows of feature indices; evaluates their products.

    Subclasses set ``table`` (p, width) long buffer, ``names`` and the flags saying whether any
    row uses a sine or cosine feature (so a subset without them skips computing them).
    """

    table: torch.Tensor  # (p, width) indices into the feature vector F

    def __init__(
        self,
        n_state: int,
        n_control: int,
        table: torch.Tensor,
        names: list[str],
    ) -> None:
        super().__init__()
        self.n_state = n_state
        self.n_control = n_control
        self.register_buffer("table", table, persistent=False)
        self.names = names
        self._one = n_state + n_control  # column of F holding the constant 1
        self._sin0 = self._one + 1  # first sine column
        self._cos0 = self._sin0 + n_state  # first cosine column
        self._needs_sin = bool(((table >= self._sin0) & (table < self._cos0)).any())
        self._needs_cos = bool((table >= self._cos0).any())

    @property
    def n_terms(self) -> int:
        return int(self.table.shape[0])

    def _features(self, z: torch.Tensor, u: torch.Tensor | None) -> torch.Tensor:
        """F = [z, u, 1, sin z, cos z]: (..., nz + nu + 1 + nz [+ nz])."""
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
        parts.append(z.new_ones((*z.shape[:-1], 1)))
        # A table never points past the columns built here (sines before cosines).
        if self._needs_sin or self._needs_cos:
            parts.append(torch.sin(z))
        if self._needs_cos:
            parts.append(torch.cos(z))
        return torch.cat(parts, dim=-1)

    def _evaluate(
        self, z: torch.Tensor, u: torch.Tensor | None, table: torch.Tensor
    ) -> torch.Tensor:
        feats = self._features(z, u)  # (..., n_features)
        out = feats.index_select(-1, table[:, 0])  # (..., p)
        for k in range(1, table.shape[1]):  # at most order - 1 iterations
            out = out * feats.index_select(-1, table[:, k])
        return out

    def forward(self, z: torch.Tensor, u: torch.Tensor | None = None) -> torch.Tensor:
        """Θ(z, u): z (..., nz), u (..., nu) -> (..., p)."""
        return self._evaluate(z, u, self.table)

    def extra_repr(self) -> str:
        return f"n_state={self.n_state}, n_control={self.n_control}, n_terms={self.n_terms}"


class LibrarySubset(_ProductTerms):
    """The chosen terms of a :class:`CandidateLibrary`, in the chosen order.

    ``subset(idx)(z, u)`` equals ``library(z, u)[..., idx]`` but computes only those terms.
    """

    def __init__(self, parent: CandidateLibrary, terms: torch.Tensor) -> None:
        super().__init__(
            parent.n_state,
            parent.n_control,
            parent.table.index_select(0, terms.to(parent.table.device)).clone(),
            [parent.names[i] for i in terms.tolist()],
        )
        self.register_buffer("terms", terms.clone(), persistent=False)  # (p_sub,) parent indices


class CandidateLibrary(_ProductTerms):
    """Candidate functions Θ(z, u) for SINDy: monomials of [z, u] up to ``order``, then sin(z).

    Args:
        n_state: nz, number of state (latent) variables, named ``z0 .. z{nz-1}``.
        n_control: nu, number of control inputs, named ``u0 .. u{nu-1}`` (may be 0).
        order: highest total degree of the monomials, one of 1, 2, 3, 4.
        include_sine: append ``sin(z_i)`` for every state variable.
        include_cosine: append ``cos(z_i)`` for every state variable (after the sines).

    Attributes:
        names: term names in column order, pysindy style (``1``, ``z0 u2``, ``z3^2``,
            ``sin(z1)``).
        n_terms: p, the number of columns of Θ.
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
        if n_state < 1 or n_control < 0:
            raise ValueError(
                f"need n_state >= 1 and n_control >= 0, got n_state={n_state}, "
                f"n_control={n_control}"
            )
        order = int(order)
        n_vars = n_state + n_control
        var_names = [f"z{i}" for i in range(n_state)] + [f"u{j}" for j in range(n_control)]
        one = n_vars  # F column of the constant, used to pad rows of lower degree

        rows: list[list[int]] = []
        names: list[str] = []
        # pysindy's order: by degree, then itertools.combinations_with_replacement.
        for degree in range(order + 1):
            for combo in itertools.combinations_with_replacement(range(n_vars), degree):
                rows.append(list(combo) + [one] * (order - degree))
                names.append(_monomial_name(combo, var_names))
        if include_sine:
            for i in range(n_state):
                rows.append([one + 1 + i] + [one] * (order - 1))
                names.append(f"sin(z{i})")
        if include_cosine:
            for i in range(n_state):
                rows.append([one + 1 + n_state + i] + [one] * (order - 1))
                names.append(f"cos(z{i})")

        super().__init__(n_state, n_control, torch.tensor(rows, dtype=torch.long), names)
        self.order = order
        self.include_sine = include_sine
        self.include_cosine = include_cosine

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

    def extra_repr(self) -> str:
        return (
            f"{super().extra_repr()}, order={self.order}, include_sine={self.include_sine}, "
            f"include_cosine={self.include_cosine}"
        )
