"""Model predictive path integral control (MPPI) on batched latent dynamics.

Every command samples K perturbations of the nominal action sequence, rolls all K candidates
out through the model in one batched loop over the horizon H, weights them by their cost and
moves the nominal sequence towards the good ones (Williams et al., the paper's §II.D):

    cost_k = Σ_{t=1..H} c(z_t^k) + w_T c(z_H^k) + λ Σ_{t=0..H-1} u_tᵀ Σ⁻¹ ε_t^k
    (a cost of states and actions, c(z_t, u_t) for t = 0..H-1, where it ``takes_actions``)
    ω_k ∝ exp(-(cost_k - min_j cost_j) / λ),   u_t += Σ_k ω_k ε_t^k

Dimensions: K samples, H horizon, nz latent size, nu action size.

    >>> from latent_sindy.control import MPPI, MPPIConfig, latent_step
    >>> from latent_sindy.models import SindyConfig
    >>> model = SindyConfig(order=2).build(nz=16, nu=3)
    >>> cfg = MPPIConfig(samples=100, horizon=10, sigma=0.1, lambda_=0.01)
    >>> mppi = MPPI(latent_step(model), torch.zeros(16), cfg,  # goal vector: quadratic cost
    ...             low=(-1, -1.57, 0), high=(1, 1.57, 1), seed=0)
    >>> action, info = mppi.command(torch.ones(16))  # (3,), MPPIInfo(discarded=0, ...)
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Annotated, Literal

import torch
import tyro
from torch import Tensor

from latent_sindy.control.costs import LatentCost, StateCost
from latent_sindy.control.sindy_step import SindyKernelStep
from latent_sindy.errors import UserError
from latent_sindy.models.dynamics import CompiledSindy, LatentDynamics, SindyDynamics

__all__ = ["MPPI", "DynamicsStep", "MPPIConfig", "MPPIInfo", "latent_step"]

#: ``step(z (K, nz), u (K, nu)) -> z_next (K, nz)``: any latent model's ``step`` fits.
DynamicsStep = Callable[[Tensor, Tensor], Tensor]

@dataclass(frozen=True)
class MPPIConfig:
    """The planner's settings, the one place their defaults live; validated on construction
    (raises :class:`UserError`). The action box is the environment's and comes separately.

    Scalars stand for the same value in every action (or latent) dimension. The defaults are
    the course's settings: K = 100, H = 10, Σ = 0.1·I, λ = 0.01, Q = I.
    """

    samples: int = 100
    """K: sampled action sequences per command (the course: 100)."""
    horizon: int = 10
    """H: planning horizon in model steps (the course: 10)."""
    sigma: float | tuple[float, ...] = 0.1
    """Diagonal of the noise covariance Σ (a variance, not a standard deviation): the paper's
    Σ = 0.1·I is 0.1. One value, or one per action dimension."""
    lambda_: Annotated[float, tyro.conf.arg(name="lambda")] = 0.01
    """Temperature λ: smaller trusts the best samples more (the course: 0.01)."""
    Q: tyro.conf.Suppress[float | tuple[float, ...]] = 1.0
    """State weight of the quadratic latent cost built when MPPI is given a goal vector
    (scalar or the diagonal); unused when it is given a cost callable."""
    terminal_weight: tyro.conf.Suppress[float] = 0.0
    """Extra weight w_T on the cost of the last predicted state (0: running cost only)."""
    u_init: tuple[float, ...] | None = None
    """Default action: fills the nominal sequence at reset (and after shifts with
    shift "init"). None: the centre of the action box (0 where a side is unbounded)."""
    shift: Literal["init", "repeat"] = "init"
    """Warm start: after each command the nominal sequence moves one step forward; its new
    last step is u_init ("init") or a repeat of the previous last step ("repeat")."""
    iterations: int = 1
    """Updates of the nominal sequence a command, each sampling K sequences around the last
    update's (1: MPPI's one update; PlaNet's CEM refines over several)."""

    def __post_init__(self) -> None:
        for name in ("samples", "horizon", "iterations"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise UserError(f"MPPI {name} {v!r}: must be a positive integer")
        sigma = _floats("sigma", self.sigma)
        if not all(0 < s < math.inf for s in sigma):
            raise UserError(f"MPPI sigma {self.sigma!r}: noise variances must be positive and "
                            "finite")
        if not (0 < self.lambda_ < math.inf):
            raise UserError(f"MPPI lambda {self.lambda_!r}: must be a finite positive number")
        if not all(0 <= v < math.inf for v in _floats("Q", self.Q)):
            raise UserError(f"MPPI Q {self.Q!r}: weights must be finite and >= 0")
        if not (0 <= self.terminal_weight < math.inf):
            raise UserError(
                f"MPPI terminal_weight {self.terminal_weight!r}: must be finite and >= 0")
        if self.u_init is not None and not all(math.isfinite(v) for v in self.u_init):
            raise UserError(f"MPPI u_init {self.u_init!r} must be finite")
        if self.shift not in ("init", "repeat"):
            raise UserError(f"MPPI shift {self.shift!r}: use 'init' or 'repeat'")

    def memory_bytes(self, nu: int, nz: int, itemsize: int = 4) -> int:
        """A lower bound on the memory one command holds: actions, noise and predicted
        states of every sample (a planner that cannot fit is refused up front)."""
        return self.samples * self.horizon * (3 * nu + 2 * nz) * itemsize


def _floats(name: str, value: float | Sequence[float]) -> tuple[float, ...]:
    vals = (value,) if isinstance(value, int | float) else tuple(value)
    if not vals or any(isinstance(v, bool) or not isinstance(v, int | float) for v in vals):
        raise UserError(f"MPPI {name} {value!r}: give a number or a list of numbers")
    if any(math.isnan(v) for v in vals):
        raise UserError(f"MPPI {name} {value!r} contains NaN")
    return tuple(float(v) for v in vals)


def _vector(name: str, value: float | Sequence[float], n: int) -> tuple[float, ...]:
    """``value`` as n floats (a scalar is repeated); NaN and wrong lengths are errors."""
    vals = _floats(name, value)
    if len(vals) == 1:
        vals = vals * n
    if len(vals) != n:
        raise UserError(f"MPPI {name} {value!r}: needs 1 or {n} values (nu={n})")
    return vals


@dataclass(frozen=True)
class MPPIInfo:
    """Diagnostics of one command."""

    discarded: int
    """Samples whose rollout or cost was NaN or infinite (given zero weight)."""
    discarded_total: int
    """Discarded samples over all commands since construction or :meth:`MPPI.reset`."""
    min_cost: float
    """Lowest total cost among the samples (inf when every sample was discarded)."""
    mean_cost: float
    """Mean total cost of the kept samples (NaN when every sample was discarded)."""
    seconds: float
    """Wall-clock time of the command."""


def latent_step(model: LatentDynamics) -> DynamicsStep:
    """The fastest equivalent ``step`` of a latent model for control.

    A SINDy model (:class:`SindyDynamics` or its ``compile_sparse()``) becomes a
    :class:`SindyKernelStep` over its active library terms only (a frozen snapshot: call again
    after further training or pruning); every other model's own ``step`` is returned. Either
    way a model with a ``circle`` (a pose latent) keeps its angle features on the unit circle
    after every step, as in training.
    """
    if isinstance(model, SindyDynamics | CompiledSindy):
        return SindyKernelStep(model)
    return model.step


class MPPI:
    """MPPI controller over a batched dynamics step and a batched state cost.

    Args:
        dynamics_step: ``step(z (K, nz), u (K, nu)) -> (K, nz)``, e.g. :func:`latent_step`.
        cost: a state cost ``cost(z (..., nz)) -> (...)``, called on all predicted states
            (H, K, nz) at once (e.g. :class:`LatentCost`,
            :class:`ImageCost`), or a goal vector z_goal (nz,), which stands for
            ``LatentCost(z_goal, config.Q)``; a cost with ``takes_actions`` (a
            :class:`RewardCost`) is called on the states z_0..z_{H-1} and the actions taken
            in them, ``cost(z (H, K, nz), u (H, K, nu)) -> (H, K)``.
        config: :class:`MPPIConfig`.

    Candidate actions are ``clamp(nominal + ε)`` into the action box, and the *clamped*
    perturbation ``ε_c = candidate - nominal`` is what enters the action cost and the update.
    Then the updated nominal ``u + Σ ω_k ε_c^k = Σ ω_k candidate_k`` is a convex combination of
    in-box actions, so it never leaves the box, and the cost does not charge the part of a
    perturbation the box cut off.

    Samples whose total cost is NaN or ±inf (a diverging model, an overflowing cost) get cost
    +inf and so zero weight; if no sample is finite every weight is 0 and the nominal sequence
    stays as it was. Attributes of the last command, for inspection: ``actions`` (K, H, nu),
    ``noise`` (K, H, nu) clamped perturbations, ``costs`` (K,), ``weights`` (K,).
    """

    def __init__(self, dynamics_step: DynamicsStep, cost: StateCost | Tensor,
                 config: MPPIConfig, low: Sequence[float], high: Sequence[float], *,
                 seed: int = 0, dtype: torch.dtype = torch.float32,
                 device: str = "cpu") -> None:
        cfg = config
        self.config = cfg
        self.step = dynamics_step
        self.nu = nu = len(low)
        if nu < 1 or len(high) != nu:
            raise UserError(f"MPPI action box low={tuple(low)}, high={tuple(high)}: give one "
                            "bound per action dimension on each side")
        lo, hi = _vector("low", low, nu), _vector("high", high, nu)
        if not all(a <= b and a < math.inf and b > -math.inf for a, b in zip(lo, hi, strict=True)):
            raise UserError(f"MPPI action box low={lo}, high={hi} must satisfy low <= high")
        if not dtype.is_floating_point:
            raise UserError(f"MPPI dtype {dtype}: use a floating dtype (float32)")
        if isinstance(seed, bool) or not isinstance(seed, int):
            raise UserError(f"MPPI seed {seed!r}: must be an integer")
        kw = {"dtype": dtype, "device": device}
        self.dtype = dtype
        self.device = device
        self.cost: StateCost = (
            LatentCost(torch.as_tensor(cost, **kw), cfg.Q) if isinstance(cost, Tensor) else cost
        )
        if not callable(self.cost):
            raise UserError(f"MPPI cost must be a callable or a goal tensor, got {type(cost)}")
        self._cost_of_actions = bool(getattr(self.cost, "takes_actions", False))
        self._big = big = torch.finfo(dtype).max
        sigma = torch.tensor(_vector("sigma", cfg.sigma, nu), **kw)  # (nu,)
        if not bool(torch.isfinite(sigma.sqrt() * 10).all()):
            raise UserError(f"MPPI sigma {cfg.sigma!r} overflows {dtype}")
        self.sigma = sigma  # (nu,) noise variances
        self.low = torch.tensor(lo, **kw)  # (nu,)
        self.high = torch.tensor(hi, **kw)  # (nu,)
        self._std = sigma.sqrt()  # (nu,)
        self._lam_sigma_inv = cfg.lambda_ / sigma  # (nu,) λ Σ⁻¹ (diagonal)
        self._inv_lambda = 1.0 / cfg.lambda_
        self._lo, self._hi = self.low.clamp(min=-big), self.high.clamp(max=big)
        if cfg.u_init is None:  # the box's centre; 0 on an unbounded side
            finite = torch.isfinite(self.low) & torch.isfinite(self.high)
            u0 = torch.where(finite, (self._lo + self._hi) / 2, torch.zeros(nu, **kw))
        else:
            u0 = torch.tensor(_vector("u_init", cfg.u_init, nu), **kw)
            if not bool(((u0 >= self.low) & (u0 <= self.high)).all()):
                raise UserError(f"MPPI u_init {cfg.u_init!r} lies outside the action box "
                                f"[{lo}, {hi}]")
        self.u_init = u0.clamp(self.low, self.high)  # (nu,)
        self._repeat_last = cfg.shift == "repeat"
        self._gen = torch.Generator(device=device)
        self.reset(seed)

    # ------------------------------------------------------------------ state
    def reset(self, seed: int | None = None) -> None:
        """Forget the warm start (nominal := u_init everywhere) and the discarded count.

        ``seed`` reseeds the noise generator; None continues its stream.
        """
        self._U = self.u_init.expand(self.config.horizon, -1).clone()  # (H, nu)
        self.discarded_total = 0
        if seed is not None:
            self._gen.manual_seed(seed)
        self.actions = self.noise = self.costs = self.weights = None

    @property
    def nominal(self) -> Tensor:
        """A copy of the nominal action sequence (H, nu) that the next command starts from."""
        return self._U.clone()

    # ------------------------------------------------------------------ control
    def command(self, z: Tensor, noise: Tensor | None = None) -> tuple[Tensor, MPPIInfo]:
        """Plan from latent state z (nz,) and return the first action (nu,) with diagnostics.

        ``noise`` (K, H, nu) replaces the sampled perturbations ε (for tests); the nominal
        sequence is then shifted one step (warm start for the next command). Planning runs in
        ``torch.inference_mode``; the returned action is an ordinary tensor (usable with
        autograd), while ``actions``, ``noise``, ``costs`` and ``weights`` are inference tensors.
        """
        t0 = time.perf_counter()
        with torch.inference_mode():
            action, discarded, min_cost, mean_cost = self.update(z, noise)
        self.discarded_total += discarded
        info = MPPIInfo(discarded, self.discarded_total, min_cost, mean_cost,
                        time.perf_counter() - t0)
        return action.clone(), info

    def update(self, z: Tensor, noise: Tensor | None = None) -> tuple[Tensor, int, float, float]:
        """One MPPI update in the caller's autograd mode (``command`` runs it in inference
        mode): returns the first action, the discarded count, the min and mean cost."""
        K, H, nu = self.config.samples, self.config.horizon, self.nu
        if noise is not None and noise.shape != (K, H, nu):
            raise ValueError(f"noise must have shape (K, H, nu)={(K, H, nu)}, "
                             f"got {tuple(noise.shape)}")
        U_new = self._U  # (H, nu)
        for _ in range(self.config.iterations):
            U = U_new
            if noise is None:
                eps = torch.randn(K, H, nu, generator=self._gen, dtype=self.dtype,
                                  device=self.device)
                eps.mul_(self._std)  # (K, H, nu)
            else:
                eps = noise.to(U)
            actions = torch.clamp(U + eps, self.low, self.high)  # (K, H, nu)
            eps = actions - U  # clamped perturbations (K, H, nu)
            # λ Σ_t u_tᵀ Σ⁻¹ ε_t^k as one matrix-vector product: (K,)
            total = eps.reshape(K, H * nu) @ (U * self._lam_sigma_inv).reshape(H * nu)
            total = total + self._rollout_cost(z.to(U).reshape(1, -1), actions)

            # NaN and ±inf totals all become +inf, so their weight below is exp(-inf) = 0.
            costs = torch.nan_to_num(total, nan=math.inf, posinf=math.inf, neginf=math.inf)
            best = costs.min()
            # β = min cost, clamped finite: an all-discarded batch gives weights 0, not NaN.
            w = torch.exp((best.clamp(max=self._big) - costs) * self._inv_lambda)  # max 1
            w = w / w.sum().clamp_min(1.0)  # the sum is >= 1 unless every weight is 0
            # A convex combination of in-box candidates; the clamp only absorbs rounding.
            U_new = (U + (w @ eps.reshape(K, H * nu)).reshape(H, nu)).clamp(self._lo,
                                                                           self._hi)
        action = U_new[0]
        fill = U_new[-1:] if self._repeat_last else self.u_init.unsqueeze(0)
        self._U = torch.cat((U_new[1:], fill))  # warm start

        n_kept = (costs < math.inf).sum()
        kept_sum = torch.nan_to_num(costs, posinf=0.0).sum()
        n_kept, min_cost, kept_sum = torch.stack((n_kept.to(costs.dtype), best, kept_sum)).tolist()
        discarded = K - int(n_kept)
        mean_cost = kept_sum / n_kept if n_kept else math.nan
        self.actions = actions
        self.noise = eps
        self.costs = costs
        self.weights = w
        return action, discarded, min_cost, mean_cost

    def _rollout_cost(self, z0: Tensor, actions: Tensor) -> Tensor:
        """Σ_t c(z_t) + w_T c(z_H) of all K samples: z0 (1, nz), actions (K, H, nu) -> (K,).

        A step with a ``rollout(z0 (K, nz), actions (K, H, nu)) -> (K, H+1, nz)`` method (like
        :class:`SindyKernelStep`) predicts the whole horizon in one call; any other step is
        called H times. The cost then runs once on all predicted states, (H, K, nz), or on
        the states the actions are taken in and the actions (a cost that ``takes_actions``).
        """
        z = z0.expand(actions.shape[0], -1)  # (K, nz)
        rollout = getattr(self.step, "rollout", None)
        if rollout is not None:
            zs = rollout(z, actions).transpose(0, 1)  # (H+1, K, nz)
        else:
            states = [z]
            for u in actions.unbind(1):  # H steps; u (K, nu)
                z = self.step(z, u)
                states.append(z)
            zs = torch.stack(states)  # (H+1, K, nz)
        if self._cost_of_actions:
            c = self.cost(zs[:-1], actions.transpose(0, 1))  # (H, K)
        else:
            c = self.cost(zs[1:])  # (H, K)
        return c.sum(0) + self.config.terminal_weight * c[-1]
