"""Latent dynamics models behind one interface: SINDy, globally linear (E2C-like) and MLP.

Every model is a ``torch.nn.Module`` with ``step(z, u) -> z_next`` on batched tensors and a
shared ``rollout``, so MPPI, evaluation and figures never ask which model they hold. A model
built with ``circle=(a, b)`` (a latent that is a pose, (x, y, cos fθ, sin fθ): the state and
moments encoders, a coordinates pose head) scales (z_a, z_b) back onto the unit circle after
every step, so the angle features cannot drift off it in long open-loop rollouts; training,
prediction, evaluation and control all step through it. A model also describes itself
(``summary``, ``coefficient_rows``, ``equations``, ``stats``), so the equations report and
the study never ask either. Each kind has one config dataclass (its settings, its ``kind``
tag and ``build``) registered in :data:`DYNAMICS_CONFIGS`: a new kind is one model class, one
config class and one entry there.
Dimensions: K samples (batch), H horizon, nz latent size, nu action size, p library terms.

    >>> model = SindyConfig(order=2).build(nz=16, nu=3)
    >>> z = model.rollout(torch.zeros(4, 16), torch.zeros(4, 10, 3))  # (4, 11, 16)
    >>> pose = SindyConfig(order=1, library="face").build(nz=4, nu=3, circle=(2, 3))
    >>> fast = model.compile_sparse()  # same step, only the active library terms
    >>> from latent_sindy.sindy import push_library  # any composed library spec
    >>> push = make_dynamics("sindy", nz=16, nu=3, library_spec=push_library(order=2))
    >>> push.fit_state_data(Z, U, Znext)  # sparse regression (STLSQ) on states: (N, nz), ...
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, ClassVar, Literal, Union

import torch
import tyro
from torch import nn

from latent_sindy.errors import UserError
from latent_sindy.sindy import fit as sindy_fit
from latent_sindy.sindy.library import (
    VALID_ORDERS,
    CandidateLibrary,
    LibrarySpec,
    LibrarySubset,
    SindyLibrary,
    Sine,
    face_library,
    frame_library,
    push_library,
    spec_from_dict,
)
from latent_sindy.sindy.optimizers import STLSQ

__all__ = [
    "DYNAMICS_CONFIGS",
    "DYNAMICS_KINDS",
    "DynamicsConfig",
    "LatentDynamics",
    "LinearConfig",
    "LinearDynamics",
    "MlpConfig",
    "MlpDynamics",
    "SindyConfig",
    "SindyDynamics",
    "SparseSindyDynamics",
    "format_equations",
    "make_dynamics",
    "project_circle",
]

#: One coefficient of a model's equations: (state, term, value), e.g. ("z3", "z0 u2", 0.05).
Row = tuple[str, str, float]


def turn_circle(z: torch.Tensor, z_next: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """``z_next`` with its pair ``index`` = (a, b) replaced by z's pair turned by the angle
    ω = z_next[a] − z[a]: z_a + i z_b multiplied by e^{iω}. Out of place, differentiable."""
    a, b = index[0], index[1]
    omega = z_next[..., a] - z[..., a]
    cos, sin = torch.cos(omega), torch.sin(omega)
    za, zb = z[..., a], z[..., b]
    pair = torch.stack([za * cos - zb * sin, zb * cos + za * sin], -1)
    return z_next.index_copy(-1, index, pair)


def project_circle(z: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """z (..., nz) with the two coordinates ``index`` (2,) divided by their norm, so they lie on
    the unit circle: (z_a, z_b) / sqrt(z_a² + z_b² + tiny) (a pair at 0 stays 0). Out of place
    and differentiable; NaN and inf stay non-finite."""
    pair = z.index_select(-1, index)  # (..., 2)
    norm = torch.sqrt(pair.square().sum(-1, keepdim=True) + torch.finfo(z.dtype).tiny)
    return z.index_copy(-1, index, pair / norm)


class LatentDynamics(nn.Module):
    """Base class: a discrete-time latent model ``z_{t+1} = f(z_t, u_t)``.

    Subclasses implement :meth:`_step`, the model's own update; the public :meth:`step` is it
    followed, for a model built with ``circle=(a, b)``, by :func:`project_circle` of
    (z_a, z_b), and :meth:`rollout` chains :meth:`step`. ``kind`` names the model in
    :data:`DYNAMICS_KINDS`, and :meth:`hparams` returns the constructor arguments, so
    ``make_dynamics(m.kind, **m.hparams())`` rebuilds an untrained copy of ``m``.

    Args:
        nz, nu: latent and action sizes.
        circle: the latent coordinates (a, b) of an angle's (cos, sin) features, kept on the
            unit circle after every step; None: none (the step is the model's own, unchanged).
        turn: with a circle, the model's update of z_a is read as the angle ω by which the
            pair turns (z_a + i z_b times e^{iω}, :func:`turn_circle`) and its update of z_b
            is unused, before the projection: a turn is one equation, exact at any angle.
    """

    kind: ClassVar[str] = ""
    _circle_index: torch.Tensor  # (2,) long, or (0,) without a circle

    def __init__(self, nz: int, nu: int, circle: Sequence[int] | None = None,
                 turn: bool = False) -> None:
        super().__init__()
        if nz < 1 or nu < 0:
            raise ValueError(f"need nz >= 1 and nu >= 0, got nz={nz}, nu={nu}")
        self.nz = nz
        self.nu = nu
        if circle is not None:
            circle = tuple(int(i) for i in circle)
            if len(circle) != 2 or circle[0] == circle[1] or not all(
                    0 <= i < nz for i in circle):
                raise ValueError(f"circle {circle}: give two different latent coordinates "
                                 f"in 0..{nz - 1} (the cos and sin features), or None")
        if turn and circle is None:
            raise ValueError("turn needs a circle: the latent coordinates of the angle's "
                             "(cos, sin) features")
        self.circle: tuple[int, int] | None = circle
        self.turn = bool(turn)
        self.register_buffer("_circle_index", torch.tensor(circle or (), dtype=torch.long),
                             persistent=False)

    def _step(self, z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """The model's own update, before any projection: z (K, nz), u (K, nu) -> (K, nz)."""
        raise NotImplementedError

    def step(self, z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """One step: z (K, nz), u (K, nu) -> z_next (K, nz), the circle's pair projected."""
        z_next = self._step(z, u)
        if self.circle is None:
            return z_next
        if self.turn:
            z_next = turn_circle(z, z_next, self._circle_index)
        return project_circle(z_next, self._circle_index)

    def forward(self, z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return self.step(z, u)

    def rollout(self, z0: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        """Open-loop prediction: z0 (B, nz), actions (B, H, nu) -> (B, H+1, nz), z0 at index 0."""
        if actions.ndim != 3 or actions.shape[0] != z0.shape[0] or actions.shape[2] != self.nu:
            raise ValueError(
                f"rollout expects actions of shape (B={z0.shape[0]}, H, nu={self.nu}), "
                f"got {tuple(actions.shape)}"
            )
        zs = [z0]
        for t in range(actions.shape[1]):
            zs.append(self.step(zs[-1], actions[:, t]))
        return torch.stack(zs, dim=1)  # (B, H+1, nz)

    def hparams(self) -> dict[str, Any]:
        """Constructor keyword arguments (nz and nu included) that rebuild this model."""
        if self.circle is None:
            return {"nz": self.nz, "nu": self.nu}
        if self.turn:
            return {"nz": self.nz, "nu": self.nu, "circle": self.circle, "turn": True}
        return {"nz": self.nz, "nu": self.nu, "circle": self.circle}

    # ---------------------------------------------------------------- self-description
    def summary(self) -> list[str]:
        """A few lines saying what the model is (the equations report's heading)."""
        return [f"{type(self).__name__} latent dynamics", *self._circle_note()]

    def _circle_note(self) -> list[str]:
        """The summary's line on the projection, if the model has one."""
        if self.circle is None:
            return []
        a, b = self.circle
        if self.turn:
            return [f"after every step (z{a}, z{b}) is turned by the angle ω that z{a}'s "
                    f"equation gives (z{a} + i z{b} times e^(iω)) and scaled onto the unit circle"]
        return [f"after every step (z{a}, z{b}) is scaled onto the unit circle"]

    def coefficient_rows(self) -> list[Row] | None:
        """Every coefficient of its equations as (state, term, value); None: it has none."""
        return None

    def equations(self, precision: int = 3) -> list[str]:
        """One readable update rule per latent state (empty if it has no equations)."""
        return []

    def export_info(self) -> dict[str, Any]:
        """What the coefficient files record besides the coefficients: the circle, and
        whether the model turns it (then z_a's coefficients give the angle ω, not z_a's
        update)."""
        if self.circle is None:
            return {}
        return {"circle": list(self.circle), "turn": self.turn}

    def stats(self) -> dict[str, float | None]:
        """Counts the study reports for every model: parameters, active coefficients and
        sparsity (None where the model has no such notion)."""
        n = sum(p.numel() for p in self.parameters())
        return {"params/dynamics": n, "sindy/active": None, "sindy/coefficients": None,
                "sindy/terms_used": None, "sindy/sparsity": None}


def format_equations(rows: list[Row], nz: int, precision: int, residual: bool) -> list[str]:
    """``z0[t+1] = [z0 +] 0.512 u0 - 0.0312 z1 z2 ...`` per state from coefficient rows.

    ``residual`` writes the identity part of a residual model (``z_{t+1} = z_t + ...``);
    coefficients are rounded to ``precision`` significant digits.
    """
    parts: dict[str, list[str]] = {f"z{j}": [] for j in range(nz)}
    for state, term, value in rows:
        mag = f"{abs(value):.{precision}g}"
        sign = "-" if value < 0 else "+"
        parts[state].append(f"{sign} {mag}" if term == "1" else f"{sign} {mag} {term}")
    lines = []
    for state, terms in parts.items():
        if residual:
            rhs = " ".join([state, *terms])
        else:
            rhs = " ".join(terms)
            rhs = rhs[2:] if rhs.startswith("+ ") else "-" + rhs[2:] if rhs else "0"
        lines.append(f"{state}[t+1] = {rhs}")
    return lines


class SindyDynamics(LatentDynamics):
    """Residual SINDy step ``z_{t+1} = z_t + Θ(z_t, u_t) (M ⊙ Ψ)``.

    Ψ (p, nz) is a parameter; M (p, nz) is a persistent boolean buffer (part of the state
    dict) that :meth:`threshold` only ever turns off. Column j of ``M ⊙ Ψ`` holds the
    coefficients of latent state j.

    Args:
        nz, nu: latent and action sizes.
        order: polynomial order of the classic library (1-4).
        include_sine, include_cosine: add sin(z_i) / cos(z_i) candidates to it.
        init_scale: standard deviation of the normal initialisation of Ψ.
        seed: seed for that initialisation; None draws from the global torch generator.
        library_spec: any library instead of the classic one: a
            :data:`~latent_sindy.sindy.library.LibrarySpec` or its ``to_dict()`` form (e.g.
            ``push_library(order=2, angle=1, length=2)``); then leave ``order``,
            ``include_sine`` and ``include_cosine`` at their defaults.
        circle, turn: see :class:`LatentDynamics` (with ``turn``, z_b's column has no
            candidates and counts in none of the sparsity figures).
    """

    kind = "sindy"
    mask: torch.Tensor  # (p, nz) bool
    library: SindyLibrary

    def __init__(
        self,
        nz: int,
        nu: int,
        order: int = 2,
        include_sine: bool = True,
        include_cosine: bool = False,
        init_scale: float = 1e-3,
        seed: int | None = None,
        library_spec: LibrarySpec | Mapping[str, Any] | None = None,
        circle: Sequence[int] | None = None,
        turn: bool = False,
    ) -> None:
        super().__init__(nz, nu, circle, turn)
        init: dict[str, Any]
        if library_spec is None:
            self.library = CandidateLibrary(nz, nu, order, include_sine, include_cosine)
            init = {"order": order, "include_sine": include_sine, "include_cosine": include_cosine}
        else:
            if (order, include_sine, include_cosine) != (2, True, False):
                raise ValueError(
                    f"SindyDynamics got library_spec and order={order}, include_sine="
                    f"{include_sine}, include_cosine={include_cosine}: put the polynomial "
                    "order and trig terms in the spec (e.g. poly_library(order, ...)) instead"
                )
            self.library = SindyLibrary(spec_from_dict(library_spec), nz, nu)
            init = {"library_spec": self.library.spec.to_dict()}
        p = self.library.n_terms
        gen = None if seed is None else torch.Generator().manual_seed(seed)
        self.psi = nn.Parameter(torch.randn(p, nz, generator=gen) * init_scale)  # (p, nz)
        self.register_buffer("mask", torch.ones(p, nz, dtype=torch.bool))  # (p, nz)
        self._free_turned_column()
        self._init = {**init, "init_scale": init_scale, "seed": seed}

    @property
    def names(self) -> list[str]:
        """Library term names, one per row of Ψ."""
        return self.library.names

    def hparams(self) -> dict[str, Any]:
        return {**super().hparams(), **self._init}

    def coefficients(self) -> torch.Tensor:
        """The effective coefficients M ⊙ Ψ: (p, nz)."""
        return self.psi * self.mask

    def _step(self, z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        theta = self.library(z, u)  # (K, p)
        return z + theta @ self.coefficients()  # (K, nz)

    @torch.no_grad()
    def threshold(self, tau: float) -> int:
        """Prune active coefficients with ``|Ψ| < tau``; return how many were newly pruned.

        Compares magnitudes, so negative coefficients are judged like positive ones. The mask
        only goes from on to off; pruned entries of Ψ are set to 0.
        """
        if tau < 0 or math.isnan(tau):
            raise ValueError(f"threshold tau must be a non-negative number, got {tau}")
        newly = self.mask & (self.psi.abs() < tau)
        self.mask &= ~newly
        self.psi.masked_fill_(~self.mask, 0.0)
        return int(newly.sum())

    @torch.no_grad()
    def set_coefficients(
        self, coef: torch.Tensor, mask: torch.Tensor | None = None
    ) -> SindyDynamics:
        """Set Ψ = ``coef`` (p, nz) and M = ``mask`` (p, nz) bool, default ``coef != 0``;
        returns ``self``. Unlike :meth:`threshold` this replaces the mask (it may turn terms
        back on); Ψ is set to 0 where the mask is off."""
        coef = torch.as_tensor(coef)
        mask = coef != 0 if mask is None else torch.as_tensor(mask)
        if coef.shape != self.psi.shape or mask.shape != self.mask.shape:
            raise ValueError(
                f"set_coefficients expects coef and mask of shape {tuple(self.psi.shape)} "
                f"(terms, nz), got {tuple(coef.shape)} and {tuple(mask.shape)}"
            )
        self.mask.copy_(mask.to(self.mask.device, torch.bool))
        self.psi.copy_(coef.to(self.psi.device, self.psi.dtype))
        self.psi.masked_fill_(~self.mask, 0.0)
        self._free_turned_column()
        return self

    def fit_state_data(
        self,
        Z: torch.Tensor,
        U: torch.Tensor,
        Znext: torch.Tensor,
        optimizer: STLSQ | None = None,
        restrict_to_mask: bool = False,
    ) -> SindyDynamics:
        """Fit Ψ and M to transitions by sparse regression; returns ``self``.

        ``Znext − Z = Θ(Z, U) (M ⊙ Ψ)`` is linear in Ψ: ``optimizer`` (default ``STLSQ()``,
        fitted in place, so pass one to read its ``n_iter_`` etc.) solves it in closed form.
        Z (N, nz), U (N, nu), Znext (N, nz). With ``restrict_to_mask`` only terms the current
        mask allows may be active (``STLSQ(threshold=0)`` then refits them by least squares).
        The regression fits the update before the circle's projection (which :meth:`step`
        then applies); with ``turn``, z_a's target is the angle from (z_a, z_b) to the next
        pair and z_b's none.
        """
        if self.turn:
            a, b = self.circle
            omega = torch.atan2(Z[:, a] * Znext[:, b] - Z[:, b] * Znext[:, a],
                                Z[:, a] * Znext[:, a] + Z[:, b] * Znext[:, b])
            Znext = Znext.clone()
            Znext[:, a], Znext[:, b] = Z[:, a] + omega, Z[:, b]
        opt = sindy_fit.fit_state_data(
            self.library, Z, U, Znext, optimizer, mask=self.mask if restrict_to_mask else None
        )
        return self.set_coefficients(opt.coef_, opt.mask_)

    def l1_penalty(self) -> torch.Tensor:
        """‖M ⊙ Ψ‖₁, a scalar tensor with gradient."""
        return self.coefficients().abs().sum()

    def n_active(self) -> int:
        """Number of active (unmasked) coefficients."""
        return int(self.mask.sum())

    def sparsity(self) -> float:
        """Fraction of coefficients pruned by the mask (the paper's "sparsity")."""
        return 1.0 - self.n_active() / self.n_candidates()

    def n_candidates(self) -> int:
        """Coefficients that may be active: every term for every state (with ``turn``,
        none for z_b, whose update is unused)."""
        p, nz = self.mask.shape
        return p * (nz - 1 if self.turn else nz)

    def active_terms(self) -> torch.Tensor:
        """Indices of library terms active in at least one state: (p_active,) long."""
        return self.mask.any(dim=1).nonzero().flatten()

    @torch.no_grad()
    def coefficient_rows(self) -> list[Row]:
        """Active coefficients as ``(state, term, value)`` rows, by state then library order."""
        coef = self.coefficients().detach().cpu()
        names = self.names
        rows = []
        for j in range(self.nz):
            for i in self.mask[:, j].nonzero().flatten().tolist():
                rows.append((f"z{j}", names[i], float(coef[i, j])))
        return rows

    def equations(self, precision: int = 3) -> list[str]:
        """One readable update rule per latent state, active terms only.

        Right-hand variables are at time t, coefficients rounded to ``precision`` significant
        digits, e.g. ``z0[t+1] = z0 + 0.512 u0 - 0.0312 z1 z2``. The leading ``z0`` is the
        residual (identity) part of the model and is always there.
        """
        rows = self.coefficient_rows()
        lines = format_equations(rows, self.nz, precision, residual=True)
        if not self.turn:
            return lines
        a, b = self.circle
        turn = [("z0", term, value) for state, term, value in rows if state == f"z{a}"]
        omega = format_equations(turn, 1, precision, residual=False)[0]
        lines[a] = omega.replace("z0[t+1] =", f"ω = turn of (z{a}, z{b}) =", 1)
        return [line for j, line in enumerate(lines) if j != b]

    def summary(self) -> list[str]:
        p, nz = self.mask.shape
        return [f"SINDy latent dynamics, library {self.library.spec} ({p} candidate terms "
                f"x {nz} states), z[t+1] = z + Θ(z, u) (M ⊙ Ψ)",
                f"active coefficients: {self.n_active()} of {self.n_candidates()} (sparsity "
                f"{100 * self.sparsity():.1f}%); terms used by some state: "
                f"{int(self.mask.any(dim=1).sum())} of {p}", *self._circle_note()]

    def export_info(self) -> dict[str, Any]:
        return {"library": self.library.spec.to_dict(), "n_active": self.n_active(),
                "n_coefficients": self.n_candidates(), "sparsity": self.sparsity(),
                "terms": self.names, **super().export_info()}

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
        self._free_turned_column()  # a mask saved by a model that did not turn

    @torch.no_grad()
    def _free_turned_column(self) -> None:
        """With ``turn``, z_b's own update is unused: its column has no candidates."""
        if self.turn:
            self.mask[:, self.circle[1]] = False
            self.psi[:, self.circle[1]] = 0.0

    def stats(self) -> dict[str, float | None]:
        return {**super().stats(), "sindy/active": self.n_active(),
                "sindy/coefficients": self.n_candidates(),
                "sindy/terms_used": int(self.mask.any(dim=1).sum()),
                "sindy/sparsity": self.sparsity()}

    def compile_sparse(self) -> SparseSindyDynamics:
        """A frozen copy of the current model that evaluates only the active library terms.

        Its ``step`` equals this model's ``step`` to float precision (the circle's projection
        included). It holds a snapshot of the coefficients (no gradient): compile again after
        further training or pruning.
        """
        return SparseSindyDynamics(self)

    def extra_repr(self) -> str:
        return f"nz={self.nz}, nu={self.nu}, active={self.n_active()}/{self.n_candidates()}"


class SparseSindyDynamics(LatentDynamics):
    """Fast, frozen SINDy step over the terms active in any state (for control).

    ``z_{t+1} = z_t + Θ_S(z_t, u_t) C_S`` with S the active terms, Θ_S (K, |S|) and
    C_S = (M ⊙ Ψ)[S] (|S|, nz) stored as a buffer; the model's circle, if any, is kept.
    """

    kind = "sindy-sparse"
    coef: torch.Tensor  # (|S|, nz)

    def __init__(self, model: SindyDynamics) -> None:
        super().__init__(model.nz, model.nu, model.circle, model.turn)
        terms = model.active_terms()
        self.library: LibrarySubset = model.library.subset(terms)
        self.register_buffer("coef", model.coefficients().detach()[terms].clone())

    @property
    def names(self) -> list[str]:
        return self.library.names

    def _step(self, z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return z + self.library(z, u) @ self.coef  # (K, nz)


class LinearDynamics(LatentDynamics):
    """Globally linear latent model ``z_{t+1} = A z_t + B u_t + c`` (the E2C-style baseline).

    A (nz, nz) starts near the identity, B (nz, nu) small, c (nz,) zero; ``circle``: see
    :class:`LatentDynamics`.
    """

    kind = "linear"

    def __init__(self, nz: int, nu: int, init_scale: float = 1e-3, seed: int | None = None,
                 circle: Sequence[int] | None = None, turn: bool = False) -> None:
        super().__init__(nz, nu, circle, turn)
        gen = None if seed is None else torch.Generator().manual_seed(seed)
        self.A = nn.Parameter(torch.eye(nz) + init_scale * torch.randn(nz, nz, generator=gen))
        self.B = nn.Parameter(init_scale * torch.randn(nz, nu, generator=gen))
        self.c = nn.Parameter(torch.zeros(nz))
        self._init = {"init_scale": init_scale, "seed": seed}

    def hparams(self) -> dict[str, Any]:
        return {**super().hparams(), **self._init}

    def _step(self, z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return z @ self.A.T + u @ self.B.T + self.c  # (K, nz)

    @torch.no_grad()
    def coefficient_rows(self) -> list[Row]:
        """Every entry of A, B and c, by state: (z_j, z_k | u_k | 1, value)."""
        A, B, c = (p.detach().cpu() for p in (self.A, self.B, self.c))
        rows: list[Row] = []
        for j in range(self.nz):
            rows += [(f"z{j}", f"z{k}", float(A[j, k])) for k in range(self.nz)]
            rows += [(f"z{j}", f"u{k}", float(B[j, k])) for k in range(self.nu)]
            rows.append((f"z{j}", "1", float(c[j])))
        return rows

    def equations(self, precision: int = 3) -> list[str]:
        return format_equations(self.coefficient_rows(), self.nz, precision, residual=False)

    def summary(self) -> list[str]:
        return [f"linear latent dynamics z[t+1] = A z + B u + c (A {self.nz}x{self.nz}, "
                f"B {self.nz}x{self.nu}, c {self.nz}), every coefficient active",
                *self._circle_note()]

    def export_info(self) -> dict[str, Any]:
        return {"n_coefficients": self.nz * (self.nz + self.nu + 1), **super().export_info()}

    def stats(self) -> dict[str, float | None]:
        n = self.nz * (self.nz + self.nu + 1)
        return {**super().stats(), "sindy/active": n, "sindy/coefficients": n}

    @torch.no_grad()
    def fit_least_squares(
        self, Z: torch.Tensor, U: torch.Tensor, Znext: torch.Tensor
    ) -> LinearDynamics:
        """Set A, B, c to the least-squares fit of Znext ≈ A Z + B U + c; returns self.

        Z (N, nz), U (N, nu), Znext (N, nz); solved in float64.
        """
        n = Z.shape[0]
        if U.shape != (n, self.nu) or Z.shape != (n, self.nz) or Znext.shape != Z.shape:
            raise ValueError(
                f"fit_least_squares expects Z, Znext (N, {self.nz}) and U (N, {self.nu}), got "
                f"{tuple(Z.shape)}, {tuple(Znext.shape)}, {tuple(U.shape)}"
            )
        X = torch.cat([Z, U, torch.ones(n, 1, dtype=Z.dtype, device=Z.device)], dim=1)
        W = torch.linalg.lstsq(X.double().cpu(), Znext.double().cpu()).solution  # (nz+nu+1, nz)
        W = W.to(self.A.dtype).to(self.A.device)
        self.A.copy_(W[: self.nz].T)
        self.B.copy_(W[self.nz : self.nz + self.nu].T)
        self.c.copy_(W[-1])
        return self

    @classmethod
    def from_least_squares(
        cls, Z: torch.Tensor, U: torch.Tensor, Znext: torch.Tensor
    ) -> LinearDynamics:
        """A new model fitted by least squares (see :meth:`fit_least_squares`)."""
        return cls(Z.shape[1], U.shape[1]).fit_least_squares(Z, U, Znext)


class MlpDynamics(LatentDynamics):
    """Neural latent model ``z_{t+1} = z_t + MLP([z_t, u_t])``.

    ``layers`` hidden layers of width ``hidden`` with SiLU; the output layer starts at a tenth
    of PyTorch's default scale so the untrained model is close to the identity. With
    ``harmonics`` = n > 0 the action ``u[angle]`` (an angle) also enters as cos(k u), sin(k u)
    for k = 1..n: a network of this size learns functions of an angle that turn n times per
    revolution (the pose features of a block with n-fold symmetry) only from such features.
    ``circle``: see :class:`LatentDynamics`.
    """

    kind = "mlp"

    def __init__(self, nz: int, nu: int, hidden: int = 128, layers: int = 2,
                 harmonics: int = 0, angle: int = 1, circle: Sequence[int] | None = None,
                 turn: bool = False) -> None:
        super().__init__(nz, nu, circle, turn)
        if layers < 1 or hidden < 1:
            raise ValueError(
                f"MlpDynamics needs layers >= 1 and hidden >= 1, got layers={layers}, "
                f"hidden={hidden}"
            )
        if harmonics < 0 or (harmonics and not 0 <= angle < nu):
            raise ValueError(f"MlpDynamics harmonics {harmonics} of action {angle}: need "
                             f"harmonics >= 0 and 0 <= angle < {nu}")
        self.register_buffer("_k", torch.arange(1, harmonics + 1, dtype=torch.float32),
                             persistent=False)
        self._angle = angle
        mods: list[nn.Module] = []
        width = nz + nu + 2 * harmonics
        for _ in range(layers):
            mods += [nn.Linear(width, hidden), nn.SiLU()]
            width = hidden
        out = nn.Linear(width, nz)
        with torch.no_grad():
            out.weight.mul_(0.1)
            out.bias.zero_()
        self.net = nn.Sequential(*mods, out)
        self._init = {"hidden": hidden, "layers": layers}
        if harmonics:
            self._init |= {"harmonics": harmonics, "angle": angle}

    def hparams(self) -> dict[str, Any]:
        return {**super().hparams(), **self._init}

    def _step(self, z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        parts = [z, u]
        if len(self._k):
            a = u[..., self._angle, None] * self._k.to(u.dtype)
            parts += [torch.cos(a), torch.sin(a)]
        return z + self.net(torch.cat(parts, dim=-1))  # (K, nz)

    def summary(self) -> list[str]:
        n = self._init.get("harmonics", 0)
        extra = f", u{self._init['angle']} as cos/sin of 1..{n} times it" if n else ""
        return [f"MLP latent dynamics z[t+1] = z + MLP([z, u]) ({self._init['layers']} hidden "
                f"layers of {self._init['hidden']}{extra}): a neural network has no readable "
                "equations", *self._circle_note()]


# ----------------------------------------------------------------------------- configs
def _check_scale(kind: str, init_scale: float) -> None:
    if not (math.isfinite(init_scale) and init_scale >= 0):
        raise UserError(f"{kind} init_scale {init_scale}: use a finite number >= 0")


@dataclass(frozen=True)
class SindyConfig:
    """SINDy: z[t+1] = z + Θ(z, u) (M ⊙ Ψ) over a candidate library of [z, u]."""

    kind: ClassVar[str] = "sindy"
    model_class: ClassVar[type[LatentDynamics]] = SindyDynamics
    order: int = 2
    """Polynomial order of the candidate library (1-4)."""
    include_sine: bool = True
    """Add sin(z_i) candidates."""
    include_cosine: bool = False
    """Add cos(z_i) candidates ("poly" library only)."""
    library: Literal["poly", "push", "face", "frame"] = "poly"
    """"poly": monomials of [z, u] up to the order (+ sin z); "push": that plus the push
    length times the sine and cosine of the push angle, alone and times each state (what a
    push does: Δx ≈ ℓ cos ψ), for actions u = [p, angle, length]; "face" (order 1, on the
    pose: state models or --pose-head coordinates; pushes given as world directions, the
    symmetric world): the push length times the push direction or the orientation features
    (z2, z3), times powers of the contact offset and the push angle relative to the pushed
    face (the library's face_library); "frame" (order 1, on the pose, world-direction
    pushes): the push in the pushed face's frame, the push length times the face normal's
    direction (cos n, sin n) or the orientation features, times the monomials of the contact
    offset and of the push's angle a from the face normal (the library's frame_library)."""
    angle_frequency: float = 4.0
    """"face" library: f of the orientation features (cos fθ, sin fθ), the block's visible
    symmetry: 4 for a square block (2π over the visible period). The relative push angle
    enters as sin(f u1), cos(f u1) times those features."""
    frame_degree: int = 3
    """"frame" library: highest degree of the monomials of the contact offset and the angle
    from the face normal."""
    frame_sense: int | None = None
    """"frame" library: the orientation features' sense against the world's, fθ =
    sense · atan2(z3, z2) + offset (-1 for features read in a mirrored image). None: the
    latent's own, which training states in the run's record: on the moments latent the
    data's camera's (envs.camera.moment_frame; a value given must match it), on a pose
    latent in world angles (the state, a coordinates pose head) 1. A model built from an
    unresolved config reads None as 1 and its offset as 0."""
    frame_offset: float | None = None
    """"frame" library: that offset (radians); None: the latent's own, as ``frame_sense``
    (the moments latent's camera's, else 0)."""
    init_scale: float = 1e-3
    """Standard deviation of the initial coefficients Ψ."""

    def __post_init__(self) -> None:
        if isinstance(self.order, bool) or self.order not in VALID_ORDERS:
            raise UserError(f"SINDy order {self.order} is not supported: use 1, 2, 3 or 4")
        if self.library not in ("poly", "push", "face", "frame"):
            raise UserError(f"--library {self.library!r}: use poly, push, face or frame")
        if self.library != "poly" and self.include_cosine:
            raise UserError("--include-cosine is for the poly library only")
        if self.library in ("face", "frame") and self.order != 1:
            raise UserError(f"--library {self.library} with --order {self.order}: the "
                            f"{self.library} library's push terms already hold the "
                            "higher-order products; use --order 1")
        if self.library == "frame" and (self.angle_frequency < 3
                                        or self.angle_frequency != round(self.angle_frequency)):
            raise UserError(f"--library frame with --angle-frequency {self.angle_frequency:g}: "
                            "its angle a is measured from the nearest face normal of a block "
                            "whose visible symmetry is its number of faces (a uniform square: "
                            "4); use an integer >= 3, or --library face / push")
        if isinstance(self.frame_degree, bool) or not 0 <= self.frame_degree <= 4:
            raise UserError(f"--frame-degree {self.frame_degree}: use 0 to 4")
        if self.frame_sense not in (None, 1, -1):
            raise UserError(f"--frame-sense {self.frame_sense}: use 1 or -1")
        if self.frame_offset is not None and not math.isfinite(self.frame_offset):
            raise UserError(f"--frame-offset {self.frame_offset}: use a finite angle (radians)")
        if not (math.isfinite(self.angle_frequency) and self.angle_frequency > 0):
            raise UserError(f"--angle-frequency {self.angle_frequency}: use a finite number "
                            "> 0 (4 for a square block)")
        _check_scale("SINDy", self.init_scale)

    def build(self, nz: int, nu: int, circle: Sequence[int] | None = None,
              turn: bool = False) -> SindyDynamics:
        """The model for latent size nz and action size nu; ``circle``: the latent
        coordinates kept on the unit circle, ``turn``: turned by z_a's update (see
        :class:`LatentDynamics`)."""
        if self.library in ("push", "face", "frame") and nu < 3:
            raise UserError(f"the {self.library} library needs actions [p, angle, length], "
                            f"got {nu}")
        if self.library in ("face", "frame") and nz < 4:
            raise UserError(f"the {self.library} library needs the pose (x, y, cos fθ, sin fθ) "
                            f"as the first four latent coordinates, got a latent of size {nz}: "
                            "use the state or moments encoder or --pose-head coordinates")
        if self.library == "frame":
            spec = frame_library(self.order, frequency=self.angle_frequency,
                                 degree=self.frame_degree,
                                 sense=1 if self.frame_sense is None else self.frame_sense,
                                 angle_offset=self.frame_offset or 0.0)
            if self.include_sine:
                spec = spec + Sine("z")
        elif self.library == "face":
            spec = face_library(self.order, frequency=self.angle_frequency)
            if self.include_sine:
                spec = spec + Sine("z")
        elif self.library == "push":
            spec = push_library(self.order, angle=1, length=2, include_sine=self.include_sine)
        else:
            return SindyDynamics(nz, nu, order=self.order, include_sine=self.include_sine,
                                 include_cosine=self.include_cosine, init_scale=self.init_scale,
                                 circle=circle, turn=turn)
        return SindyDynamics(nz, nu, init_scale=self.init_scale, library_spec=spec, circle=circle,
                             turn=turn)


@dataclass(frozen=True)
class LinearConfig:
    """Globally linear (the E2C baseline): z[t+1] = A z + B u + c."""

    kind: ClassVar[str] = "linear"
    model_class: ClassVar[type[LatentDynamics]] = LinearDynamics
    init_scale: float = 1e-3
    """Standard deviation of A − I and B at initialisation."""

    def __post_init__(self) -> None:
        _check_scale("linear", self.init_scale)

    def build(self, nz: int, nu: int, circle: Sequence[int] | None = None,
              turn: bool = False) -> LinearDynamics:
        return LinearDynamics(nz, nu, init_scale=self.init_scale, circle=circle, turn=turn)


@dataclass(frozen=True)
class MlpConfig:
    """Neural reference: z[t+1] = z + MLP([z, u])."""

    kind: ClassVar[str] = "mlp"
    model_class: ClassVar[type[LatentDynamics]] = MlpDynamics
    hidden: int = 128
    """Width of the hidden layers."""
    layers: int = 2
    """Number of hidden layers."""
    harmonics: int = 0
    """Also feed the push angle u1 as cos(k u1), sin(k u1), k = 1..harmonics (0: u as it is).
    The state reference rows use 4: a square block's pose features turn 4 times per
    revolution."""

    def __post_init__(self) -> None:
        if self.hidden < 1 or self.layers < 1:
            raise UserError(f"MLP hidden {self.hidden} and layers {self.layers}: use 1 or more")
        if not 0 <= self.harmonics <= 64:
            raise UserError(f"--harmonics {self.harmonics}: use 0 to 64")

    def build(self, nz: int, nu: int, circle: Sequence[int] | None = None,
              turn: bool = False) -> MlpDynamics:
        if self.harmonics and nu < 2:
            raise UserError(f"--harmonics needs a push angle u1, but actions have {nu} "
                            "components")
        return MlpDynamics(nz, nu, hidden=self.hidden, layers=self.layers,
                           harmonics=self.harmonics, angle=1, circle=circle, turn=turn)


#: The registry: every latent dynamics kind's config class (its ``kind`` names it).
DYNAMICS_CONFIGS: tuple[type, ...] = (SindyConfig, LinearConfig, MlpConfig)
DYNAMICS_KINDS: dict[str, type] = {c.kind: c for c in DYNAMICS_CONFIGS}

#: A tagged union of the registered configs; on the command line each is a subcommand
#: (``latent-sindy train sindy --order 3``, ``... train linear``).
DynamicsConfig = Union[tuple(  # noqa: UP007  (built from the registry at import time)
    Annotated[c, tyro.conf.subcommand(c.kind)] for c in DYNAMICS_CONFIGS)]


def make_dynamics(kind: str, nz: int, nu: int, **kwargs: Any) -> LatentDynamics:
    """Build a latent dynamics model by kind name (``"sindy"``, ``"linear"``, ``"mlp"``).

    Extra keyword arguments go to the model's constructor (e.g. ``order=3``, ``seed=0``).
    """
    try:
        cls = DYNAMICS_KINDS[kind].model_class
    except KeyError:
        raise ValueError(
            f"unknown dynamics kind {kind!r}; valid kinds: {', '.join(sorted(DYNAMICS_KINDS))}"
        ) from None
    return cls(nz, nu, **kwargs)
