"""A fixed linear front for the fully connected autoencoder: the first ``k`` principal
components of the training frames in front of the encoder's network and behind the
decoder's (``AutoencoderConfig.pca_components``).

The networks then work on k coordinates instead of every pixel, which makes a step of the
SINDy autoencoder's pendulum model tens of times cheaper (BENCHMARKS.md), and being linear
the map carries the frames' time derivatives exactly. Nothing of it is learned: the map is
fitted once, from the normalised training frames, when the model takes its statistics, and
travels in the model's state (its buffers).

    mean, basis, spread = principal_components(frames.flatten(1), k)  # (pixels,), (pixels, k)
"""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn import functional as F

from latent_sindy.errors import UserError

__all__ = ["FRONT_FRAMES", "LinearMap", "blurred_metric", "principal_components"]

#: The most training frames the principal components are fitted on (evenly spaced).
FRONT_FRAMES = 8192
#: Where frames and pixels both number more than this, the principal directions are found
#: by subspace iteration (:data:`POWER_STEPS` passes over :data:`OVERSAMPLE` directions more
#: than asked for) rather than by an eigendecomposition of every pixel's or frame's
#: covariance (BENCHMARKS.md: the front of a 75 × 75 video, 8192 frames).
EXACT_BELOW = 2048
POWER_STEPS = 6
OVERSAMPLE = 32


class LinearMap(nn.Module):
    """x -> x Wᵀ + b with W (n_out, n_in) and b fixed (buffers, not parameters)."""

    is_linear = True  # (derivatives.along_layers: its derivatives are W times its input's)

    def __init__(self, n_in: int, n_out: int) -> None:
        super().__init__()
        self.register_buffer("weight", torch.zeros(n_out, n_in))
        self.register_buffer("bias", torch.zeros(n_out))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.linear(x, self.weight, self.bias)

    def set(self, weight: torch.Tensor, bias: torch.Tensor) -> None:
        """Give the map its weight (n_out, n_in) and bias (n_out,)."""
        self.weight.copy_(weight)
        self.bias.copy_(bias)


def _leading_directions(x: torch.Tensor, k: int) -> torch.Tensor:
    """The first ``k`` principal directions (pixels, k) of centred ``x`` (M, pixels) by
    subspace iteration from a seeded random start (Halko, Martinsson and Tropp 2011):
    :data:`POWER_STEPS` passes of x and xᵀ over k + :data:`OVERSAMPLE` directions, then the
    leading ones of the subspace found. A direction the frames do not vary along is 0."""
    gen = torch.Generator().manual_seed(0)
    q = torch.randn(x.shape[1], min(k + OVERSAMPLE, *x.shape), dtype=x.dtype, generator=gen)
    for _ in range(POWER_STEPS):
        q = torch.linalg.qr(x.T @ torch.linalg.qr(x @ q).Q).Q
    values, vectors = torch.linalg.eigh((x @ q).T @ (x @ q))
    top = values[-k:].flip(0)
    flat = top <= values[-1].clamp_min(0) * 1e-12
    return (q @ vectors[:, -k:].flip(1)).masked_fill(flat, 0.0)


@torch.no_grad()
def principal_components(frames: torch.Tensor, k: int
                         ) -> tuple[torch.Tensor, torch.Tensor, float]:
    """The mean (pixels,), the first ``k`` principal directions (pixels, k), orthonormal
    columns, of ``frames`` (M, pixels), and the rms of the frames' coordinates on them,
    fitted in float64 on at most :data:`FRONT_FRAMES` evenly spaced frames (by subspace
    iteration where frames and pixels number more than :data:`EXACT_BELOW`); UserError
    where there are fewer frames or pixels than ``k``."""
    m, p = frames.shape
    if k > min(m, p):
        raise UserError(f"pca_components {k}: the training split has {m} frames of {p} values; "
                        f"use at most {min(m, p)} components")
    x = frames[torch.linspace(0, m - 1, min(m, FRONT_FRAMES)).round().long()].double()
    mean = x.mean(0)
    x = x - mean
    if min(x.shape) > EXACT_BELOW:
        basis = _leading_directions(x, k)
    # the eigenvectors of the smaller of xᵀx and xxᵀ (2.5 times quicker than an SVD here)
    elif p <= len(x):
        basis = torch.linalg.eigh(x.T @ x)[1][:, -k:].flip(1)
    else:
        values, u = torch.linalg.eigh(x @ x.T)
        top = values[-k:].flip(0)
        scale = top.clamp_min(torch.finfo(x.dtype).tiny).sqrt()
        # a direction the frames do not vary along (k of M frames, less their mean) is 0
        flat = top <= values[-1].clamp_min(0) * 1e-12
        basis = ((x.T @ u[:, -k:].flip(1)) / scale).masked_fill(flat, 0.0)
    spread = (x @ basis).square().mean().sqrt().clamp_min(torch.finfo(x.dtype).tiny)
    return mean.float(), basis.float(), float(spread)


@torch.no_grad()
def blurred_metric(columns: torch.Tensor, shape: tuple[int, ...], width: float) -> torch.Tensor:
    """R (k, k) under which the distance between two points of a linear front, ‖R (c − c')‖,
    is the distance between the frames they stand for blurred by a Gaussian of ``width``
    pixels: ‖G (W (c − c'))‖, with ``columns`` W (pixels, k) the front's map back to the
    frames (C, H, W) = ``shape``, and G the blur of each channel (zeros beyond the frame).
    R is the triangular factor of G W, so the points map to c Rᵀ."""
    c, h, w = shape
    r = max(1, math.ceil(3 * width))
    x = torch.arange(-r, r + 1, dtype=torch.float64)
    g = torch.exp(-x.square() / (2 * width * width))
    g = g / g.sum()
    k = columns.shape[1]
    im = columns.T.double().reshape(k * c, 1, h, w)
    im = F.conv2d(im, g.view(1, 1, 1, -1), padding=(0, r))
    im = F.conv2d(im, g.view(1, 1, -1, 1), padding=(r, 0))
    return torch.linalg.qr(im.reshape(k, -1).T, mode="r").R
