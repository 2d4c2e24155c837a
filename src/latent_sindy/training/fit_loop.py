"""The fit loop: one gradient loop over a latent model, its pruning and model selection.

:func:`fit` is the loop, readable on one screen: every epoch one shuffled pass of AdamW over
the training sequences, every ``prune_every`` epochs the SINDy coefficients with
|Ψ| < ``prune_below`` pruned for good (the optimiser's moments of pruned entries cleared), in
the last ``refine_epochs`` neither pruning nor the L1 term (a refinement on the fixed mask), the
validation loss every ``eval_every`` epochs, and the weights of the best validated epoch since
the last pruning that removed a term kept (:class:`BestValidation`). It works in memory;
every training reaches it through a :class:`~latent_sindy.training.session.Session`, and the
run folder (checkpoints, resume, metrics file, progress) wraps it through ``on_epoch``
(:mod:`latent_sindy.training.train_run`).

    result = fit(model, opt, gen, Sequences(x, u), Sequences(xv, uv), settings)
    model.load_state_dict(result.state)
"""

from __future__ import annotations

import ctypes
import dataclasses
import functools
import math
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import torch

from latent_sindy.errors import UserError
from latent_sindy.models.latent_model import LOSS_TERMS, LatentModel, LossWeights
from latent_sindy.training.config import TrainConfig, resolve_prune
from latent_sindy.training.metrics import METRIC_COLUMNS
from latent_sindy.training.samples import DerivativeSamples, Samples, Sequences

__all__ = ["BestValidation", "DerivativeSamples", "FitResult", "Gradients", "Sequences",
           "TrainingDiverged", "evaluate", "fit", "keep_freed_memory", "prune", "share_scale",
           "to_cpu"]


class TrainingDiverged(UserError):
    """A loss term or a parameter became NaN or infinite (``epoch``, ``what``)."""

    def __init__(self, epoch: int, what: str, message: str | None = None) -> None:
        super().__init__(message or f"training diverged at epoch {epoch}: {what} is not "
                         "finite; lower the learning rate and start over")
        self.epoch = epoch
        self.what = what

    def __reduce__(self):  # crosses process boundaries (the study's workers) whole
        return type(self), (self.epoch, self.what, str(self))


@dataclass
class FitResult:
    """What :func:`fit` returns: the per-epoch metrics rows, the kept weights and why."""

    metrics: list[dict[str, Any]]
    state: dict[str, torch.Tensor]
    kept: dict[str, Any]
    best: BestValidation = field(repr=False)


def fit(model: LatentModel, opt: torch.optim.Optimizer, gen: torch.Generator,
        train: Samples, val: Samples | None,
        cfg: TrainConfig, *, per_batch: int, parts: int = 1, done: int = 0,
        metrics: list[dict[str, Any]] | None = None, best: BestValidation | None = None,
        on_epoch: Callable[[int, dict[str, Any]], None] | None = None) -> FitResult:
    """Train ``model`` from epoch ``done`` + 1 to ``cfg.epochs`` (``metrics`` and ``best``:
    a resumed run's); ``per_batch`` samples per mini-batch, gradients split over ``parts``
    threads; ``on_epoch(epoch, row)`` after every epoch (checkpoints, progress), once the row
    is appended to ``metrics`` (the list given is extended in place)."""
    metrics = [] if metrics is None else metrics
    best = best or BestValidation()
    sparse = model.dynamics.sparse
    pruning = sparse and cfg.prune_every > 0
    relative = pruning and resolve_prune(cfg) == "relative"
    refine_after = cfg.epochs - cfg.refine_epochs  # the epochs after this one refine
    refining = dataclasses.replace(cfg.loss, lambda_l1=0.0)
    grads = Gradients(model, parts)
    model.train()
    try:
        for epoch in range(done + 1, cfg.epochs + 1):
            t0 = time.perf_counter()
            row: dict[str, Any] = dict.fromkeys(METRIC_COLUMNS)
            row["epoch"] = epoch
            refine = epoch > refine_after
            terms = train_epoch(grads, opt, train, cfg, per_batch, gen, epoch,
                                weights=refining if refine else None)
            row.update({f"train/{k}": v for k, v in terms.items()})
            if pruning and not refine and epoch % cfg.prune_every == 0:
                scale = share_scale(model, train.x, train.u) if relative else None
                row["sindy/pruned"] = prune(model, opt, cfg.prune_below, scale)
                if row["sindy/pruned"]:
                    best.mask_changed(epoch)
            if val is not None and (epoch % cfg.eval_every == 0 or epoch == cfg.epochs):
                val_terms = evaluate(model, val, cfg.loss, cfg.batch_size)
                if not math.isfinite(val_terms["total"]):
                    raise TrainingDiverged(epoch, "the validation loss")
                row.update({f"val/{k}": v for k, v in val_terms.items()})
                # A pose head's reading, or a reward head's, is what its model plans on: it
                # counts in the choice (0 without a head).
                best.offer(epoch, val_terms["objective"]
                           + cfg.loss.lambda_pose * val_terms.get("pose", 0.0)
                           + cfg.loss.lambda_reward * val_terms.get("reward", 0.0), model)
            if sparse:
                row["sindy/active"] = model.dynamics.n_active()
                row["sindy/sparsity"] = model.dynamics.sparsity()
            row["time_s"] = time.perf_counter() - t0
            metrics.append(row)
            if on_epoch is not None:
                on_epoch(epoch, row)
    finally:
        grads.close()
    kept = kept_weights(cfg, best, metrics)
    state = best.state if kept["selection"] == "best validation" else model.state_dict()
    return FitResult(metrics, state, kept, best)


@torch.inference_mode()
def evaluate(model: LatentModel, samples: Samples,
             weights: LossWeights | None = None, batch_size: int = 500) -> dict[str, float]:
    """Mean loss terms over ``samples``, in batches (on the device of the model and the
    samples): windows (:class:`Sequences`, whole: no window is cut; with the true poses for
    a pose head's term) or a continuous-time model's :class:`DerivativeSamples` (or
    :class:`CoordinateSamples`)."""
    was_training = model.training
    model.eval()
    sums = torch.zeros(len(LOSS_TERMS), dtype=torch.float64)
    for b in range(0, samples.n, batch_size):
        batch = samples.pick(slice(b, b + batch_size))
        terms = batch.loss(model, weights, None)
        values = torch.stack([terms[k] for k in LOSS_TERMS]).double().cpu()
        sums += values * batch.n
    model.train(was_training)
    return dict(zip(LOSS_TERMS, (sums / max(samples.n, 1)).tolist(), strict=True))


class Gradients:
    """Loss terms and gradients of one mini-batch, on one thread or split across several.

    With ``parts`` > 1 the batch is cut into that many slices whose losses and gradients
    that many threads compute at once, each with one torch thread (torch's own threads are
    set to 1 until :meth:`close`), and the gradients are added in slice order; the loss terms
    are means, so each slice counts by its share of the samples. Deterministic: every
    slice runs single-threaded and the sums have a fixed order. With ``parts`` = 1 it is one
    ``loss(...).backward()``.
    """

    def __init__(self, model: LatentModel, parts: int) -> None:
        self.model = model
        self.parts = parts
        self.params = [p for p in model.parameters() if p.requires_grad]
        self._pool: ThreadPoolExecutor | None = None
        self._threads = torch.get_num_threads()
        if parts > 1:
            self._pool = ThreadPoolExecutor(parts, thread_name_prefix="latent-sindy-grad")
            torch.set_num_threads(1)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
            torch.set_num_threads(self._threads)

    def __call__(self, batch: Samples, weights: LossWeights,
                 window: int | None) -> dict[str, torch.Tensor]:
        """Set every parameter's ``.grad`` to d total / d parameter on the ``batch``
        (sequences cut into windows of ``window`` actions, or derivative samples, which take
        none); returns the loss terms (detached)."""
        n = batch.n
        if self._pool is None or n < 2:
            terms = batch.loss(self.model, weights, window)
            for p in self.params:
                p.grad = None
            terms["total"].backward()
            return {k: v.detach() for k, v in terms.items()}
        bounds = torch.linspace(0, n, min(self.parts, n) + 1).round().long().tolist()

        def part(a: int, b: int) -> tuple[dict[str, torch.Tensor], tuple]:
            share = (b - a) / n
            terms = batch.pick(slice(a, b)).loss(self.model, weights, window)
            g = torch.autograd.grad(terms["total"] * share, self.params, allow_unused=True)
            return {k: v.detach() * share for k, v in terms.items()}, g

        results = list(self._pool.map(part, bounds[:-1], bounds[1:]))
        terms = {k: functools.reduce(torch.add, [r[0][k] for r in results])
                 for k in results[0][0]}
        for i, p in enumerate(self.params):
            gs = [r[1][i] for r in results if r[1][i] is not None]
            p.grad = None if not gs else functools.reduce(torch.add, gs)
        return terms


def train_epoch(grads: Gradients, opt: torch.optim.Optimizer,
                samples: Samples, cfg: TrainConfig, per_batch: int,
                gen: torch.Generator, epoch: int, weights: LossWeights | None = None
                ) -> dict[str, float]:
    """One shuffled pass over the training ``samples`` (sequences: windows or whole
    trajectories, with their true states for a pose or reward head; or a continuous-time
    model's derivative samples), ``per_batch`` of them per batch; mean loss terms per sample
    (as seen before each batch's update). ``weights``: the loss's (default ``cfg.loss``)."""
    weights = weights or cfg.loss
    # The generator lives on the CPU: the same mini-batches on every device.
    order = torch.randperm(samples.n, generator=gen).to(samples.device)
    sums = torch.zeros(len(LOSS_TERMS), dtype=torch.float64)
    for b in range(0, samples.n, per_batch):
        idx = order[b : b + per_batch]
        terms = grads(samples.pick(idx), weights, cfg.window)
        values = torch.stack([terms[k] for k in LOSS_TERMS])  # (8,)
        if not torch.isfinite(values).all():
            bad = next(k for k in ("recon", "pred_x", "pred_z", "l1", "pose", "reward", "total")
                       if not torch.isfinite(terms[k]))
            raise TrainingDiverged(epoch, f"loss term {bad} ({float(terms[bad])})")
        opt.step()
        sums += values.double().cpu() * len(idx)
    for name, p in grads.model.named_parameters():
        if not torch.isfinite(p).all():
            raise TrainingDiverged(epoch, f"parameter {name}")
    return dict(zip(LOSS_TERMS, (sums / samples.n).tolist(), strict=True))


#: Frames encoded at once where a whole split is encoded (bounds the encoder's activations).
ENCODE_CHUNK = 2048
#: Sequences whose encoded transitions measure the terms' shares for a relative pruning.
SHARE_SEQUENCES = 256


@torch.no_grad()
def share_scale(model: LatentModel, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Weights (p, nz) that turn |Ψ| into each term's share of its state's update:
    rms(Θ_k) / rms((Θ (M ⊙ Ψ))_j), the root mean square of the term's column over that of
    the whole update, on the encoded transitions of up to :data:`SHARE_SEQUENCES` of the
    training sequences x (N, L, ...), u (N, L-1, nu), evenly spaced (no randomness drawn).
    ``prune(model, opt, tau, scale)`` then drops the terms that move their state by less
    than ``tau`` of its update, whatever the scales of z, u or the library's columns (1
    where an update is 0 everywhere)."""
    pick = torch.linspace(0, len(x) - 1, min(len(x), SHARE_SEQUENCES)).round().long()
    xs, us = x[pick.to(x.device)], u[pick.to(u.device)]
    frames = xs.flatten(0, 1)
    z = torch.cat([model.encode(frames[i:i + ENCODE_CHUNK])
                   for i in range(0, len(frames), ENCODE_CHUNK)]).reshape(*xs.shape[:2], -1)
    dyn = model.dynamics
    theta = dyn.library(z[:, :-1].flatten(0, 1), us.flatten(0, 1))  # (M, p)
    column = theta.square().mean(0).sqrt()  # (p,)
    update = (theta @ dyn.coefficients()).square().mean(0).sqrt()  # (nz,)
    update = torch.where(update > 0, update, torch.ones_like(update))
    return column[:, None] / update[None, :]


@torch.no_grad()
def prune(model: LatentModel, opt: torch.optim.Optimizer, tau: float,
          scale: torch.Tensor | None = None) -> int:
    """Prune SINDy coefficients (|Ψ| < tau, or |Ψ| · ``scale`` < tau: see
    :func:`share_scale`); clear AdamW's moments of pruned entries so Ψ stays 0."""
    dyn = model.dynamics
    pruned = dyn.prune(tau, scale)
    state = opt.state.get(dyn.psi, {})
    for key in ("exp_avg", "exp_avg_sq"):
        if key in state:
            state[key].masked_fill_(~dyn.mask, 0.0)
    return pruned


class BestValidation:
    """The weights of the validated epoch with the lowest validation objective among the
    candidates: the epochs since the last SINDy pruning step that removed a term (pruning
    that removes nothing leaves the mask as it was), so the kept model's mask is the final
    one. Linear and MLP models never prune: every validated epoch is a candidate.

    The weights are a copy of the state dict (on the model's device), taken when a new best
    is seen; :meth:`to_checkpoint` / :meth:`from_checkpoint` carry it through a resume.
    """

    def __init__(self) -> None:
        self.epoch: int | None = None
        self.objective = math.inf
        self.state: dict[str, torch.Tensor] | None = None
        self.since = 1  # the first candidate epoch (after the last mask change)

    def mask_changed(self, epoch: int) -> None:
        """A pruning at ``epoch`` removed terms: earlier epochs have another mask."""
        self.epoch = None
        self.objective = math.inf
        self.state = None
        self.since = epoch

    def offer(self, epoch: int, objective: float, model: torch.nn.Module) -> bool:
        """Keep ``model``'s weights if ``objective`` is the lowest so far (ties: the earlier)."""
        if objective >= self.objective:
            return False
        self.epoch = epoch
        self.objective = objective
        self.state = {k: v.detach().clone() for k, v in model.state_dict().items()}
        return True

    def to_checkpoint(self) -> dict[str, Any]:
        return {"epoch": self.epoch, "objective": self.objective, "since": self.since,
                "model": None if self.state is None else to_cpu(self.state)}

    @classmethod
    def from_checkpoint(cls, saved: dict[str, Any] | None, device: torch.device,
                        resumed_at: int) -> BestValidation:
        """Rebuilt from :meth:`to_checkpoint`; ``saved`` None (a checkpoint written before
        selection existed): candidates start after ``resumed_at``."""
        best = cls()
        if saved is None:
            best.since = resumed_at + 1
            return best
        best.epoch = saved["epoch"]
        best.objective = saved["objective"]
        best.since = saved["since"]
        if saved["model"] is not None:
            best.state = {k: v.to(device) for k, v in saved["model"].items()}
        return best


_MEMORY_KEPT = False


def keep_freed_memory() -> None:
    """Let glibc's malloc keep freed blocks of up to 32 MiB for reuse (process-wide, once).

    By default it returns the ~80 MB of activations a step frees to the OS and page-faults
    them back in at the next step: 40-57 k faults and 80-120 ms of kernel time per epoch at
    the paper's sizes; keeping them made epochs 1.39x faster (BENCHMARKS.md). Allocation never
    changes the arithmetic (torch aligns every buffer to 64 bytes either way; checked bit for
    bit at 1 and 2 threads). A no-op where libc is not glibc.
    """
    global _MEMORY_KEPT
    if _MEMORY_KEPT:
        return
    _MEMORY_KEPT = True
    try:
        libc = ctypes.CDLL("libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return
    m_trim_threshold, m_mmap_threshold = -1, -3  # <malloc.h>
    mallopt(m_mmap_threshold, 32 * 2**20)  # glibc's largest: the activations fit below it
    mallopt(m_trim_threshold, 2**30)


def to_cpu(obj: Any) -> Any:
    """A state dict (nested dicts and lists of tensors) with every tensor on the CPU, so that
    run files load anywhere."""
    if isinstance(obj, torch.Tensor):
        return obj.cpu()
    if isinstance(obj, dict):
        return {k: to_cpu(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return type(obj)(to_cpu(v) for v in obj)
    return obj


def kept_weights(cfg: TrainConfig, best: BestValidation, metrics: list[dict[str, Any]]
          ) -> dict[str, Any]:
    """Which epoch's weights the run saves as its model, for config.json's "kept"."""
    last = metrics[-1] if metrics else {}
    if cfg.keep_best and best.state is not None:
        return {"epoch": best.epoch, "selection": "best validation",
                "val_objective": best.objective, "candidates_from": best.since}
    return {"epoch": cfg.epochs, "selection": "last epoch",
            "val_objective": last.get("val/objective"), "candidates_from": None}


