"""Measurements of one trained run on the same footing as every other, and their aggregation.

Every model, whatever its dynamics, is judged on the same normalised images:

* ``split_losses``: the objective without the L1 term (recon + λ1 pred_x + λ2 pred_z, see
  :mod:`latent_sindy.models.latent_model`) on the single-step (H = 1) windows of each split,
  so a multi-step-trained model is scored like the others;
* ``horizon_errors``: image MSE of dec(rollout) against the true images, h = 1..T steps after
  every start of every test trajectory (open loop, normalised pixels);
* ``model_stats``: active coefficients and sparsity (SINDy), coefficient / parameter counts;
* ``aggregate``: mean ± std over seeds of flat metric dictionaries.

    from latent_sindy.experiments.evaluation import horizon_errors, split_losses
    run = load_run("results/runs/seed0/sindy2")
    losses = split_losses(run.model, read_trajectories("results/data.h5"), run.normalizer)
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from latent_sindy.data.store import SPLITS, Trajectories
from latent_sindy.data.windows import Normalizer, WindowDataset
from latent_sindy.models.dynamics import LinearDynamics, SindyDynamics
from latent_sindy.models.latent_model import LatentModel, LossWeights
from latent_sindy.training import evaluate

__all__ = ["Stat", "aggregate", "horizon_errors", "mean_std", "model_stats", "split_losses"]


def split_losses(model: LatentModel, data: Trajectories, normalizer: Normalizer,
                 weights: LossWeights | None = None) -> dict[str, dict[str, float]]:
    """Loss terms (``objective``, ``recon``, ``pred_x``, ``pred_z``) per split, H = 1 windows."""
    out = {}
    for split in SPLITS:
        part = data.split(split)
        if part.n == 0:
            continue
        terms = evaluate(model, *WindowDataset(part, 1, normalizer).tensors(), weights)
        out[split] = {k: terms[k] for k in ("objective", "recon", "pred_x", "pred_z")}
    return out


@torch.no_grad()
def horizon_errors(model: LatentModel, data: Trajectories, normalizer: Normalizer) -> list[float]:
    """Mean image MSE at horizon h = 1..T (index h-1), over all starts t with t + h <= T.

    A rollout that diverged gives inf (never NaN).
    """
    x = normalizer.normalize(data.images)  # (N, T+1, C, S, S)
    u = torch.as_tensor(data.actions, dtype=torch.float32)  # (N, T, nu)
    steps = u.shape[1]
    sums, counts = np.zeros(steps), np.zeros(steps)
    model.eval()
    for t in range(steps):
        pred = model.predict(x[:, t], u[:, t:])  # (N, T-t+1, C, S, S)
        err = (pred[:, 1:] - x[:, t + 1:]).square().mean(dim=(0, 2, 3, 4))  # (T-t,)
        sums[: steps - t] += err.double().numpy() * len(x)
        counts[: steps - t] += len(x)
    err = sums / np.maximum(counts, 1)
    return np.where(np.isnan(err), np.inf, err).tolist()  # NaN here means a diverged rollout


def model_stats(model: LatentModel) -> dict[str, float | None]:
    """Coefficient counts and sparsity; None where a model has no such notion."""
    dyn = model.dynamics
    n_dyn_params = sum(p.numel() for p in dyn.parameters())
    stats: dict[str, float | None] = {"params/dynamics": n_dyn_params,
                                      "params/total": sum(p.numel() for p in model.parameters())}
    if isinstance(dyn, SindyDynamics):
        stats.update({"sindy/active": dyn.n_active(), "sindy/coefficients": dyn.mask.numel(),
                      "sindy/terms_used": int(dyn.mask.any(dim=1).sum()),
                      "sindy/sparsity": dyn.sparsity()})
    else:
        n = n_dyn_params if isinstance(dyn, LinearDynamics) else None
        stats.update({"sindy/active": n, "sindy/coefficients": n, "sindy/terms_used": None,
                      "sindy/sparsity": None})
    return stats


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
