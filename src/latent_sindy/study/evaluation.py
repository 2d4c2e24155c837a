"""Measurements of one trained run on the same footing as every other, and their aggregation.

Every model, whatever its dynamics, is judged on the same normalised images:

* ``split_losses``: the objective without the L1 term (recon + λ1 pred_x + λ2 pred_z, see
  :mod:`latent_sindy.models.latent_model`) on the single-step (H = 1) windows of each split,
  so a multi-step-trained model is scored like the others;
* ``horizon_errors``: image MSE of dec(rollout) against the true images, h = 1..T steps after
  every start of every test trajectory (open loop, normalised pixels);
* ``baseline_errors``: the same for two predictors that learn nothing, for scale: "nothing
  moves" (x̂_{t+h} = x_t) and "mean image" (the training split's mean image at every h);
* ``model_stats``: active coefficients and sparsity (SINDy), coefficient / parameter counts;
* ``aggregate``: mean ± std over seeds of flat metric dictionaries.

    from latent_sindy.study.evaluation import horizon_errors, split_losses
    run = load_run("results/runs/seed0/sindy2")
    losses = split_losses(run.model, read_sequences("results/data.h5"), run.normalizer)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from latent_sindy.data import SPLITS, SequenceData
from latent_sindy.data.windows import OBSERVATIONS, Normalizer, WindowDataset
from latent_sindy.models.latent_model import LatentModel, LossWeights
from latent_sindy.training import Sequences, evaluate

__all__ = ["BASELINES", "Stat", "aggregate", "baseline_errors", "horizon_errors", "mean_std",
           "model_stats", "rollouts", "split_losses"]

#: Model-free predictors of :func:`baseline_errors`, by name: their labels.
BASELINES = {"still": "nothing moves", "mean_image": "mean training image"}


def split_losses(model: LatentModel, data: SequenceData, normalizer: Normalizer,
                 weights: LossWeights | None = None) -> dict[str, dict[str, float]]:
    """Loss terms (``objective``, ``recon``, ``pred_x``, ``pred_z``) per split, H = 1 windows."""
    out = {}
    for split in SPLITS:
        part = data.split(split)
        if part.n == 0:
            continue
        windows = WindowDataset(part, 1, normalizer, model.config.observation.kind)
        terms = evaluate(model, Sequences(*windows.tensors()), weights)
        out[split] = {k: terms[k] for k in ("objective", "recon", "pred_x", "pred_z")}
    return out


def _by_horizon(x: torch.Tensor, predict: Callable[[int], torch.Tensor]) -> list[float]:
    """Mean squared error at horizon h = 1..T (index h-1) over all starts t with t + h <= T.

    x (N, T+1, ...) true observations (images, or encoded states); ``predict(t)`` gives the
    predictions of x[:, t+1:]. NaN (a diverged rollout) becomes inf.
    """
    steps = x.shape[1] - 1
    dims = (0, *range(2, x.ndim))  # everything but the horizon
    sums, counts = np.zeros(steps), np.zeros(steps)
    for t in range(steps):
        err = (predict(t) - x[:, t + 1:]).square().mean(dim=dims)  # (T-t,)
        sums[: steps - t] += err.double().numpy() * len(x)
        counts[: steps - t] += len(x)
    err = sums / np.maximum(counts, 1)
    return np.where(np.isnan(err), np.inf, err).tolist()


@torch.no_grad()
def rollouts(model: LatentModel, data: SequenceData, normalizer: Normalizer
             ) -> list[torch.Tensor]:
    """The model's open-loop predictions from every start t = 0..T-1 with the true actions:
    item t is (N, T-t+1, ...), its first frame dec(enc(x_t)) (what the model observes)."""
    x = OBSERVATIONS[model.config.observation.kind].batch(data, normalizer)  # (N, T+1, ...)
    u = torch.as_tensor(data.actions, dtype=torch.float32)  # (N, T, nu)
    model.eval()
    return [model.predict(x[:, t], u[:, t:]) for t in range(x.shape[1] - 1)]


@torch.no_grad()
def horizon_errors(model: LatentModel, data: SequenceData, normalizer: Normalizer,
                   predictions: list[torch.Tensor] | None = None) -> list[float]:
    """Mean image MSE of the model's open-loop prediction at horizon h = 1..T (index h-1),
    over all starts t with t + h <= T. A rollout that diverged gives inf (never NaN).
    ``predictions``: :func:`rollouts` of the same model and data, when already made."""
    x = OBSERVATIONS[model.config.observation.kind].batch(data, normalizer)  # (N, T+1, ...)
    pred = predictions if predictions is not None else rollouts(model, data, normalizer)
    return _by_horizon(x, lambda t: pred[t][:, 1:])


@torch.no_grad()
def baseline_errors(train: SequenceData, held_out: SequenceData,
                    normalizer: Normalizer) -> dict[str, list[float]]:
    """:func:`horizon_errors` of the model-free predictors in :data:`BASELINES` on
    ``held_out``; the mean image is the training split's."""
    x = normalizer.normalize(held_out.images)  # (N, T+1, C, S, S)
    mean = normalizer.normalize(train.images).flatten(0, 1).mean(0)  # (C, S, S)
    steps = x.shape[1] - 1
    return {
        "still": _by_horizon(x, lambda t: x[:, t:t + 1].expand(-1, steps - t, -1, -1, -1)),
        "mean_image": _by_horizon(x, lambda t: mean.expand(len(x), steps - t, *mean.shape)),
    }


def model_stats(model: LatentModel) -> dict[str, float | None]:
    """Coefficient counts and sparsity (the dynamics model's own ``stats``; None where a model
    has no such notion) and the parameter count of the whole model."""
    return {**model.dynamics.stats(),
            "params/total": sum(p.numel() for p in model.parameters())}


@dataclass(frozen=True)
class Stat:
    """Mean ± std of one metric over seeds; ``n`` counts the finite values used.

    ``mean`` is None when the metric does not apply (every value None), inf when every
    value is inf (a diverged prediction), and NaN when no seed produced a finite value
    otherwise (e.g. steps to goal without a success).
    """

    mean: float | None
    std: float | None
    n: int


def mean_std(values: Sequence[float | None]) -> Stat:
    """Mean and sample standard deviation (ddof = 1; 0 for a single value) of the finite values.

    None (not applicable), NaN (no result) and inf (diverged) entries are left out of both.
    """
    given = [v for v in values if v is not None]
    if not given:
        return Stat(None, None, 0)
    finite = np.array([v for v in given if math.isfinite(v)], dtype=float)
    if finite.size == 0:
        diverged = all(v == math.inf for v in given)
        return Stat(math.inf if diverged else math.nan, math.nan, 0)
    std = float(finite.std(ddof=1)) if finite.size > 1 else 0.0
    return Stat(float(finite.mean()), std, int(finite.size))


def aggregate(per_seed: Sequence[Mapping[str, float | None]]) -> dict[str, Stat]:
    """Flat metric dictionaries, one per seed, to {metric: Stat} over the union of keys."""
    keys = dict.fromkeys(k for d in per_seed for k in d)  # ordered union
    return {k: mean_std([d.get(k) for d in per_seed]) for k in keys}
