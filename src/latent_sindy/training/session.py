"""One training, set up in one place: :func:`prepare` checks the settings and the data and
builds everything a fit needs (a :class:`Session`: model, optimiser, mini-batch generator,
tensors, where it stands); :meth:`Session.fit` trains it, whole or a :class:`Phase` at a time.
The estimator, the run folder (:mod:`latent_sindy.training.train_run`), the choice of a moment
order and the worlds' own studies all train through it.

An autoencoder and its sparse dynamics find a good model from some initialisations and not
from others (the paper kept the best of ten runs). With ``TrainConfig.starts`` > 1, prepare
trains that many candidates (seeded from ``cfg.seed``) for ``start_epochs`` and keeps the one
of lowest validation objective; it continues to ``cfg.epochs`` as if it had been the only
one (its metrics from epoch 1, its optimiser and batches as they were).

    session = prepare(cfg, data)          # every check first, then the model and its start
    result = session.fit()                # to cfg.epochs: the kept weights and the metrics
    model = session.finish(result)        # the kept weights (and --sindy-fit after)

    warm = session.fit(Phase(100, "warm-up", {"loss": LossWeights(lambda_l1=0.0)}, adopt=False))
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from latent_sindy.atomic import check_memory
from latent_sindy.configs import from_json
from latent_sindy.data import SequenceData
from latent_sindy.data.windows import Normalizer
from latent_sindy.errors import UserError
from latent_sindy.models.latent_model import LatentModel, ModelConfig
from latent_sindy.progress import Progress, Silent
from latent_sindy.training.config import TrainConfig, resolve_device, resolve_parallel
from latent_sindy.training.fit_loop import (
    BestValidation,
    FitResult,
    TrainingDiverged,
    evaluate,
    fit,
    to_cpu,
)
from latent_sindy.training.memory import check_training_memory
from latent_sindy.training.metrics import METRIC_COLUMNS
from latent_sindy.training.prepare import (
    TrainingTensors,
    fit_after,
    new_model,
    regression_init,
    settle_model,
    settle_settings,
    training_tensors,
)
from latent_sindy.training.record import run_record

__all__ = ["Phase", "Restarts", "Session", "fit_in_memory", "kept_value", "prepare",
           "start_seed"]


@dataclass(frozen=True)
class Phase:
    """A stretch of ``epochs`` epochs trained with settings of its own (``changes``: any
    :class:`TrainConfig` fields, e.g. ``loss``, ``lr``, ``prune_every``,
    ``refine_epochs``), after whatever the session has trained. Its epochs keep counting
    from the session's, so pruning every k epochs falls where it would in one run. A phase
    chooses its kept weights among its own epochs (its objective may differ from the last
    phase's), and the session continues from them (``adopt``) or from its last epoch."""

    epochs: int
    name: str = "phase"
    changes: Mapping[str, Any] = field(default_factory=dict)
    adopt: bool = True

    def __post_init__(self) -> None:
        if self.epochs < 0:
            raise UserError(f"phase {self.name!r}: epochs {self.epochs}: use 0 or more")
        object.__setattr__(self, "changes", dict(self.changes))
        unknown = set(self.changes) - {f.name for f in dataclasses.fields(TrainConfig)}
        if unknown or "epochs" in self.changes:
            raise UserError(f"phase {self.name!r} changes {sorted(unknown or {'epochs'})}: "
                            "give TrainConfig fields other than epochs (the phase's own)")


@dataclass
class Session:
    """A model ready to train from epoch ``done`` + 1: its settings, optimiser, generator and
    tensors, the metrics and selection state so far, and how its start was chosen (``info``:
    None for a single start)."""

    cfg: TrainConfig
    model: LatentModel
    opt: torch.optim.Optimizer
    gen: torch.Generator
    tensors: TrainingTensors
    data: SequenceData
    norm: Normalizer
    record: dict[str, Any]
    device: torch.device
    parts: int = 1
    done: int = 0
    metrics: list[dict[str, Any]] = field(default_factory=list)
    best: BestValidation = field(default_factory=BestValidation)
    info: dict[str, Any] | None = None

    def fit(self, phase: Phase | None = None,
            on_epoch: Callable[[int, dict[str, Any]], None] | None = None) -> FitResult:
        """Train: without ``phase`` to ``cfg.epochs`` with the run's settings, its metrics and
        selection going on (a resumed run, the chosen start); with one, the phase's epochs
        with its settings, then its kept weights adopted as it says. Returns the fit's
        result (:func:`~latent_sindy.training.fit_loop.fit`)."""
        if phase is None:
            result = self._fit(self.cfg, self.metrics, self.best, on_epoch)
        else:
            cfg = dataclasses.replace(self.cfg, **phase.changes, epochs=self.done + phase.epochs)
            for group in self.opt.param_groups:
                group["lr"] = cfg.lr
            result = self._fit(cfg, [], BestValidation(), on_epoch)
            result.kept["phase"] = phase.name
            if phase.adopt:
                self.model.load_state_dict(result.state)
        self.done = max(self.done, result.metrics[-1]["epoch"] if result.metrics else 0)
        return result

    def _fit(self, cfg: TrainConfig, metrics: list, best: BestValidation,
             on_epoch: Callable[[int, dict[str, Any]], None] | None) -> FitResult:
        result = fit(self.model, self.opt, self.gen, self.tensors.train, self.tensors.val,
                     cfg, per_batch=self.tensors.per_batch, parts=self.parts, done=self.done,
                     metrics=metrics, best=best, on_epoch=on_epoch)
        if self.info is not None:
            result.kept["start"] = self.info
        return result

    def finish(self, result: FitResult) -> LatentModel:
        """The model with ``result``'s kept weights and, with ``--sindy-fit after``, its
        coefficients fitted to the trained encoder (``result.state`` then updated too)."""
        self.model.load_state_dict(result.state)
        if self.cfg.sindy_fit == "after":
            fit_after(self.model, self.data, self.norm, self.cfg, self.device)
            result.state = to_cpu(self.model.state_dict())
        return self.model


def prepare(cfg: TrainConfig, data: SequenceData, device: str | torch.device | None = None,
            *, record: dict[str, Any] | None = None, earlier: dict[str, Any] | None = None,
            resumed: bool = False, progress: Progress | None = None,
            ready: Callable[[], None] | None = None) -> Session:
    """Check ``cfg`` against ``data`` and build its :class:`Session`: the settings the data
    settle (batch size), the record a run folder keeps (``record``: where the caller made it),
    the memory the training needs, a moment order chosen from the data, the model, its
    optimiser and tensors, and, unless ``resumed`` (the caller then loads its checkpoint into
    the session), the start (several candidates where ``cfg.starts`` > 1). ``earlier``: the
    record of a run being resumed, whose choices stand. UserError for anything unusable,
    before any model is trained; ``ready()``, where given, is called once everything is
    checked and before the starts train (a run folder writes its record then)."""
    progress = progress or Silent()
    cfg = settle_settings(cfg, data)
    on = torch.device(resolve_device(cfg.device) if device is None else device)
    record = run_record(cfg, data) if record is None else record
    n_windows = data.n * (data.steps - cfg.window + 1)
    check_memory(4 * n_windows * (cfg.window + 1) * data.images[0, 0].size * 3,
                 f"training windows of {cfg.window} steps", "use a smaller --window")
    norm = Normalizer.from_dict(record["normalizer"])
    model_cfg = from_json(ModelConfig, record["model"], "model")
    check_training_memory(model_cfg, cfg, data)
    if earlier is None and getattr(model_cfg.observation, "order_from_data", False):
        progress.note(f"--moment-order 0: choosing the order from the data ({cfg.order_epochs} "
                      "epochs at order 2 first)")
    model_cfg = settle_model(record, data, norm, cfg, on, earlier)
    built = new_model(model_cfg, cfg, on)
    regression = regression_init(cfg, built[0])  # (refuses settings it would ignore)
    threads = torch.get_num_threads()
    parts = threads if resolve_parallel(cfg, on.type, threads) == "batch" else 1
    if ready is not None:
        ready()

    def session(model, opt, gen, tensors) -> Session:
        return Session(cfg, model, opt, gen, tensors, data, norm, record, on, parts)

    if resumed:
        return session(*built, training_tensors(built[0], data, norm, cfg, on, fresh=False))
    shared: list[TrainingTensors] = []  # built once: the data are the same for every start

    def candidate(seed: int) -> Session:
        model, opt, gen = built if seed == cfg.seed else new_model(
            model_cfg, dataclasses.replace(cfg, seed=seed), on)
        if shared and shared[0].prime is not None:
            shared[0].prime(model)
        else:
            shared[:] = [training_tensors(model, data, norm, cfg, on, regression=regression)]
        return session(model, opt, gen, shared[0])

    return candidate(cfg.seed) if cfg.starts == 1 else _choose_start(cfg, candidate, progress)


@dataclass(frozen=True)
class Restarts:
    """The rule for fresh starts of a fit (the pendulum video's: RESULTS.md). A start whose
    main fit keeps weights that reconstruct the validation frames poorly (``val/recon`` above
    ``recon_above``) is followed by another (seed + 1000 r) before anything more is trained on
    it; of those waiting, the best reconstruction goes on to the phases. If then its last
    phase's kept validation latent term (``val/pred_z``: with ``relative_pred_z`` the
    fraction of the encoder's z^(k) the equations leave unexplained) is above ``fvu_above``,
    another start follows while ``count`` allows; of the starts trained through, the one
    with the smallest such term is kept. ``fvu_above`` is a fraction only when the last
    phase's latent term is scale-free. A figure that was not validated (data without a
    validation split) judges nothing; one that is not a number counts as poor."""

    count: int = 1
    """Fresh starts allowed after the first."""
    recon_above: float = 0.1
    fvu_above: float = math.inf
    agree: int = 1
    """Starts that must write the same law (the same active terms, whatever the latents'
    order) before one is trusted: with 2, starts are trained through until two agree (up to
    ``count``), and the kept start is the best of the largest group that agrees; a law of no
    term agrees with nothing. 1: the first start under the limits is trusted (the rule as it
    was before laws were compared)."""

    def __post_init__(self) -> None:
        if isinstance(self.count, bool) or not isinstance(self.count, int) or self.count < 0:
            raise UserError(f"restarts count {self.count!r}: use a whole number >= 0")
        if isinstance(self.agree, bool) or not isinstance(self.agree, int) or self.agree < 1:
            raise UserError(f"restarts agree {self.agree!r}: use a whole number >= 1")
        if not (self.recon_above >= 0 and self.fvu_above >= 0):
            raise UserError(f"restarts recon_above {self.recon_above}, fvu_above "
                            f"{self.fvu_above}: use numbers >= 0 (inf: never)")


def fit_in_memory(cfg: TrainConfig, data: SequenceData, progress: Progress | None = None,
                  phases: Sequence[Phase] = (), *, warmup: Sequence[Phase] = (),
                  restarts: Restarts | None = None,
                  begin: Callable[[Session], dict | None] | None = None,
                  finish: Callable[[Session], float | None] | None = None
                  ) -> tuple[Session, FitResult, list[dict]]:
    """Train ``cfg``'s model on ``data`` without a run folder: ``warmup`` phases, the fit to
    ``cfg.epochs`` (its epochs counting the warm-up's), then each of ``phases`` in turn, from
    the kept weights of the stretch before; with ``restarts``, fresh starts by its rule.
    Returns the session (its model holding the kept weights, on the CPU, in eval mode), the
    last fit's result (``kept["restarts"]``: starts trained and the one kept, with
    ``restarts``) and every epoch's metrics rows of the kept start. ``finish``, called on
    each start's session after its phases (its model holding the kept weights), may change
    the model (the recipe chooses the law again: :mod:`~latent_sindy.training.reselect`)
    and returns the validation share of z^(k) the law leaves unexplained, or None.
    ``begin``, called on each start's fresh session before anything is trained, may set its
    model's start (the recipe's: :mod:`~latent_sindy.training.manifold_start`); what it
    returns is kept as ``kept["start"]``."""
    if not all(isinstance(p, Phase) for p in (*phases, *warmup)):
        raise UserError("phases, warmup: give a sequence of latent_sindy.Phase")
    if restarts is not None and not isinstance(restarts, Restarts):
        raise UserError(f"restarts: give a latent_sindy.Restarts, got {type(restarts).__name__}")
    progress = progress or Silent()
    rule = restarts or Restarts(count=0)
    if warmup and sum(p.epochs for p in warmup) >= cfg.epochs:
        raise UserError(f"warm-up of {sum(p.epochs for p in warmup)} epochs leaves none of the "
                        f"fit's {cfg.epochs} (the warm-up counts toward them): give more "
                        "epochs or a shorter warm-up")

    def main(start: int) -> dict[str, Any]:
        seed = cfg.seed + 1000 * start
        session = prepare(cfg if start == 0 else dataclasses.replace(cfg, seed=seed), data,
                          progress=progress)
        if start:
            progress.close()
            progress.note(f"restart {start} of {rule.count} (seed {seed})")
        begun = begin(session) if begin is not None else None
        if begun is not None and begun.get("settled"):  # the start wrote the law: no fit
            return {"session": session, "result": _settled_result(session), "metrics": [],
                    "recon": None, "start": start, "begun": begun, "settled": True}
        progress.start(session.cfg.epochs + sum(p.epochs for p in phases), session.done)
        metrics: list[dict] = []
        for phase in warmup:
            metrics += session.fit(phase, on_epoch=progress.update).metrics
        if warmup:  # the main fit chooses among its own epochs, as a phase does
            result = session.fit(Phase(session.cfg.epochs - session.done, "main"),
                                 on_epoch=progress.update)
        else:
            result = session.fit(on_epoch=progress.update)
            if phases:  # the phases go on from the kept weights
                session.model.load_state_dict(result.state)
        return {"session": session, "result": result, "metrics": metrics + result.metrics,
                "recon": kept_value(result, "val/recon"), "start": start, "begun": begun}

    def finish_phases(c: dict[str, Any]) -> None:
        if c.get("settled"):
            c["fvu"] = max(c["begun"]["law_fvu"])
            c["law"] = law_key(c["session"].model.dynamics)
            c["result"].metrics[0]["val/pred_z"] = c["fvu"]
            return
        for phase in phases:
            c["result"] = c["session"].fit(phase, on_epoch=progress.update)
            c["metrics"] += c["result"].metrics
        c["fvu"] = kept_value(c["result"], "val/pred_z") if phases else 0.0
        c["session"].model.load_state_dict(c["result"].state)
        if finish is not None:
            share = finish(c["session"])
            if share is not None:
                c["fvu"] = share
                c["result"].state = to_cpu(c["session"].model.state_dict())
        c["law"] = law_key(c["session"].model.dynamics)

    def agreeing(c: dict[str, Any]) -> list[dict[str, Any]]:
        return [d for d in done if c["law"] and d["law"] == c["law"]]

    def poor(value: float | None, limit: float) -> bool:  # (not validated: cannot judge)
        return value is not None and not value <= limit  # (NaN: poor)

    def rank(value: float | None) -> float:
        return math.inf if value is None or math.isnan(value) else value

    waiting: list[dict[str, Any]] = []
    done: list[dict[str, Any]] = []
    try:
        for start in range(1 + rule.count):
            waiting.append(main(start))
            if poor(waiting[-1]["recon"], rule.recon_above) and start < rule.count:
                continue
            pick = min(waiting, key=lambda c: rank(c["recon"]))
            waiting.remove(pick)
            finish_phases(pick)
            done.append(pick)
            if not poor(pick["fvu"], rule.fvu_above) and (
                    rule.agree == 1 or len(agreeing(pick)) >= rule.agree):
                break
    finally:
        progress.close()
    groups = [agreeing(c) for c in done]
    largest = max((len(g) for g in groups), default=0)
    pool = [c for c, g in zip(done, groups, strict=True) if len(g) == largest] \
        if rule.agree > 1 and largest > 0 else done
    kept = min(pool, key=lambda c: rank(c["fvu"]))
    session, result = kept["session"], kept["result"]
    if restarts is not None:
        result.kept["restarts"] = {"starts": start + 1, "kept": kept["start"]}
        if rule.agree > 1:
            result.kept["restarts"]["laws"] = [
                {"start": c["start"], "law": [list(t) for t in c["law"]], "fvu": c["fvu"]}
                for c in done]
            result.kept["restarts"]["agreed"] = largest >= rule.agree
    if phases:
        result.kept["unexplained"] = kept["fvu"]
    if kept["begun"] is not None:
        result.kept["start"] = kept["begun"]
    session.finish(result).cpu().eval()
    return session, result, kept["metrics"]


def _settled_result(session: Session) -> FitResult:
    """The result of a start whose law was written before any training (the recipe's
    :func:`~latent_sindy.training.manifold_start.begin_session`): its weights as they are,
    one row of their validation figures at epoch 0."""
    row: dict[str, Any] = dict.fromkeys(METRIC_COLUMNS)
    row["epoch"] = 0
    cfg = session.cfg
    if session.tensors.val is not None and session.tensors.val.n:
        terms = evaluate(session.model, session.tensors.val, cfg.loss, cfg.batch_size)
        row.update({f"val/{k}": v for k, v in terms.items()})
    kept = {"epoch": 0, "selection": "the law found on the coordinates at the start",
            "val_objective": row.get("val/objective"), "candidates_from": None}
    return FitResult([row], to_cpu(session.model.state_dict()), kept, BestValidation())


#: Latent sizes up to this compare laws over every order of the latents (beyond, as given).
MAX_PERMUTED = 5


def law_key(dynamics: Any) -> tuple[tuple[str, ...], ...]:
    """What a sparse model's law is, whatever the order of its latents: per latent, its
    active terms' names (a product's factors sorted), the latents renumbered to the
    smallest such tuple over every order (z0 <-> z1 swapped reads the same law; up to
    :data:`MAX_PERMUTED` latents). Empty: no term (or not a sparse model)."""
    if not getattr(dynamics, "sparse", False) or dynamics.n_active() == 0:
        return ()
    mask = dynamics.mask.detach().cpu().numpy()  # (p, nz)
    names = dynamics.names
    nz = mask.shape[1]

    def renamed(name: str, order: tuple[int, ...]) -> str:
        # a product's factors in one order, whatever the renumbering made of them
        return " ".join(sorted(re.sub(r"\bz(\d+)", lambda m: f"z{order[int(m[1])]}", part)
                               for part in name.split(" ")))

    orders = itertools.permutations(range(nz)) if nz <= MAX_PERMUTED else [tuple(range(nz))]
    keys = []
    for order in orders:
        law: list[tuple[str, ...]] = [()] * nz
        for j in range(nz):
            law[order[j]] = tuple(sorted(renamed(names[i], order)
                                         for i in range(len(names)) if mask[i, j]))
        keys.append(tuple(law))
    return min(keys)


def kept_value(result: FitResult, key: str) -> float | None:
    """A validation figure (``val/recon``, ``val/pred_z``) at the epoch a fit kept (None if
    not validated there)."""
    epoch = result.kept["epoch"]
    for row in result.metrics:
        if row["epoch"] == epoch and row.get(key) is not None:
            return float(row[key])
    return None


def start_seed(seed: int, k: int) -> int:
    """The seed of candidate ``k`` of a run of ``seed``: the seed itself for the first (one
    start is the run it always was), independent streams for the others."""
    if k == 0:
        return seed
    return int(np.random.SeedSequence([seed, k]).generate_state(1)[0])


def _choose_start(cfg: TrainConfig, candidate: Callable[[int], Session],
                  progress: Progress) -> Session:
    """The candidate whose validation objective after ``cfg.start_epochs`` (a fifth of the
    epochs where None) is lowest (ties: the earlier), with its metrics and selection state."""
    probe = min(cfg.epochs, cfg.start_epochs or max(1, cfg.epochs // 5))
    chosen: Session | None = None
    diverged: TrainingDiverged | None = None
    seeds = []
    scores = []
    for k in range(cfg.starts):
        seed = start_seed(cfg.seed, k)
        start = candidate(seed)
        # (refinement begins at the same epoch as in the whole run, if within the probe)
        short = dataclasses.replace(cfg, seed=seed, epochs=probe, refine_epochs=max(
            0, cfg.refine_epochs - (cfg.epochs - probe)))
        try:
            result = start._fit(short, [], BestValidation(), None)
        except TrainingDiverged as e:
            diverged = e
            seeds.append(seed)
            scores.append(math.inf)
            progress.note(f"start {k + 1} of {cfg.starts} (seed {seed}) diverged: {e}")
            continue
        last = result.metrics[-1]
        score = last.get("val/objective")  # (with a pose head's reading, as the kept weights)
        if score is not None:
            score += cfg.loss.lambda_pose * (last.get("val/pose") or 0.0)
        else:  # no validation split: the training objective
            score = last.get("train/objective", last.get("train/total"))
        score = float(score) if score is not None and math.isfinite(score) else math.inf
        seeds.append(seed)
        scores.append(score)
        progress.note(f"start {k + 1} of {cfg.starts} (seed {seed}): objective {score:.4g} "
                      f"after {probe} epochs")
        if chosen is None or score < min(scores[:-1]):
            start.done = probe
            start.metrics = result.metrics
            start.best = result.best
            chosen = start
    if chosen is None:  # every candidate diverged
        raise diverged
    k = scores.index(min(scores))
    chosen.info = {"starts": cfg.starts, "epochs": probe, "chosen": k, "seeds": seeds,
                   "objectives": [s if math.isfinite(s) else None for s in scores]}
    return chosen
