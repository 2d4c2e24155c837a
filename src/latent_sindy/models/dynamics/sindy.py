"""SINDy latent dynamics: z[t+1] = z + Θ(z, u) (M ⊙ Ψ) over a candidate library, its
frozen fast form for control, and its config.

Ψ is trained (or fitted by sparse regression, :meth:`SindyDynamics.fit_state_data`) and the
mask M only ever pruned, so :class:`SindyDynamics` is a
:class:`~latent_sindy.models.dynamics.base.SparseDynamics`. Any library of
:mod:`latent_sindy.sindy` can be given (``library_spec``); the config chooses one by name.

    >>> model = SindyConfig(order=2).build(nz=16, nu=3)
    >>> z = model.rollout(torch.zeros(4, 16), torch.zeros(4, 10, 3))  # (4, 11, 16)
    >>> fast = model.compile_sparse()  # same step, only the active library terms
    >>> from latent_sindy.sindy import Polynomial, Sine  # any composed library spec
    >>> lib = SindyDynamics(16, 3, library_spec=Polynomial(2, ("z", "u")) + Sine("z"))
    >>> lib.fit_state_data(Z, U, Znext)  # sparse regression (STLSQ) on states: (N, nz), ...
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import torch
import tyro
from torch import nn

from latent_sindy.errors import UserError
from latent_sindy.models.dynamics.base import (
    LatentDynamics,
    Row,
    SparseDynamics,
    check_init_scale,
    format_equations,
    turned_running_sum,
    turned_target,
)
from latent_sindy.models.dynamics.compiled import CompiledSindy
from latent_sindy.sindy import (
    VALID_ORDERS,
    CandidateLibrary,
    LibrarySpec,
    NamedLibrary,
    SindyLibrary,
    named_library,
    spec_from_dict,
)
from latent_sindy.sindy import fit as sindy_fit
from latent_sindy.sindy.optimizers import STLSQ

__all__ = ["CompiledSindy", "SindyConfig", "SindyDynamics"]


class SindyDynamics(SparseDynamics):
    """Residual SINDy step ``z_{t+1} = z_t + Θ(z_t, u_t) (M ⊙ Ψ)``.

    Ψ (p, nz) is a parameter; M (p, nz) is a persistent boolean buffer (part of the state
    dict) that :meth:`prune` only ever turns off. Column j of ``M ⊙ Ψ`` holds the
    coefficients of latent state j.

    Args:
        nz, nu: latent and action sizes.
        order: polynomial order of the classic library (1-4).
        include_sine, include_cosine: add sin(z_i) / cos(z_i) candidates to it.
        init_scale: standard deviation of the normal initialisation of Ψ.
        seed: seed for that initialisation; None draws from the global torch generator.
        library_spec: any library instead of the classic one: a
            :class:`~latent_sindy.sindy.LibrarySpec` or its ``to_dict()`` form (e.g.
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
    def prune(self, tau: float, scale: torch.Tensor | None = None) -> int:
        """Prune active coefficients with ``|Ψ| < tau`` (with weights ``scale`` (p, nz):
        ``|Ψ| · scale < tau``); return how many were newly pruned.

        Compares magnitudes, so negative coefficients are judged like positive ones. The mask
        only goes from on to off; pruned entries of Ψ are set to 0.
        """
        if tau < 0 or math.isnan(tau):
            raise ValueError(f"prune: tau must be a non-negative number, got {tau}")
        size = self.psi.abs() if scale is None else self.psi.abs() * scale
        newly = self.mask & (size < tau)
        self.mask &= ~newly
        self.psi.masked_fill_(~self.mask, 0.0)
        return int(newly.sum())

    @torch.no_grad()
    def set_coefficients(
        self, coef: torch.Tensor, mask: torch.Tensor | None = None
    ) -> SindyDynamics:
        """Set Ψ = ``coef`` (p, nz) and M = ``mask`` (p, nz) bool, default ``coef != 0``;
        returns ``self``. Unlike :meth:`prune` this replaces the mask (it may turn terms
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
        mask allows may be active (``STLSQ(min_share=0)`` then refits them by least squares).
        The regression fits the update before the circle's projection (which :meth:`step`
        then applies); with ``turn``, z_a's target is the angle from (z_a, z_b) to the next
        pair and z_b's none.
        """
        if self.turn:
            Znext = turned_target(Z, Znext, self._circle_index.to(Z.device))
        opt = sindy_fit.fit_state_data(
            self.library, Z, U, Znext, optimizer, mask=self.mask if restrict_to_mask else None
        )
        return self.set_coefficients(opt.coef_, opt.mask_)

    @torch.no_grad()
    def fit_trajectory_data(self, X: torch.Tensor, U: torch.Tensor, window: int | None = None,
                            optimizer: Any = None, valid: torch.Tensor | None = None,
                            restrict_to_mask: bool = False) -> SindyDynamics:
        """Fit Ψ and M to whole trajectories in the windowed form, for latents read with an
        error (a camera's); returns ``self``. :func:`latent_sindy.sindy.fit_trajectory_data`
        with its defaults: X (B, T+1, nz), U (B, T, nu), ``valid`` (B, T+1) the states read
        well; each step's target and ``restrict_to_mask`` as in :meth:`fit_state_data`."""
        run = turned_running_sum(X, self._circle_index.to(X.device), valid) if self.turn else None
        opt = sindy_fit.fit_trajectory_data(self.library, X, U, window, optimizer, valid=valid,
            targets=run, mask=self.mask if restrict_to_mask else None)
        return self.set_coefficients(opt.coef_, opt.mask_)

    @torch.no_grad()
    def prune_circle_ties(self) -> int:
        """With a circle (z_a, z_b): z_b² = 1 − z_a² there, so a term with the factor z_b² is
        a sum of others, and a regression splits one effect among them (z3 and z1² z3 and
        z2² z3 for z3). Prunes those terms (a fit with ``restrict_to_mask`` keeps them out);
        returns how many coefficients it pruned."""
        if self.circle is None:
            raise UserError("prune_circle_ties needs a model built with a circle (a, b)")
        tied = (self.library.table == self.circle[1]).sum(1).cpu() >= 2  # (p,)
        newly = self.mask & tied[:, None].to(self.mask.device)
        self.set_coefficients(self.psi.detach(), self.mask & ~newly)
        return int(newly.sum())

    def n_candidates(self) -> int:
        """Coefficients that may be active: every term for every state (with ``turn``,
        none for z_b, whose update is unused)."""
        p, nz = self.mask.shape
        return p * (nz - 1 if self.turn else nz)

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

    def compile_sparse(self) -> CompiledSindy:
        """A frozen copy of the current model that evaluates only the active library terms.

        Its ``step`` equals this model's ``step`` to float precision (the circle's projection
        included). It holds a snapshot of the coefficients (no gradient): compile again after
        further training or pruning.
        """
        terms = self.active_terms()
        return CompiledSindy(self.library.subset(terms), self.coefficients().detach()[terms],
                             self.nu, self.circle, self.turn)

    def extra_repr(self) -> str:
        return f"nz={self.nz}, nu={self.nu}, active={self.n_active()}/{self.n_candidates()}"




@dataclass(frozen=True)
class SindyConfig:
    """SINDy: z[t+1] = z + Θ(z, u) (M ⊙ Ψ) over a candidate library of [z, u] chosen by name
    (--library: "poly" or one an installed world registers), or composed in Python."""

    kind: ClassVar[str] = "sindy"
    model_class: ClassVar[type[LatentDynamics]] = SindyDynamics
    order: int = 2
    """Polynomial order of the candidate library (1-4; a named library may take fewer)."""
    include_sine: bool = True
    """Add sin(z_i) candidates."""
    include_cosine: bool = False
    """Add cos(z_i) candidates ("poly" library only)."""
    library: str = "poly"
    """The candidate library by name: "poly", monomials of [z, u] up to the order (+ sin z),
    or one an installed world registers (latent_sindy.sindy.library_names() lists them;
    docs/training.md). In Python a library composed from the grammar goes to `composed`
    instead (or LatentSINDy(library=spec))."""
    library_options: tuple[str, ...] = ()
    """KEY=VALUE options of the named library (the fields of its options dataclass), e.g.
    `frequency=4`; a value left out keeps its default. In Python a mapping or the options
    dataclass is taken too; the config keeps the pairs that differ from the defaults."""
    init_scale: float = 1e-3
    """Standard deviation of the initial coefficients Ψ."""
    composed: tyro.conf.Suppress[Any] = None
    """A library composed in Python from the grammar (a LibrarySpec; the config keeps its
    dict), in place of a named one: ``SindyConfig(composed=Polynomial(("z", "u"), 2) +
    Sine("z"))``. It holds its own terms, so ``order`` and the sine and cosine switches are
    not read."""

    def __post_init__(self) -> None:
        if isinstance(self.order, bool) or self.order not in VALID_ORDERS:
            raise UserError(f"SINDy order {self.order} is not supported: use 1, 2, 3 or 4")
        if self.composed is not None:
            if self.library != "poly" or self.library_options:
                raise UserError(f"a composed library replaces a named one: drop library "
                                f"{self.library!r} and its options, or the composed spec")
            object.__setattr__(self, "composed", spec_from_dict(self.composed).to_dict())
        library = named_library(self.library)
        if self.library != "poly" and self.include_cosine:
            raise UserError("--include-cosine is for the poly library only")
        if self.order not in library.orders:
            raise UserError(f"--library {self.library} with --order {self.order}: that library "
                            f"takes --order {' or '.join(map(str, library.orders))}")
        options = library.settings(self.library_options, f"--library-options of {self.library}")
        object.__setattr__(self, "library_options", library.pairs(options))
        check_init_scale("SINDy", self.init_scale)

    @property
    def named(self) -> NamedLibrary:
        """What the library's name stands for (its builder, options and needs)."""
        return named_library(self.library)

    @property
    def options(self) -> Any:
        """The named library's options (its options dataclass)."""
        return self.named.settings(self.library_options, f"--library-options of {self.library}")

    def with_options(self, **changes: Any) -> SindyConfig:
        """This config with the named library's options ``changes`` replaced."""
        return dataclasses.replace(self, library_options=dataclasses.replace(
            self.options, **changes))

    @property
    def pose_library(self) -> bool:
        """Whether the library writes the dynamics on a pose latent (x, y, cos fθ, sin fθ,
        ...): the model needs a latent whose first four coordinates are those."""
        return self.named.pose_latent

    @property
    def follows_latent(self) -> bool:
        """Whether the library's angle frequency is left to the pose latent's (its
        ``latent_frequency`` option at 0): resolved from the encoder's moment order."""
        name = self.named.latent_frequency
        return name is not None and getattr(self.options, name) == 0

    def with_latent_frequency(self, frequency: float) -> SindyConfig:
        """This config with a frequency left to the latent (:attr:`follows_latent`) set to
        ``frequency``; as it is otherwise."""
        if not self.follows_latent:
            return self
        return self.with_options(**{self.named.latent_frequency: float(frequency)})

    def build(self, nz: int, nu: int, circle: Sequence[int] | None = None,
              turn: bool = False) -> SindyDynamics:
        """The model for latent size nz and action size nu; ``circle``: the latent
        coordinates kept on the unit circle, ``turn``: turned by z_a's update (see
        :class:`LatentDynamics`)."""
        if self.composed is not None:
            return SindyDynamics(nz, nu, init_scale=self.init_scale, library_spec=self.composed,
                                 circle=circle, turn=turn)
        if self.library == "poly":
            return SindyDynamics(nz, nu, order=self.order, include_sine=self.include_sine,
                                 include_cosine=self.include_cosine, init_scale=self.init_scale,
                                 circle=circle, turn=turn)
        library = self.named
        if nu < library.actions:
            raise UserError(f"the {self.library} library needs at least {library.actions} "
                            f"action coordinates, got {nu}")
        if library.pose_latent and nz < 4:
            raise UserError(f"the {self.library} library needs the pose (x, y, cos fθ, sin fθ) "
                            f"as the first four latent coordinates, got a latent of size {nz}: "
                            "use the state or moments encoder or --pose-head coordinates")
        spec = library.build(self.order, self.include_sine, self.options)
        return SindyDynamics(nz, nu, init_scale=self.init_scale, library_spec=spec, circle=circle,
                             turn=turn)
