"""Continuous-time SINDy latent dynamics, first or second order: the SINDy autoencoder's
(Champion et al., PNAS 2019) ż = Θ(z, u) (M ⊙ Ψ), or z̈ = Θ(z, ż, u) (M ⊙ Ψ), and its config.

The model gives the latent's derivative (:meth:`ContinuousSindyDynamics.derivative`); the
latent model's loss compares it with the encoder's own ż or z̈ along the data
(:mod:`latent_sindy.models.derivatives`). Behind the shared ``step(s, u)`` it integrates one
time step ``dt`` by the classical Runge-Kutta scheme, on the phase state s = z (first order)
or s = (z, ż) (second order, 2 nz coordinates). The library is over the phase state and the
actions: for a second-order model its variables z{nz}..z{2nz-1} are ż, written z0', z1', ...
in every name, so the equations read ``z0'' = -0.98 sin(z0)``.

With a ``time_unit`` T other than 1 the coefficients Ψ are those of the model in its own
time t/T (where a video at another frequency looks like the one a recipe's weights were set
on: :func:`time_unit_for`), while everything the model shows and does is in the data's time:
``derivative`` and ``step`` take and give real-time rates, ``coefficients()`` and the
equations are real-time (a term's coefficient times T^(its time order − k); a sine of a
velocity keeps its model-time argument, written ``sin(0.841 z0')``). The L1 penalty and the
pruning act on Ψ, and the latent model's loss weighs its derivative terms by T^(2k), so a fit
in real time is the fit in model time.

    >>> model = ContinuousSindyConfig(derivative_order=2, order=3).build(nz=1, nu=0)
    >>> model.names[:4]
    ['1', 'z0', "z0'", 'z0^2']
    >>> model.derivative(torch.zeros(8, 2), torch.zeros(8, 0)).shape  # z̈ (8, 1)
    torch.Size([8, 1])
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import torch
from torch import nn

from latent_sindy.errors import UserError
from latent_sindy.models.dynamics.base import (
    LatentDynamics,
    SparseDynamics,
    check_init_scale,
    format_equations,
)
from latent_sindy.models.dynamics.sindy import SindyDynamics
from latent_sindy.sindy import VALID_ORDERS, Polynomial, SindyLibrary, Sine

__all__ = ["DERIVATIVE_ORDERS", "TIME_UNIT_REFERENCE", "ContinuousSindyConfig",
           "ContinuousSindyDynamics", "time_unit_for"]

#: The derivative orders a continuous-time model may have.
DERIVATIVE_ORDERS = (1, 2)

#: The motion time (:func:`~latent_sindy.models.derivatives.motion_time`) that
#: :func:`time_unit_for` maps to 1: the pendulum video's at ω² = 1 (1.013 s on its frames,
#: every 5th of 500, 64 training trajectories), where the continuous-time recipe's weights were
#: set; its videos at ω² = 1.44 and 0.5 keep the units they had (0.841, 1.414).
TIME_UNIT_REFERENCE = 1.013
#: Time units are whole powers of this, so that data near the reference (a subset of the
#: benchmark's trajectories) keep the unit 1 exactly.
TIME_UNIT_STEP = 2 ** (1 / 4)


def time_unit_for(tau: float) -> float:
    """The time unit of data whose characteristic time is ``tau`` (in the data's time:
    :func:`~latent_sindy.models.derivatives.characteristic_time`): ``tau`` over
    :data:`TIME_UNIT_REFERENCE`, rounded to a whole power of :data:`TIME_UNIT_STEP`, so a
    video of the pendulum at ω is the ω = 1 video in the model's time, its ω within 9 %."""
    if not (math.isfinite(tau) and tau > 0):
        raise UserError(f"characteristic time {tau}: the data do not move (or their "
                        "derivatives are not finite); give time_unit a number")
    steps = round(math.log(tau / TIME_UNIT_REFERENCE) / math.log(TIME_UNIT_STEP))
    return TIME_UNIT_STEP ** steps if steps else 1.0


def check_derivative_order(order: Any) -> int:
    if isinstance(order, bool) or order not in DERIVATIVE_ORDERS:
        raise UserError(f"derivative_order {order!r}: use 1 (z' = Θ(z) Ξ) or 2 "
                        "(z'' = Θ(z, z') Ξ)")
    return int(order)


class ContinuousSindyDynamics(SparseDynamics):
    """``z^(k) = Θ(z, .., z^(k-1), u) (M ⊙ Ψ)`` for k = ``derivative_order``; Ψ (p, nz) a
    parameter, M (p, nz) a boolean buffer that pruning only turns off, as for the
    discrete-time :class:`~latent_sindy.models.dynamics.sindy.SindyDynamics`.

    Args:
        nz, nu: latent and action sizes.
        derivative_order: 1 or 2.
        order: polynomial order of the library over the phase state and actions (1-4).
        include_sine: add sin of every phase variable (z and, at second order, ż).
        include_constant: the library's constant term 1 (without it the equations cannot
            hold an offset, so the encoder's free offset of z goes).
        init_scale: the initial coefficients: normal with this standard deviation
            (``init`` "normal"), or all equal to it (``init`` "constant"; the SINDy
            autoencoder's: 1).
        seed: seed of a normal start; None draws from the global torch generator.
        dt: the time step of :meth:`step` (time units of the data's derivatives); the
            config passes the data's.
        circle: see :class:`LatentDynamics` (the circle's pair of z is projected after a step).
        time_unit: the model's own time unit T in the data's (see the module docstring).
    """

    kind = "continuous"
    continuous: ClassVar[bool] = True
    mask: torch.Tensor  # (p, nz) bool

    def __init__(self, nz: int, nu: int, derivative_order: int = 1, order: int = 3,
                 include_sine: bool = True, include_constant: bool = True,
                 init_scale: float = 1e-3,
                 init: Literal["normal", "constant"] = "normal", seed: int | None = None,
                 dt: float = 0.1, circle: Sequence[int] | None = None,
                 turn: bool = False, time_unit: float = 1.0) -> None:
        super().__init__(nz, nu, circle)
        if turn:
            raise ValueError("turn is for discrete-time models: a continuous-time model's "
                             "equation for z_a is its derivative")
        self.derivative_order = check_derivative_order(derivative_order)
        if not (math.isfinite(dt) and dt > 0):
            raise UserError(f"dt {dt}: the time step must be a positive number")
        if init not in ("normal", "constant"):
            raise UserError(f"init {init!r}: use normal or constant")
        if not (math.isfinite(time_unit) and time_unit > 0):
            raise UserError(f"time_unit {time_unit}: use a positive number (1: the data's)")
        self.dt, self.time_unit = float(dt), float(time_unit)
        spec = Polynomial(("z", "u"), order, bias=include_constant)
        if include_sine:
            spec = spec + Sine("z")
        self.library = SindyLibrary(spec, nz * derivative_order, nu)
        p = self.library.n_terms
        if init == "constant":
            psi = torch.full((p, nz), float(init_scale))
        else:
            gen = None if seed is None else torch.Generator().manual_seed(seed)
            psi = torch.randn(p, nz, generator=gen) * init_scale
        self.psi = nn.Parameter(psi)  # (p, nz)
        self.register_buffer("mask", torch.ones(p, nz, dtype=torch.bool))  # (p, nz)
        self._init = {"derivative_order": self.derivative_order, "order": order,
                      "include_sine": include_sine, "include_constant": include_constant,
                      "init_scale": init_scale, "init": init,
                      "seed": seed, "dt": self.dt, "time_unit": self.time_unit}
        rename = {f"z{nz * k + j}": f"z{j}" + "'" * k
                  for k in range(derivative_order) for j in range(nz)}
        self._names = [re.sub(r"\bz(\d+)\b", lambda m: rename[m[0]], name)
                       for name in self.library.names]
        # model time t/T: a phase variable z^(j) is T^j times its real-time value, and a
        # term's real-time coefficient is T^(its monomial time order - k) times its Ψ
        n = nz * derivative_order
        self.register_buffer("_phase_scale", torch.tensor(
            [self.time_unit ** (i // nz) for i in range(n)]), persistent=False)  # (k nz,)
        table = self.library.table  # (p, width) feature indices, [z, ż] first
        orders = torch.where(table < n, table // nz, 0).sum(1)  # (p,)
        self.register_buffer("_term_scale", torch.tensor(
            [self.time_unit ** (int(o) - derivative_order) for o in orders]
        )[:, None], persistent=False)  # (p, 1)
        if self.time_unit != 1.0:
            self._names = [re.sub(r"\b(sin|cos)\((z\d+)('+)\)", lambda m: (
                f"{m[1]}({self.time_unit ** len(m[3]):.4g} {m[2]}{m[3]})"), name)
                for name in self._names]

    # The mask, the pruning and the coefficient rows are the discrete model's, read from
    # the same Ψ, M and names: one implementation for both.
    prune = SindyDynamics.prune
    coefficient_rows = SindyDynamics.coefficient_rows
    n_candidates = SindyDynamics.n_candidates

    def coefficients(self) -> torch.Tensor:
        """The effective coefficients in the data's time: M ⊙ Ψ, times T^(time order − k)
        per term where the time unit T is not 1; (p, nz)."""
        own = self.psi * self.mask
        return own if self.time_unit == 1.0 else own * self._term_scale

    def set_coefficients(self, coef: torch.Tensor, mask: torch.Tensor | None = None
                         ) -> ContinuousSindyDynamics:
        """Set the real-time coefficients ``coef`` (p, nz) (Ψ is them in the model's time)
        and M = ``mask`` (default ``coef != 0``); returns ``self``."""
        coef = torch.as_tensor(coef)
        if self.time_unit != 1.0:
            coef = coef.to(self.psi.dtype) / self._term_scale.to(coef.device, self.psi.dtype)
        return SindyDynamics.set_coefficients(self, coef, mask)

    def l1_penalty(self) -> torch.Tensor:
        """‖M ⊙ Ψ‖₁ in the model's time, a scalar tensor with gradient."""
        return (self.psi * self.mask).abs().sum()

    def _free_turned_column(self) -> None:  # (set_coefficients' hook: never turned here)
        pass

    @property
    def names(self) -> list[str]:
        """Library term names, one per row of Ψ (ż written z0', z1', ...)."""
        return self._names

    def hparams(self) -> dict[str, Any]:
        return {**super().hparams(), **self._init}

    def derivative(self, phase: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """The model's z^(k): phase (K, k nz) = (z[, ż]), u (K, nu) -> (K, nz), in the
        data's time."""
        if self.time_unit == 1.0:
            return self.library(phase, u) @ self.coefficients()
        own = self.library(phase * self._phase_scale, u) @ (self.psi * self.mask)
        return own * self.time_unit ** -self.derivative_order

    def field(self, phase: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """d/dt of the phase state: (K, k nz) -> (K, k nz)."""
        top = self.derivative(phase, u)
        if self.derivative_order == 1:
            return top
        return torch.cat([phase[..., self.nz:], top], dim=-1)

    def _step(self, z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        size = self.nz * self.derivative_order
        if z.shape[-1] != size:
            raise UserError(f"a continuous-time model of order {self.derivative_order} steps "
                            f"its phase state of {size} coordinates (z{', ż' * (size > self.nz)}"
                            f"), got {z.shape[-1]}")
        h = self.dt
        f = self.field
        k1 = f(z, u)
        k2 = f(z + 0.5 * h * k1, u)
        k3 = f(z + 0.5 * h * k2, u)
        k4 = f(z + h * k3, u)
        return z + (h / 6) * (k1 + 2 * k2 + 2 * k3 + k4)

    def fit_state_data(self, Z, U, Znext, optimizer=None, restrict_to_mask=False):
        raise UserError("a continuous-time model is fitted to derivatives, not to transitions: "
                        "train it with the latent model's loss")

    # ---------------------------------------------------------------- self-description
    def _left(self) -> str:
        return "{state}" + "'" * self.derivative_order

    def equations(self, precision: int = 3) -> list[str]:
        """One equation per latent state, active terms only: ``z0'' = -0.98 sin(z0)``."""
        return format_equations(self.coefficient_rows(), self.nz, precision, residual=False,
                                left=self._left())

    def summary(self) -> list[str]:
        p, nz = self.mask.shape
        lhs = "z" + "'" * self.derivative_order
        args = "z, z'" if self.derivative_order == 2 else "z"
        unit = (f"; coefficients fitted in time units of {self.time_unit:.4g}"
                if self.time_unit != 1.0 else "")
        return [f"continuous-time SINDy latent dynamics, library {self.library.spec} over "
                f"({args}{', u' if self.nu else ''}) ({p} candidate terms x {nz} states), "
                f"{lhs} = Θ({args}{', u' if self.nu else ''}) (M ⊙ Ψ){unit}",
                f"active coefficients: {self.n_active()} of {self.n_candidates()} (sparsity "
                f"{100 * self.sparsity():.1f}%); terms used by some state: "
                f"{int(self.mask.any(dim=1).sum())} of {p}", *self._circle_note()]

    def export_info(self) -> dict[str, Any]:
        return {"library": self.library.spec.to_dict(), "n_active": self.n_active(),
                "n_coefficients": self.n_candidates(), "sparsity": self.sparsity(),
                "terms": self.names, "derivative_order": self.derivative_order,
                "dt": self.dt, "time_unit": self.time_unit, **super().export_info()}

    def extra_repr(self) -> str:
        return (f"nz={self.nz}, nu={self.nu}, derivative_order={self.derivative_order}, "
                f"active={self.n_active()}/{self.n_candidates()}")


@dataclass(frozen=True)
class ContinuousSindyConfig:
    """Continuous-time SINDy (the SINDy autoencoder's): z' = Θ(z, u) Ξ or z'' = Θ(z, z', u) Ξ,
    trained on the time derivatives of the data (given with it, or estimated from the frames:
    --derivatives)."""

    kind: ClassVar[str] = "continuous"
    model_class: ClassVar[type[LatentDynamics]] = ContinuousSindyDynamics
    derivative_order: int = 1
    """1: z' = Θ(z, u) Ξ; 2: z'' = Θ(z, z', u) Ξ (the SINDy autoencoder's pendulum)."""
    order: int = 3
    """Polynomial order of the library over (z[, z'], u) (1-4; the pendulum's: 3)."""
    include_sine: bool = True
    """Add sin of every variable of the phase state (z and z')."""
    include_constant: bool = True
    """The library's constant term 1 (the SINDy autoencoder's had it). Without it the
    equations hold no offset, which pins the encoder's otherwise free offset of z."""
    init: Literal["normal", "constant"] = "constant"
    """The coefficients' start: "constant" (all equal to --init-scale; the SINDy
    autoencoder's, at 1, so that every term starts active and the L1 term and the pruning
    remove what is not needed) or "normal" (standard deviation --init-scale, seeded)."""
    init_scale: float = 1.0
    """The standard deviation or the value of the initial coefficients (see --init)."""
    dt: float | None = None
    """Time step of the model's step (RK4) and of the estimated derivatives' units; None: the
    data's dt (1 where the data has none)."""
    time_unit: float | None = 1.0
    """The unit of the model's own time, in the data's, in which its coefficients are fitted
    (the equations are shown in the data's time): 1, the data's; None: chosen from the data
    (:func:`time_unit_for` of their characteristic time), so that a video of a faster or
    slower system trains as the one the recipe's loss weights were set on."""

    def __post_init__(self) -> None:
        check_derivative_order(self.derivative_order)
        if isinstance(self.order, bool) or self.order not in VALID_ORDERS:
            raise UserError(f"SINDy order {self.order} is not supported: use 1, 2, 3 or 4")
        if self.init not in ("normal", "constant"):
            raise UserError(f"--init {self.init!r}: use normal or constant")
        check_init_scale("continuous SINDy", self.init_scale)
        if self.dt is not None and not (math.isfinite(self.dt) and self.dt > 0):
            raise UserError(f"--dt {self.dt}: use a positive time step, or leave it unset to "
                            "take the data's")
        if self.time_unit is not None and (isinstance(self.time_unit, bool) or not (
                math.isfinite(self.time_unit) and self.time_unit > 0)):
            raise UserError(f"time_unit {self.time_unit}: use a positive number (1: the "
                            "data's time), or None to choose it from the data")

    def build(self, nz: int, nu: int, circle: Sequence[int] | None = None,
              turn: bool = False) -> ContinuousSindyDynamics:
        """The model for latent size nz and action size nu (``turn`` is refused)."""
        if turn:
            raise UserError("--turn is for discrete-time dynamics: drop it")
        return ContinuousSindyDynamics(nz, nu, self.derivative_order, self.order,
                                       self.include_sine, self.include_constant,
                                       self.init_scale, self.init,
                                       dt=1.0 if self.dt is None else self.dt, circle=circle,
                                       time_unit=self.time_unit or 1.0)
