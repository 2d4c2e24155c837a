"""The interface every latent dynamics model offers, and what the kinds share.

:class:`LatentDynamics` is a ``torch.nn.Module`` with ``step(z, u) -> z_next`` on batched
tensors and a shared ``rollout``, so MPPI, evaluation and figures never ask which model they
hold. A model built with ``circle=(a, b)`` (two latent coordinates that hold an angle's
(cos, sin) features) scales (z_a, z_b) back onto the unit circle after every step, so the
angle features cannot drift off it in long open-loop rollouts; training, prediction,
evaluation and control all step through it. A model also describes itself (``summary``,
``coefficient_rows``, ``equations``, ``stats``), so reports never ask either.
:class:`SparseDynamics` is the one answer to "is this a sparse model?": a model whose
coefficients sit under a mask that training prunes (SINDy).
Dimensions: K samples (batch), H horizon, nz latent size, nu action size, p library terms.

    >>> model = LinearConfig().build(nz=4, nu=2, circle=(2, 3))
    >>> model.rollout(torch.zeros(8, 4), torch.zeros(8, 10, 2)).shape  # (8, 11, 4)
    >>> isinstance(model, SparseDynamics)
    False
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, ClassVar

import torch
from torch import nn

from latent_sindy.errors import UserError
from latent_sindy.sindy.fit import checked_valid

if TYPE_CHECKING:
    from latent_sindy.sindy.optimizers import STLSQ

__all__ = ["LatentDynamics", "Row", "SparseDynamics", "check_init_scale", "format_equations",
           "project_circle", "turn_circle", "turned_running_sum", "turned_target"]

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


def turned_target(z: torch.Tensor, z_next: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """What a ``turn`` model's step is fitted to: ``z_next`` with z_a replaced by z_a + ω, ω
    the angle from z's pair ``index`` = (a, b) to z_next's, and z_b by z_b (the inverse of
    :func:`turn_circle` before the projection). Out of place."""
    a, b = index[0], index[1]
    omega = torch.atan2(z[..., a] * z_next[..., b] - z[..., b] * z_next[..., a],
                        z[..., a] * z_next[..., a] + z[..., b] * z_next[..., b])
    pair = torch.stack([z[..., a] + omega, z[..., b]], -1)
    return z_next.index_copy(-1, index, pair)


def turned_running_sum(X: torch.Tensor, index: torch.Tensor, valid: torch.Tensor | None = None
                       ) -> torch.Tensor:
    """Trajectories X (B, T+1, nz) as the running sum (from 0) of each step's
    :func:`turned_target` change: a window's change of it is what a ``turn`` model's steps
    over the window add up to. ``valid`` (B, T+1) bool: steps to or from a state read badly
    add 0 (no window that is fitted holds them)."""
    step = turned_target(X[:, :-1], X[:, 1:], index) - X[:, :-1]
    if valid is not None:
        valid = checked_valid(valid, X)
        both = (valid[:, :-1] & valid[:, 1:])[..., None].to(X.device)
        step = torch.where(both, step, torch.zeros((), dtype=X.dtype, device=X.device))
    return torch.cat([torch.zeros_like(X[:, :1]), step.cumsum(1)], 1)


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
    #: ``isinstance(self, SparseDynamics)`` as a class variable, for code that does not
    #: import the models (True exactly for its subclasses).
    sparse: ClassVar[bool] = False
    #: Whether the model is a continuous-time one (its equations give the latent's time
    #: derivative, trained against the encoder's along the data; ``step`` integrates them).
    continuous: ClassVar[bool] = False
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


class SparseDynamics(LatentDynamics):
    """A latent model whose coefficients sit under a mask that pruning only turns off: the
    one answer to "is this a sparse model?", ``isinstance(model, SparseDynamics)``.

    Training asks it for the L1 penalty, the pruning step and a start by sparse regression;
    evaluation and reports for the counts and the coefficient map. A subclass holds the
    trainable coefficients Ψ as the parameter ``psi`` (p, nz) and the mask M as the persistent
    boolean buffer ``mask`` (p, nz), and implements the methods that raise here; the penalty,
    the counts and the active terms follow from them.
    """

    sparse: ClassVar[bool] = True
    psi: nn.Parameter  # (p, nz)
    mask: torch.Tensor  # (p, nz) bool

    def coefficients(self) -> torch.Tensor:
        """The effective coefficients M ⊙ Ψ: (p, nz)."""
        raise NotImplementedError

    def prune(self, tau: float, scale: torch.Tensor | None = None) -> int:
        """Prune active coefficients with ``|Ψ| < tau`` (``|Ψ| · scale < tau`` with weights
        ``scale`` (p, nz)); return how many were newly pruned."""
        raise NotImplementedError

    def set_coefficients(self, coef: torch.Tensor, mask: torch.Tensor | None = None
                         ) -> SparseDynamics:
        """Set Ψ (p, nz) and M (p, nz), default ``coef != 0``; returns ``self``."""
        raise NotImplementedError

    def fit_state_data(self, Z: torch.Tensor, U: torch.Tensor, Znext: torch.Tensor,
                       optimizer: STLSQ | None = None, restrict_to_mask: bool = False
                       ) -> SparseDynamics:
        """Fit Ψ and M to transitions Z (N, nz), U (N, nu), Znext (N, nz) by sparse
        regression; returns ``self``."""
        raise NotImplementedError

    def n_candidates(self) -> int:
        """Coefficients that may be active."""
        raise NotImplementedError

    def l1_penalty(self) -> torch.Tensor:
        """‖M ⊙ Ψ‖₁, a scalar tensor with gradient."""
        return self.coefficients().abs().sum()

    def n_active(self) -> int:
        """Number of active (unmasked) coefficients."""
        return int(self.mask.sum())

    def sparsity(self) -> float:
        """Fraction of coefficients pruned by the mask (the paper's "sparsity")."""
        return 1.0 - self.n_active() / self.n_candidates()

    def active_terms(self) -> torch.Tensor:
        """Indices of library terms active in at least one state: (p_active,) long."""
        return self.mask.any(dim=1).nonzero().flatten()

    def stats(self) -> dict[str, float | None]:
        return {**super().stats(), "sindy/active": self.n_active(),
                "sindy/coefficients": self.n_candidates(),
                "sindy/terms_used": int(self.mask.any(dim=1).sum()),
                "sindy/sparsity": self.sparsity()}


def format_equations(rows: list[Row], nz: int, precision: int, residual: bool,
                     left: str = "{state}[t+1]") -> list[str]:
    """``z0[t+1] = [z0 +] 0.512 u0 - 0.0312 z1 z2 ...`` per state from coefficient rows.

    ``residual`` writes the identity part of a residual model (``z_{t+1} = z_t + ...``);
    coefficients are rounded to ``precision`` significant digits; ``left`` is the left-hand
    side, ``{state}`` standing for the state's name (``"{state}''"`` writes ``z0'' = ...``).
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
        lines.append(f"{left.format(state=state)} = {rhs}")
    return lines


def check_init_scale(kind: str, init_scale: float) -> None:
    if not (math.isfinite(init_scale) and init_scale >= 0):
        raise UserError(f"{kind} init_scale {init_scale}: use a finite number >= 0")

