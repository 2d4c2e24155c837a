"""Where training starts: a fresh model, its optimiser, generator and tensors; with several
starts, the one of lowest validation objective after a short probe.

An autoencoder and its sparse dynamics find a good model from some initialisations and not
from others (the paper kept the best of ten runs). ``TrainConfig.starts`` candidates, seeded
from ``--seed``, each train ``start_epochs``; the best continues to ``--epochs`` as if it had
been the only one (its metrics from epoch 1, its optimiser and batches as they were).

    start = first_start(model_cfg, cfg, device, data, norm, regression, parts, progress)
    result = start.fit(cfg, parts, on_epoch)   # from epoch start.done + 1
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from latent_sindy.data import SequenceData
from latent_sindy.data.windows import Normalizer
from latent_sindy.models.latent_model import LatentModel
from latent_sindy.progress import Progress
from latent_sindy.training.config import TrainConfig, resolve_device, resolve_parallel
from latent_sindy.training.core import BestValidation, FitResult, TrainingDiverged, fit
from latent_sindy.training.memory import check_training_memory
from latent_sindy.training.prepare import (
    TrainingTensors,
    fit_after,
    new_model,
    regression_init,
    settle_model,
    training_tensors,
)
from latent_sindy.training.record import resolve_model, run_record

__all__ = ["Start", "first_start", "start_seed", "train_in_memory"]


@dataclass
class Start:
    """A model ready to train from epoch ``done`` + 1, and how it was chosen (``info``:
    None for a single start)."""

    model: LatentModel
    opt: torch.optim.Optimizer
    gen: torch.Generator
    tensors: TrainingTensors
    done: int = 0
    metrics: list[dict[str, Any]] = field(default_factory=list)
    best: BestValidation = field(default_factory=BestValidation)
    info: dict[str, Any] | None = None

    def fit(self, cfg: TrainConfig, parts: int = 1,
            on_epoch: Callable[[int, dict[str, Any]], None] | None = None) -> FitResult:
        """Train from epoch ``done`` + 1 to ``cfg.epochs``
        (:func:`~latent_sindy.training.core.fit`); the kept weights' record says how the
        start was chosen (``"start"``) where there were several."""
        result = fit(self.model, self.opt, self.gen, self.tensors.train, self.tensors.val,
                     cfg, per_batch=self.tensors.per_batch, parts=parts, done=self.done,
                     metrics=self.metrics, best=self.best, on_epoch=on_epoch)
        if self.info is not None:
            result.kept["start"] = self.info
        return result


def start_seed(seed: int, k: int) -> int:
    """The seed of candidate ``k`` of a run of ``seed``: the seed itself for the first (one
    start is the run it always was), independent streams for the others."""
    if k == 0:
        return seed
    return int(np.random.SeedSequence([seed, k]).generate_state(1)[0])


def first_start(model_cfg: Any, cfg: TrainConfig, device: torch.device, data: SequenceData,
                norm: Normalizer, regression: bool, parts: int, progress: Progress,
                first: tuple[LatentModel, torch.optim.Optimizer, torch.Generator] | None = None
                ) -> Start:
    """The model a fresh run trains: seeded by ``cfg.seed`` where ``cfg.starts`` is 1, else
    the candidate whose validation objective after ``cfg.start_epochs`` is lowest (ties: the
    earlier), with its metrics, selection state and optimiser. ``first``: the seed's model,
    optimiser and generator where the caller has built them (:func:`new_model`)."""
    shared: list[TrainingTensors] = []  # built once: the data are the same for every start

    def candidate(seed: int) -> Start:
        run_cfg = dataclasses.replace(cfg, seed=seed)
        if seed == cfg.seed and first is not None:
            model, opt, gen = first
        else:
            model, opt, gen = new_model(model_cfg, run_cfg, device)
        if shared and shared[0].prime is not None:
            shared[0].prime(model)
        else:
            shared[:] = [training_tensors(model, data, norm, run_cfg, device,
                                          regression=regression)]
        return Start(model, opt, gen, shared[0])

    if cfg.starts == 1:
        return candidate(cfg.seed)
    probe = min(cfg.epochs, cfg.start_epochs or max(1, cfg.epochs // 5))
    chosen: Start | None = None
    diverged: TrainingDiverged | None = None
    seeds, scores = [], []
    for k in range(cfg.starts):
        seed = start_seed(cfg.seed, k)
        start = candidate(seed)
        # (refinement begins at the same epoch as in the whole run, if within the probe)
        short = dataclasses.replace(cfg, seed=seed, epochs=probe, refine_epochs=max(
            0, cfg.refine_epochs - (cfg.epochs - probe)))
        try:
            result = fit(start.model, start.opt, start.gen, start.tensors.train,
                         start.tensors.val, short, per_batch=start.tensors.per_batch,
                         parts=parts)
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
            start.done, start.metrics, start.best = probe, result.metrics, result.best
            chosen = start
    if chosen is None:  # every candidate diverged
        raise diverged
    k = scores.index(min(scores))
    chosen.info = {"starts": cfg.starts, "epochs": probe, "chosen": k, "seeds": seeds,
                   "objectives": [s if math.isfinite(s) else None for s in scores]}
    return chosen


def train_in_memory(cfg: TrainConfig, data: SequenceData, progress: Progress
                    ) -> tuple[LatentModel, Normalizer, dict[str, Any], FitResult]:
    """Train ``cfg``'s model on ``data`` without a run folder (``cfg.batch_size`` settled):
    the trained model (the kept weights, on the CPU), its normaliser, the record a run folder
    would hold, and the fit's result."""
    check_training_memory(resolve_model(cfg.model, data, data.source), cfg, data)
    record = run_record(cfg, data)
    device = torch.device(resolve_device(cfg.device))
    norm = Normalizer.from_dict(record["normalizer"])
    model_cfg = settle_model(record, data, norm, cfg, device)
    built = new_model(model_cfg, cfg, device)
    regression = regression_init(cfg, built[0])
    threads = torch.get_num_threads()
    parts = threads if resolve_parallel(cfg, device.type, threads) == "batch" else 1
    start = first_start(model_cfg, cfg, device, data, norm, regression, parts, progress, built)
    progress.start(cfg.epochs, start.done)
    try:
        result = start.fit(cfg, parts, lambda e, row: progress.update(e, row))
    finally:
        progress.close()
    model = start.model
    model.load_state_dict(result.state)
    if cfg.sindy_fit == "after":
        fit_after(model, data, norm, cfg, device)
    return model.cpu().eval(), norm, record, result
