"""Planning on a latent that is read from the frames, not learned: a world's reader (image
moments, a marker, a tracker) gives the latent, and only its dynamics and a reward head are
fitted. The estimator the model-based loop (:func:`~latent_sindy.model_based.model_based`) takes
like any other, so SINDy, linear and MLP dynamics on the same read latent are compared on
the same data and planner.

A reader (:class:`LatentReader`) is fitted on training episodes and then reads an episode's
latents (with a flag per frame: was the object seen), or one observation's from it and the
action held since the last one (a latent of two stacked frames needs it: their change
depends on that action). Frames not seen are left out of every fit.

SINDy is fitted in the windowed form (:meth:`SindyDynamics.fit_trajectory_data`: a reader's
error enters a window's two ends only) with trimmed STLSQ (end stops, contacts). By default
that fit is first made on four fifths of the episodes and rolled out over the planner's
horizon on the fifth held out; where more than 1 % of those rollouts diverge, the window,
the trimmed share and STLSQ's threshold are chosen instead among :data:`FIT_CHOICES`, by
the same rollouts (:func:`choose_fit`), and the chosen fit is made again on all episodes. Linear
dynamics by least squares on the seen transitions; the MLP by Adam on them. The latents are
standardised (a reader's (cos, sin) pair, its ``circle``, kept as it is) before any fit.

The planner filters what it reads: its latent is the model's prediction from the last one
moved by ``gain`` of the way to the reading (the reading alone where no latent came before,
the prediction is not finite, or the frame did not see the object: a model's prediction
carried on out of view planned worse than the raw reading on the cart-pole, RESULTS.md).
A reader's error, which a frame difference doubles in the velocities, is then averaged
over steps by the model. The gain is chosen on the training episodes
(:func:`filter_gain`): of :data:`GAINS`, the one whose filtered latents best predict, through
the model, the readings two steps on (an error of the reading at that step is independent
of the filtered latent, so the smallest error is the most accurate latent). It plans
against the reward head less a penalty for predicted latents outside the range of the
training latents in view (``support``): a plan that leaves the reader's view, or the
model's data, is a plan from guesses.

    def make(iteration):
        return ReadLatent(ColourPoseReader(64), ReadLatentConfig(dynamics="sindy"), seed=iteration)
    result = model_based(world, make, ModelBasedConfig(..., warm_updates=0), out="runs/read")
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal, Protocol

import numpy as np
import torch

from latent_sindy.control.costs import RewardCost
from latent_sindy.control.mppi import MPPI, MPPIConfig, latent_step
from latent_sindy.data import SequenceData
from latent_sindy.errors import UserError
from latent_sindy.models.dynamics import LinearConfig, MlpConfig, SindyConfig
from latent_sindy.models.reward_head import RewardHead
from latent_sindy.sindy import STLSQ, Trimmed

__all__ = ["DIVERGED_SHARE", "ERROR_CAP", "FIT_CHOICES", "GAINS", "FitChoice", "FitSetting",
           "HeldOut", "LatentReader", "ReadLatent", "ReadLatentConfig", "ReadLatentPlanner",
           "choose_fit", "filter_gain", "filter_step", "filtered", "held_out_rollouts"]

#: The filter gains :func:`filter_gain` chooses from (1: the reading alone).
GAINS = (0.2, 0.3, 0.4, 0.5, 0.6, 0.8, 1.0)


@dataclass(frozen=True)
class FitSetting:
    """One SINDy fit on a read latent: windows of ``window`` steps, the ``trim`` share of
    them left out as the worst explained, STLSQ's ``min_share``."""

    window: int
    trim: float
    min_share: float


#: The SINDy fits ``ReadLatentConfig(select=True)`` chooses from when the set one diverges:
#: windows of 5 steps or one, 30 %, 10 % or none of them trimmed, a term's least share 3 %,
#: 10 % or 20 %.
FIT_CHOICES: tuple[FitSetting, ...] = tuple(
    FitSetting(w, t, m) for w in (5, 1) for t in (0.3, 0.1, 0.0) for m in (0.03, 0.1, 0.2))

#: A rollout's squared error (standardised units) above this has diverged: it counts this
#: much in :func:`held_out_rollouts`' error, a lot but not everything.
ERROR_CAP = 10.0

#: The set fit is kept while at most this share of its held-out rollouts diverge.
DIVERGED_SHARE = 0.01


@dataclass(frozen=True)
class HeldOut:
    """How a model's rollouts over a horizon predict held-out episodes."""

    error: float
    """Squared error (mean over the latent), each capped at :data:`ERROR_CAP`, averaged over
    the steps and the starts; nan where no start has its horizon seen."""
    diverged: float
    """Share of the rollouts whose squared error passed the cap (or left the floats) within
    the horizon."""


@dataclass(frozen=True)
class FitChoice:
    """What :func:`choose_fit` chose: the ``setting``, and for every setting tried its
    active terms and held-out rollouts (``path``: (setting, terms, HeldOut); the set one
    first), on ``held_out`` episodes."""

    setting: FitSetting
    path: tuple[tuple[FitSetting, int, HeldOut], ...]
    held_out: tuple[int, ...]

    def table(self) -> str:
        """The path as text: a line per setting, the chosen one marked."""
        return "\n".join(
            f"{'*' if s == self.setting else ' '} window {s.window}, trim {s.trim:g}, "
            f"min_share {s.min_share:g}: {terms} terms, held-out error {h.error:.4g}, "
            f"{h.diverged:.1%} diverged" for s, terms, h in self.path)


@torch.no_grad()
def held_out_rollouts(model: torch.nn.Module, Z: torch.Tensor, U: torch.Tensor,
                      seen: torch.Tensor, horizon: int, cap: float = ERROR_CAP) -> HeldOut:
    """How well ``model`` (``model(z, u)`` -> the next z) predicts episodes Z (E, T+1, nz)
    under their actions U (E, T, nu) over ``horizon`` steps, rolled out from every frame
    whose next ``horizon`` frames are all ``seen`` (E, T+1): :class:`HeldOut`."""
    T = U.shape[1]
    runs = (seen.unfold(1, horizon + 1, 1).all(-1) if T >= horizon  # (E, T - horizon + 1)
            else seen[:, :0])
    e, t = runs.nonzero(as_tuple=True)
    if len(e) == 0:
        return HeldOut(math.nan, math.nan)
    z = Z[e, t].float()
    total = 0.0
    gone = torch.zeros(len(e), dtype=torch.bool)
    for h in range(horizon):
        z = model(z, U[e, t + h].float())
        err = (z - Z[e, t + h + 1].float()).pow(2).mean(-1)
        gone |= ~(err <= cap)
        total += float(torch.nan_to_num(err, nan=cap, posinf=cap).clamp(max=cap).mean())
    return HeldOut(total / horizon, float(gone.double().mean()))


def choose_fit(fit: Any, Z: torch.Tensor, U: torch.Tensor, seen: torch.Tensor,
               keep: FitSetting, settings: tuple[FitSetting, ...], horizon: int, seed: int,
               slack: float = 1.1, share: float = 0.2, always: bool = False
               ) -> FitChoice | None:
    """The set fit ``keep`` while its rollouts over ``horizon`` steps seldom diverge on
    held-out episodes (at most :data:`DIVERGED_SHARE` of them); else (or ``always``), of
    ``keep`` and ``settings``, the sparsest whose held-out error is within ``slack`` of the
    best among those that diverge least (:func:`held_out_rollouts`). ``fit(setting,
    episodes)`` -> a model fitted on those episodes of Z (E, T+1, nz), U (E, T, nu),
    ``seen`` (E, T+1), with ``coefficients()`` (its terms: those not 0 count as active);
    ``share`` of the episodes (a random draw by ``seed``, at least one) are held out. None
    where that cannot be judged: fewer than 5 episodes, or no held-out run of ``horizon``
    frames seen.

    A sparse model fitted one step (or one window) at a time may still diverge within the
    planner's horizon: on the cart-pole's learned keypoints the set windowed fit predicted
    best over a few steps but diverged in a tenth of the horizons; where it does not, a
    choice among fits by held-out error alone planned no better (RESULTS.md)."""
    n = Z.shape[0]
    if n < 5:
        return None
    order = torch.randperm(n, generator=torch.Generator().manual_seed(seed))
    k = max(1, round(share * n))
    held, kept = order[:k].sort().values, order[k:].sort().values

    def judged(setting: FitSetting) -> tuple[FitSetting, int, HeldOut]:
        model = fit(setting, kept)
        return (setting, int((model.coefficients() != 0).sum()),
                held_out_rollouts(model, Z[held], U[held], seen[held], horizon))

    first = judged(keep)
    if math.isnan(first[2].error):
        return None
    path = [first]
    if always or first[2].diverged > DIVERGED_SHARE:
        path += [judged(s) for s in settings if s != keep]
    least = min(h.diverged for _, _, h in path)
    calm = [p for p in path if p[2].diverged <= max(least, DIVERGED_SHARE)]
    best = min(h.error for _, _, h in calm)
    chosen = min((p for p in calm if p[2].error <= slack * best),
                 key=lambda p: (p[1], p[2].error))
    return FitChoice(chosen[0], tuple(path), tuple(held.tolist()))


class LatentReader(Protocol):
    """Reads latents from observations; ``circle``: the latent coordinates of an angle's
    (cos, sin) pair, or None."""

    circle: tuple[int, int] | None

    def fit_episodes(self, images: torch.Tensor) -> LatentReader:
        """Fit on training episodes' observations (E, T+1, C, H, W); returns ``self``."""

    def episode(self, images: torch.Tensor, actions: torch.Tensor, dt: float
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """One episode's latents (T+1, nz) float64 and (T+1,) bool seen."""

    def latent(self, obs: torch.Tensor, previous: torch.Tensor, dt: float
               ) -> tuple[torch.Tensor, torch.Tensor]:
        """Latents (B, nz) of observations (B, C, H, W), the actions held since the last
        ones (B, nu); and (B,) bool seen."""


@dataclass(frozen=True)
class ReadLatentConfig:
    """The fits on a read latent."""

    dynamics: Literal["sindy", "linear", "mlp"] = "sindy"
    order: int = 3
    """SINDy's polynomial order."""
    window: int = 5
    """SINDy's windowed fit: steps a window sums (1: the one-step fit)."""
    min_share: float = 0.03
    """STLSQ's threshold (a term's least share of a change's RMS; on the cart-pole's read
    latent 0.03 kept a third of the terms of 0.01 and planned as well, RESULTS.md)."""
    trim: float = 0.3
    """Share of SINDy's windows left out as the worst explained (end stops, contacts)."""
    select: bool = True
    """Check SINDy's fit (``window``, ``trim``, ``min_share``) on held-out episodes and, where
    more than 1 % of its rollouts over ``horizon`` steps diverge, fit instead the sparsest of
    :data:`FIT_CHOICES` that diverges least and predicts within 10 % of the best
    (:func:`choose_fit`); False: fit the three as they are set, unchecked."""
    horizon: int = 20
    """Steps of the held-out rollouts ``select`` judges a fit by (the planner's horizon)."""
    sparsest_within: float | None = None
    """With ``select``: judge every fit of :data:`FIT_CHOICES` on the held-out episodes,
    even where the set one holds, and fit the sparsest whose held-out error is within this
    factor of the best among those that diverge least (readable equations for some
    prediction: 2 kept a quarter of the terms on the cart-pole's 8 keypoints, RESULTS.md);
    None: the set fit unless it diverges, and otherwise the sparsest within 1.1."""
    reward_width: int = 64
    updates: int = 3000
    """Adam updates of the reward head and of the MLP (batches of 256 rows)."""
    mlp_width: int = 128
    reader_episodes: int | None = None
    """The reader is fitted on the data's first this many episodes (None: all). A model-based
    loop's first episodes are its random ones; a reader fitted by the frames' statistics (a
    median background) would, on planned episodes that hold the object in one place, take
    the object for background there."""
    gain: float | None = None
    """The planner's filter gain (module docstring): 1 plans from each reading as it is;
    None chooses it from :data:`GAINS` on the training episodes (:func:`filter_gain`)."""

    support: float = 10.0
    """The planner gives up this much reward a step for each standardised unit a predicted
    latent lies outside the range of the training latents in view (``RewardCost``'s
    support): plans stay where the reader sees and the model has data (0: no penalty;
    RESULTS.md)."""

    def __post_init__(self) -> None:
        if self.dynamics not in ("sindy", "linear", "mlp"):
            raise UserError(f"dynamics {self.dynamics!r}: use sindy, linear or mlp")
        if self.gain is not None and not (isinstance(self.gain, int | float)
                                          and 0.0 < self.gain <= 1.0):
            raise UserError(f"ReadLatentConfig gain={self.gain!r}: use a number in (0, 1], "
                            "or None to choose it from the training episodes")
        if not isinstance(self.select, bool):
            raise UserError(f"ReadLatentConfig select={self.select!r}: use True (check SINDy's "
                            "fit on held-out episodes) or False")
        if self.sparsest_within is not None and not (
                isinstance(self.sparsest_within, int | float)
                and not isinstance(self.sparsest_within, bool)
                and 1.0 <= self.sparsest_within < math.inf and self.select):
            raise UserError(f"ReadLatentConfig sparsest_within={self.sparsest_within!r}: use "
                            "a number >= 1 (a factor of the best held-out error) with "
                            "select=True, or None")
        if not (isinstance(self.support, int | float) and not isinstance(self.support, bool)
                and 0.0 <= self.support < math.inf):
            raise UserError(f"ReadLatentConfig support={self.support!r}: use a number >= 0 "
                            "(0: no penalty)")
        for name in ("order", "window", "horizon", "reward_width", "updates", "mlp_width") + (
                () if self.reader_episodes is None else ("reader_episodes",)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise UserError(f"ReadLatentConfig {name}={value!r}: use an integer >= 1")


class ReadLatent:
    """Dynamics and a reward head fitted on a reader's latents; see the module docstring."""

    def __init__(self, reader: LatentReader, config: ReadLatentConfig | None = None,
                 seed: int = 0) -> None:
        for method in ("fit_episodes", "episode", "latent"):
            if not callable(getattr(reader, method, None)):
                raise UserError(f"ReadLatent needs a reader with {method}(); "
                                f"{type(reader).__name__} has none")
        self.reader = reader
        self.config = config or ReadLatentConfig()
        self.seed = seed

    def fit(self, data: SequenceData, **_: Any) -> ReadLatent:
        """Fit the reader, the dynamics and the reward head on ``data`` (stacked-frame
        episodes with actions and rewards); returns ``self``."""
        if data.actions is None or data.rewards is None:
            raise UserError("ReadLatent.fit needs episodes with actions and rewards")
        cfg = self.config
        gen = torch.Generator().manual_seed(self.seed)
        torch.manual_seed(self.seed)
        images = torch.from_numpy(np.asarray(data.images))
        actions = torch.from_numpy(np.asarray(data.actions, np.float64))
        # (changes per second where the data give dt, else per step: the fits standardise)
        self.dt = float(data.dt) if data.dt is not None else 1.0
        self.reader.fit_episodes(images[:cfg.reader_episodes])
        read = [self.reader.episode(images[e], actions[e], self.dt) for e in range(data.n)]
        Z = torch.stack([z for z, _ in read])
        seen = torch.stack([s for _, s in read])
        if int(seen.sum()) < 2:
            raise UserError("ReadLatent.fit: the reader saw the object in fewer than two "
                            "frames; check the reader on these frames")
        circle = getattr(self.reader, "circle", None)
        self.mean, self.sd = Z[seen].mean(0), Z[seen].std(0).clamp_min(1e-12)
        if circle is not None:
            self.mean[list(circle)] = 0.0
            self.sd[list(circle)] = 1.0
        Zs = (Z - self.mean) / self.sd
        self.support_ = (Zs[seen].min(0).values.float(), Zs[seen].max(0).values.float())
        rows = (seen[:, :-1] & seen[:, 1:]).reshape(-1)
        nz, nu = Z.shape[-1], actions.shape[-1]
        z0 = Zs[:, :-1].reshape(-1, nz)[rows].float()
        z1 = Zs[:, 1:].reshape(-1, nz)[rows].float()
        u = actions.reshape(-1, nu)[rows].float()
        if cfg.dynamics == "sindy":
            def sindy(setting: FitSetting, episodes: torch.Tensor) -> torch.nn.Module:
                model = SindyConfig(order=cfg.order, include_sine=False).build(
                    nz, nu, circle=circle)  # (the regression itself runs in float64)
                return model.fit_trajectory_data(
                    Zs[episodes], actions[episodes], setting.window,
                    Trimmed(STLSQ(min_share=setting.min_share), share=setting.trim),
                    valid=seen[episodes]).requires_grad_(False)

            fixed = FitSetting(cfg.window, cfg.trim, cfg.min_share)
            sparsest = ({} if cfg.sparsest_within is None else
                        {"slack": cfg.sparsest_within, "always": True})
            self.selection_ = choose_fit(sindy, Zs, actions, seen, fixed, FIT_CHOICES,
                                         cfg.horizon, self.seed, **sparsest
                                         ) if cfg.select else None
            self.model = sindy(self.selection_.setting if self.selection_ else fixed,
                               torch.arange(data.n))
        elif cfg.dynamics == "linear":
            self.model = LinearConfig().build(nz, nu, circle=circle)
            self.model.fit_least_squares(z0, u, z1)
        else:
            self.model = MlpConfig(hidden=cfg.mlp_width).build(nz, nu, circle=circle)
            _adam(self.model, lambda i: (self.model(z0[i], u[i]) - z1[i]).pow(2).mean(),
                  len(z0), cfg.updates, gen)
        self.model.requires_grad_(False)
        r = torch.from_numpy(np.asarray(data.rewards, np.float32)).reshape(-1)[rows]
        self.head = RewardHead(nz, nu, cfg.reward_width)
        _adam(self.head, lambda i: (self.head(z0[i], u[i]) - r[i]).pow(2).mean(), len(z0),
              cfg.updates, gen)
        self.head.requires_grad_(False)
        with torch.no_grad():
            self.gain_, self.gain_errors_ = (cfg.gain, {}) if cfg.gain is not None else (
                filter_gain(self.model, Zs.float(), actions.float(), seen, circle))
        self.action_low = np.asarray(data.action_low, np.float64)
        self.action_high = np.asarray(data.action_high, np.float64)
        self.seen_share_ = float(seen.double().mean())
        return self

    def _check_fitted(self) -> None:
        if not hasattr(self, "model"):
            raise UserError("ReadLatent: fit it first")

    def latent_record(self) -> dict[str, Any]:
        """What the latent of the last fit is, JSON-ready: its coordinates' names, the share
        of frames seen, the filter gain and, where the reader says (``record()``), what it
        found; ``summary``, the same in a line."""
        self._check_fitted()
        own = getattr(self.reader, "record", None)
        reader = own() if callable(own) else {"reader": type(self.reader).__name__}
        names = list(getattr(self.reader, "names", ()) or ())
        summary = reader.get("summary") or reader["reader"]
        record = {"reader": reader, "coordinates": names, "seen_share": self.seen_share_,
                  "gain": self.gain_,
                  "summary": f"latent {', '.join(names) or '(unnamed)'}: {summary}; "
                             f"{self.seen_share_:.0%} of the frames seen"}
        choice = getattr(self, "selection_", None)
        if choice is not None:
            s = choice.setting
            record["sindy_fit"] = {"window": s.window, "trim": s.trim,
                                   "min_share": s.min_share,
                                   "held_out_episodes": len(choice.held_out),
                                   "tried": [{"window": t.window, "trim": t.trim,
                                              "min_share": t.min_share, "terms": terms,
                                              "held_out_error": h.error,
                                              "diverged": h.diverged}
                                             for t, terms, h in choice.path]}
            first = choice.path[0][2]
            within = self.config.sparsest_within
            record["sindy_fit"]["sparsest_within"] = within
            setting = f"window {s.window}, trim {s.trim:g}, min_share {s.min_share:g}"
            if within is not None:
                terms = next(t for tried, t, _ in choice.path if tried == s)
                outcome = (f"; the sparsest of {len(choice.path)} fits within {within:g} of "
                           f"the best held-out error: {setting}, {terms} terms")
            else:
                outcome = ", kept" if s == choice.path[0][0] else f"; replaced by {setting}"
            record["summary"] += (
                f"; SINDy's set fit diverged in {first.diverged:.1%} of the rollouts on "
                f"{len(choice.held_out)} held-out episodes{outcome}")
        return record

    def planner(self, mppi: MPPIConfig | None = None, seed: int = 0,
                objective: str = "reward") -> ReadLatentPlanner:
        """MPPI on the read latent against the reward head: ``act(image)`` -> (nu,)."""
        self._check_fitted()
        if objective != "reward":
            raise UserError(f"ReadLatent plans against its reward head; objective "
                            f"{objective!r} is not one it has")
        return ReadLatentPlanner(self, mppi or MPPIConfig(), seed)

    def equations(self) -> list[str]:
        """The dynamics' equations on the standardised latent (an MLP has none), after a
        line naming the latent's coordinates where the reader names them (``names``)."""
        self._check_fitted()
        if self.config.dynamics == "mlp":
            raise NotImplementedError("an MLP's dynamics have no equations")
        names = getattr(self.reader, "names", None)
        legend = [] if not names else ["latent: " + ", ".join(
            f"z{i} = {n}" for i, n in enumerate(names)) + " (each standardised over the "
            "training frames" + (", but the circle's pair" if self.model.circle else "") + ")"]
        return legend + list(self.model.equations())

    def coefficients(self) -> np.ndarray:
        """The SINDy coefficients (p, nz) (zeros where pruned)."""
        self._check_fitted()
        if self.config.dynamics != "sindy":
            raise NotImplementedError("coefficients are a SINDy model's")
        return self.model.coefficients().detach().numpy().copy()


class ReadLatentPlanner:
    """MPPI on a :class:`ReadLatent`'s latent; it keeps the last action for the next
    reading (:meth:`note_action` tells it the one carried out, if noise changed it)."""

    def __init__(self, est: ReadLatent, mppi: MPPIConfig, seed: int) -> None:
        self.est = est
        self.cfg = mppi
        self.seed = seed
        self.reset()

    def reset(self, goal: Any = None, seed: int | None = None) -> None:
        cost = RewardCost(self.est.head, self.est.support_, self.est.config.support)
        self.mppi = MPPI(latent_step(self.est.model), cost, self.cfg,
                         self.est.action_low.tolist(), self.est.action_high.tolist(),
                         seed=self.seed if seed is None else seed)
        self.previous = np.zeros(len(self.est.action_low))
        self.latent: torch.Tensor | None = None  # the last filtered latent (standardised)

    def note_action(self, action: np.ndarray) -> None:
        self.previous = np.asarray(action, np.float64).reshape(-1)

    def act(self, image: np.ndarray, goal_image: Any = None) -> np.ndarray:
        z, seen = self.est.reader.latent(torch.from_numpy(np.asarray(image))[None],
                                         torch.from_numpy(self.previous)[None], self.est.dt)
        zs = ((z[0] - self.est.mean) / self.est.sd).float()
        if self.latent is not None and self.est.gain_ < 1.0:
            with torch.no_grad():
                zs = filter_step(self.est.model(self.latent[None], torch.from_numpy(
                    self.previous).float()[None])[0], zs, seen[0], self.est.gain_,
                    getattr(self.est.reader, "circle", None))
        if self.latent is not None or bool(seen[0]):  # (filtered from the first seen frame)
            self.latent = zs
        u = self.mppi.command(zs)[0].detach().numpy().astype(np.float64)
        self.previous = u
        return u


def filter_step(pred: torch.Tensor, read: torch.Tensor, seen: torch.Tensor, gain: float,
                circle: tuple[int, int] | None) -> torch.Tensor:
    """The filter's step (..., nz): ``gain`` of the way from the prediction to the reading
    where ``seen`` (...,) and the prediction is finite, the reading elsewhere; a circle's
    pair back on the unit circle. Gain 1 returns the reading as it is."""
    if gain >= 1.0:
        return read
    use = seen[..., None] & torch.isfinite(pred).all(-1, keepdim=True)
    out = torch.where(use, pred + gain * (read - pred), read)
    if circle is not None:
        pair = out[..., list(circle)]
        out[..., list(circle)] = pair / pair.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    return out


def filtered(model: torch.nn.Module, Z: torch.Tensor, U: torch.Tensor, seen: torch.Tensor,
             gain: float, circle: tuple[int, int] | None = None) -> torch.Tensor:
    """Filtered latents (E, T+1, nz) of episodes' readings Z (E, T+1, nz), actions U (E, T,
    nu) and seen flags (E, T+1): each step ``gain`` of the way from the model's prediction
    to the reading (the planner's filter, module docstring); readings as they are until an
    episode's first seen frame."""
    est = Z[:, 0]
    out = [Z[:, 0]]
    known = seen[:, 0].clone()
    for t in range(U.shape[1]):
        step = filter_step(model(est, U[:, t]), Z[:, t + 1], seen[:, t + 1], gain, circle)
        est = torch.where(known[:, None], step, Z[:, t + 1])
        known |= seen[:, t + 1]
        out.append(est)
    return torch.stack(out, 1)


def filter_gain(model: torch.nn.Module, Z: torch.Tensor, U: torch.Tensor, seen: torch.Tensor,
                circle: tuple[int, int] | None = None, gains: tuple[float, ...] = GAINS
                ) -> tuple[float, dict[float, float]]:
    """The gain of ``gains`` whose filtered latents (:func:`filtered`) predict the readings
    two steps on best (mean squared error over seen frames; of gains within 0.1 % of the
    least error, the largest); and each gain's error."""
    if U.shape[1] < 2:
        raise UserError("filter_gain needs episodes of at least two steps")
    errors = {}
    for gain in gains:
        est = filtered(model, Z, U, seen, gain, circle)[:, :-2]
        ahead = model(model(est.flatten(0, 1), U[:, :-1].flatten(0, 1)),
                      U[:, 1:].flatten(0, 1)).view_as(est)
        err = (ahead - Z[:, 2:]).square().sum(-1)
        ok = seen[:, 2:] & torch.isfinite(err)
        errors[float(gain)] = float(err[ok].mean()) if bool(ok.any()) else math.inf
    # the largest gain within 0.1 % of the least error (and float32's rounding of the
    # latents' scale): the reading as it is unless filtering helps
    close = min(errors.values()) * 1.001 + 1e-6 * float(Z[seen].square().sum(-1).mean())
    return max(g for g, e in errors.items() if e <= close), errors


def _adam(module: torch.nn.Module, loss, n: int, updates: int, gen: torch.Generator) -> None:
    """``updates`` Adam steps (lr 3e-3) on ``loss(rows)`` of batches of 256 of n rows."""
    opt = torch.optim.Adam(module.parameters(), lr=3e-3)
    for _ in range(updates):
        value = loss(torch.randint(0, n, (min(256, n),), generator=gen))
        opt.zero_grad()
        value.backward()
        opt.step()
