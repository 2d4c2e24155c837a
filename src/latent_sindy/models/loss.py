"""The loss's weights (λ1 image prediction, λ2 latent prediction, λ3 L1, λ4 pose, λ5
reward; see :mod:`latent_sindy.models.latent_model`) and the error terms the latent model's
loss shares: the latent prediction error (absolute or scale-free) and the object's pixels of
an image."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from latent_sindy.errors import UserError

__all__ = ["DEFAULT_WEIGHTS", "MAX_FOREGROUND_WEIGHT", "LossWeights", "foreground",
           "latent_error"]


#: Largest :attr:`LossWeights.foreground_weight` (1e308 made the first epoch's loss NaN).
MAX_FOREGROUND_WEIGHT = 1000.0


@dataclass(frozen=True)
class LossWeights:
    """λ1 ... λ5 of the loss (see the module docstring)."""

    # On a 60-trajectory set (SINDy order 2, 300 epochs): λ2 = 0.1 left the latent prediction
    # error 9x larger than λ2 = 1 for 6% better validation reconstruction. On 100 training
    # trajectories (conv decoder, 60 epochs): λ3 = 1e-3 pruned 90% of the order-2
    # coefficients, 1e-2 pruned 98.5% for a 1% higher validation loss.
    lambda_pred_x: float = 1.0
    """λ1: weight of the image prediction loss, dec(ẑ_t) vs x_t."""
    lambda_pred_z: float = 1.0
    """λ2: weight of the latent prediction loss, ẑ_t vs enc(x_t) (latent MPPI relies on it)."""
    lambda_l1: float = 1e-2
    """λ3: weight of ‖M ⊙ Ψ‖₁, a sum over all coefficients (SINDy only)."""
    lambda_pose: float = 0.0
    """λ4: weight of the pose head's error on the true poses (models with --pose-head; a
    privileged signal used in training only). 0: the head is not trained."""
    lambda_reward: float = 1.0
    """λ5: weight of the reward head's error on the data's rewards (models with
    --reward-head, on data with rewards; nothing otherwise)."""
    relative_pred_z: bool = False
    """λ2's term as a fraction of its targets' variance (the encoded latents' z_t, or the
    encoder's z^(k) in continuous time) instead of the mean squared error: scale-free, so the
    encoder cannot lower it by shrinking z, and a large λ2 straightens the latent instead
    (the pendulum video: RESULTS.md, "A scale-free latent loss")."""
    foreground_weight: float = 0.0
    """Image models: extra weight of the moving object's pixels in the trained image terms
    (recon, pred_x): a pixel of the true image further than 1 (one training pixel std) from
    its image's median counts 1 + this. The reported terms and objective stay unweighted."""

    def __post_init__(self) -> None:
        for name in ("lambda_pred_x", "lambda_pred_z", "lambda_l1", "lambda_pose",
                     "lambda_reward", "foreground_weight"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise UserError(f"--{name.replace('_', '-')} {v}: use a finite number >= 0")
        if self.foreground_weight > MAX_FOREGROUND_WEIGHT:
            raise UserError(f"--foreground-weight {self.foreground_weight}: use 0 to "
                            f"{MAX_FOREGROUND_WEIGHT:g} (the object's pixels count 1 + this; "
                            "far larger drowns the background and overflows the loss; "
                            "3 and 10 were tried, RESULTS.md)")


DEFAULT_WEIGHTS = LossWeights()


def latent_error(pred: torch.Tensor, target: torch.Tensor, relative: bool) -> torch.Tensor:
    """The mean squared error of ``pred`` against ``target`` (..., nz), or with ``relative``
    that divided by the target's variance over every sample (its mean per coordinate
    removed): the fraction of it left unexplained."""
    err = (pred - target).square().mean()
    if not relative:
        return err
    flat = target.reshape(-1, target.shape[-1])
    spread = (flat - flat.mean(0)).square().mean()
    return err / spread.clamp_min(torch.finfo(spread.dtype).tiny)


def foreground(x: torch.Tensor) -> torch.Tensor:
    """1 where a normalised image (..., C, h, w) differs from its median by more than 1 (one
    training pixel std: the object against the background), else 0."""
    flat = x.flatten(-3)
    median = flat.median(dim=-1, keepdim=True).values
    return ((flat - median).abs() > 1).to(x.dtype).view_as(x)
