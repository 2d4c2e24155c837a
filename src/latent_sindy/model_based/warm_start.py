"""Warm-started refits for the model-based loop (:mod:`.online`): the first iteration
fits from scratch; every later one continues from the last iteration's model and AdamW
optimiser for a fixed budget of updates on all the data so far, instead of fitting anew.

What a continued fit keeps and what it changes:

* the normaliser and the resolved model of the first fit (its record): the pixels the
  model was trained on keep their meaning, and the data statistics held in the weights
  (an encoder's background, say) come with the weights;
* the weights and the optimiser's state (moments, step counts) of the last iteration's
  end; the kept weights are the best on the validation split among the fit's own epochs
  (as a :class:`~latent_sindy.training.Phase` keeps its own), and the next fit continues
  from them;
* the mini-batch generator is seeded from the estimator's seed of the iteration, and a
  SINDy mask prunes on its own schedule counted within each fit;
* the budget: ``updates`` mini-batch updates. Where the data so far hold more than that
  many batches, the refit is one pass over ``updates`` batches of windows drawn at random
  (without replacement) from all of them, so a refit's cost does not grow with the data;
  otherwise whole epochs, rounded up;
* pruning across refits (``prune_rate`` > 0, SINDy only): before its updates each refit
  drops the coefficients below the fit's ``--prune-below`` (as ``--prune`` measures them) and then
  the smallest ``prune_rate`` of the active ones by the same measure, never below
  ``prune_to``; the refit's updates then adapt the others to the new mask (AdamW's moments
  of the pruned entries cleared).

:class:`WarmState` is all a continued fit needs; :func:`save_state` / :func:`load_state`
write it beside the loop's log and read it back with ``torch.load(weights_only=True)``, so a
resumed loop continues exactly as an uninterrupted one. Works with
:class:`latent_sindy.LatentSINDy` (any estimator with its ``train_config``).

    est, state = first_fit(make(1), data, {"epochs": 60})
    est, state = warm_fit(make(2), more_data, {"epochs": 60}, state, updates=100,
                          prune_rate=0.3, prune_to=48)
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from latent_sindy.atomic import write_atomic
from latent_sindy.data import SequenceData
from latent_sindy.errors import UserError
from latent_sindy.training.config import resolve_prune
from latent_sindy.training.fit_loop import FitResult, prune, share_scale, to_cpu
from latent_sindy.training.session import Session, fit_in_memory, prepare

__all__ = ["STATE_FORMAT", "WarmState", "first_fit", "load_state", "save_state", "warm_fit"]

STATE_FORMAT = "latent-sindy-warm-state"


@dataclass
class WarmState:
    """The end of one iteration's fit: kept weights, optimiser state, the first fit's record
    (its normaliser and resolved model), and the epochs and updates that fit trained."""

    model: dict[str, torch.Tensor]
    optimizer: dict[str, Any]
    record: dict[str, Any]
    epochs: int
    updates: int
    pruned: int = 0
    """SINDy terms the fit's own prune step removed before its updates (not saved)."""
    batch_size: int = 0
    """The fit's batch size, in windows (its ``batch_size``, resolved; not saved)."""


def _adopt(estimator: Any, session: Session, result: FitResult, metrics: list[dict]) -> Any:
    """``estimator`` holding the session's model as its own fit would (the attributes
    :meth:`latent_sindy.LatentSINDy.fit` sets)."""
    estimator.model_ = session.model
    estimator.normalizer_ = session.norm
    estimator.description_ = session.record["description"]
    estimator.world_record_ = session.record["world"]["record"]
    estimator.record_ = {**session.record, "kept": result.kept}
    estimator.metrics_ = metrics
    estimator.kept_ = result.kept
    return estimator


def _state(session: Session, epochs: int, updates: int, pruned: int = 0) -> WarmState:
    # (copies: the state dicts' tensors are the live model's and optimiser's)
    return WarmState(copy.deepcopy(to_cpu(session.model.state_dict())),
                     copy.deepcopy(to_cpu(session.opt.state_dict())),
                     json.loads(json.dumps(session.record)), epochs, updates, pruned,
                     session.cfg.batch_size)


def _updates_per_epoch(session: Session) -> int:
    return max(1, math.ceil(session.tensors.train.n / session.tensors.per_batch))


def first_fit(estimator: Any, data: SequenceData, settings: dict[str, Any]
              ) -> tuple[Any, WarmState]:
    """``estimator`` fitted from scratch on ``data`` (as ``estimator.fit(data, **settings)``
    in memory), and the state a continued fit starts from."""
    session, result, metrics = fit_in_memory(estimator.train_config(**settings), data)
    epochs = session.cfg.epochs
    return (_adopt(estimator, session, result, metrics),
            _state(session, epochs, epochs * _updates_per_epoch(session)))


def warm_fit(estimator: Any, data: SequenceData, settings: dict[str, Any], state: WarmState,
             updates: int, prune_rate: float = 0.0, prune_to: int = 0
             ) -> tuple[Any, WarmState]:
    """``estimator`` holding ``state``'s model trained on for ``updates`` more mini-batch
    updates with its optimiser, normaliser and model settings (one pass over a random sample
    of ``updates`` batches of ``data``'s windows where it holds more, else whole epochs);
    a SINDy model first pruned (``prune_rate``, ``prune_to``: the module's docstring). The
    estimator's own settings give the batches (seed, batch size, window, loss)."""
    if updates < 1:
        raise UserError(f"warm-started refit of {updates} updates: use 1 or more")
    if not 0 <= prune_rate < 1:
        raise UserError(f"warm-started refit's prune_rate {prune_rate!r}: use a share in "
                        "[0, 1) (0: no pruning between refits)")
    cfg = estimator.train_config(**settings)
    record = json.loads(json.dumps(state.record))
    session = prepare(cfg, data, record=record, earlier=record, resumed=True)
    session.model.load_state_dict(state.model)
    session.opt.load_state_dict(state.optimizer)
    train = session.tensors.train
    per_batch = session.tensors.per_batch
    if _updates_per_epoch(session) > updates:  # the budget, whatever the data so far
        take = torch.randperm(train.n, generator=session.gen)[:updates * per_batch]
        take = take.sort().values.to(train.device)
        session.tensors = dataclasses.replace(session.tensors, train=train.pick(take))
    pruned = _prune_step(session, prune_rate, prune_to) if prune_rate else 0
    epochs = math.ceil(updates / _updates_per_epoch(session))
    session.cfg = dataclasses.replace(session.cfg, epochs=epochs,
                                      refine_epochs=min(session.cfg.refine_epochs, epochs))
    for group in session.opt.param_groups:
        group["lr"] = session.cfg.lr
    result = session.fit()
    session.finish(result).cpu().eval()
    return (_adopt(estimator, session, result, list(result.metrics)),
            _state(session, epochs, epochs * _updates_per_epoch(session), pruned))


def _prune_step(session: Session, rate: float, floor: int) -> int:
    """Prune the session's SINDy model below its ``prune_below``, then its smallest ``rate`` of
    active terms (never below ``floor``), measured on its training windows; the count."""
    model = session.model
    if not model.dynamics.sparse:
        return 0
    with torch.no_grad():  # (relative: sequences; continuous time prunes |Ξ|)
        scale = (share_scale(model, session.tensors.train.x, session.tensors.train.u)
                 if resolve_prune(session.cfg) == "relative" else None)
    pruned = prune(model, session.opt, session.cfg.prune_below, scale)
    dyn = model.dynamics
    active = dyn.n_active()
    keep = max(floor, math.ceil(active * (1 - rate)))
    if active > keep:
        size = dyn.psi.detach().abs() * (1.0 if scale is None else scale)
        smallest_kept = size[dyn.mask].sort(descending=True).values[keep - 1]
        pruned += prune(model, session.opt, float(smallest_kept), scale)
    return pruned


def save_state(path: Path, state: WarmState, iteration: int) -> None:
    """``state`` (of iteration ``iteration``) into ``path``, atomically."""
    payload = {"format": STATE_FORMAT, "iteration": iteration, "model": state.model,
               "optimizer": state.optimizer, "record": json.dumps(state.record),
               "epochs": state.epochs, "updates": state.updates}
    write_atomic(path, lambda f: torch.save(payload, f))


def load_state(path: Path, iteration: int) -> WarmState:
    """The state :func:`save_state` wrote for ``iteration`` (weights only: no code runs)."""
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
        if obj.get("format") != STATE_FORMAT or obj.get("iteration") != iteration:
            raise ValueError(f"not the warm state of iteration {iteration}")
        return WarmState(obj["model"], obj["optimizer"], json.loads(obj["record"]),
                         int(obj["epochs"]), int(obj["updates"]))
    except (OSError, RuntimeError, EOFError, ValueError, KeyError, AttributeError,
            pickle.UnpicklingError) as e:
        raise UserError(f"{path} is missing or damaged ({e}): the loop cannot continue its "
                        f"warm-started fits; delete {path.parent} to start again") from e
