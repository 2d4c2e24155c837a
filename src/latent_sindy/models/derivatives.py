"""Time derivatives for continuous-time latent models: through a network by the chain rule,
and of a camera's frames by finite differences.

Along a trajectory x(t) of the data, the encoder's latent z = φ(x) moves as

    ż = J ẋ                 z̈ = J ẍ + H[ẋ, ẋ]        (J, H: φ's Jacobian and Hessian at x)

:func:`along` computes both in forward mode (``torch.func.jvp``, the second by the jvp of the
jvp), batched, at about two (first order) or four (second order) forward passes and with
gradients for the network's parameters; the decoder's ẋ̂, ẍ̂ from z, ż, z̈ are the same call.
No Jacobian is ever formed.

When the data gives no derivatives (a real camera), :func:`estimate_derivatives` takes them
from the frames: central finite differences (second-order accurate, one-sided at the ends),
or a Savitzky-Golay smoothing differentiator for noisy frames.

    z, dz, ddz = along(encoder, x, dx, ddx)        # x, dx, ddx (B, C, H, W) -> (B, nz) each
    dx, ddx = estimate_derivatives(frames, dt=0.02, order=2)   # frames (N, T+1, ...)
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch
from torch import nn
from torch.func import jvp

from latent_sindy.errors import UserError

__all__ = ["DERIVATIVE_METHODS", "along", "along_layers", "characteristic_time",
           "estimate_derivatives", "motion_time"]

#: How :func:`estimate_derivatives` differentiates frames.
DERIVATIVE_METHODS = ("central", "smooth")


def along(f: Callable[[torch.Tensor], torch.Tensor], x: torch.Tensor, dx: torch.Tensor,
          ddx: torch.Tensor | None = None) -> tuple[torch.Tensor, ...]:
    """f(x) and its time derivatives along a path through x with velocity ``dx`` (and
    acceleration ``ddx``): (y, ẏ) = (f(x), J dx), or with ``ddx`` (y, ẏ, ÿ) with
    ÿ = J ddx + H[dx, dx]. ``f`` maps a batch to a batch sample by sample, so one call gives
    every sample's own derivatives; differentiable in f's parameters. A module with its own
    ``along(x, dx[, ddx])`` (the fully connected encoder and decoder: :func:`along_layers`)
    computes them itself."""
    own = getattr(f, "along", None)
    if own is not None:
        return own(x, dx) if ddx is None else own(x, dx, ddx)
    if ddx is None:
        return jvp(f, (x,), (dx,))

    def first(a: torch.Tensor, da: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return jvp(f, (a,), (da,))

    # d/dt of (f(x), J(x) ẋ) along (ẋ, ẍ): (J ẋ, J ẍ + H[ẋ, ẋ])
    (y, dy), (_, ddy) = jvp(first, (x, dx), (dx, ddx))
    return y, dy, ddy


def along_layers(layers: nn.Sequential, x: torch.Tensor, *rates: torch.Tensor
                 ) -> tuple[torch.Tensor, ...]:
    """:func:`along` through ``layers`` one at a time, the same values: a linear layer's
    derivatives are its weight times its input's, any other layer's come from :func:`along`
    (forward mode). For the 128-64-32 sigmoid encoder (121 pixels, batch 50, both
    derivatives, forward and backward) it took 2.4x less time than forward mode through the
    whole network, which pays for every op it passes."""
    for layer in layers:
        if isinstance(layer, nn.Linear) or getattr(layer, "is_linear", False):
            x = layer(x)
            rates = tuple(r @ layer.weight.T for r in rates)
        else:
            x, *more = along(layer, x, *rates)
            rates = tuple(more)
    return (x, *rates)


def _central(v: np.ndarray, dt: float, order: int) -> np.ndarray:
    """First or second derivative along axis 1 by central differences: second-order accurate
    inside and at the ends (one-sided stencils there)."""
    if order == 1:
        return np.gradient(v, dt, axis=1, edge_order=2)
    out = np.empty_like(v)
    out[:, 1:-1] = v[:, 2:] - 2 * v[:, 1:-1] + v[:, :-2]
    out[:, 0] = 2 * v[:, 0] - 5 * v[:, 1] + 4 * v[:, 2] - v[:, 3]
    out[:, -1] = 2 * v[:, -1] - 5 * v[:, -2] + 4 * v[:, -3] - v[:, -4]
    return out / dt**2


def estimate_derivatives(frames: np.ndarray, dt: float, order: int,
                         method: str = "central", window: int = 9,
                         dx: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """ẋ (and ẍ for ``order`` 2) of ``frames`` (N, T+1, ...) sampled every ``dt``, each as
    float32 arrays of the frames' shape, in the frames' own units per unit time.

    ``method`` "central": central differences (2nd-order accurate; needs 4 frames for ẍ);
    "smooth": a Savitzky-Golay differentiator, a cubic fitted to ``window`` frames (odd)
    around each, which averages out pixel noise at the price of some bias. ``dx`` given
    (exact velocities): only ẍ is estimated, from them, to first order in them.
    """
    if method not in DERIVATIVE_METHODS:
        raise UserError(f"derivatives {method!r}: use auto, {', '.join(DERIVATIVE_METHODS)}")
    if order not in (1, 2):
        raise UserError(f"derivative order {order}: use 1 or 2")
    if not (dt and np.isfinite(dt) and dt > 0):
        raise UserError(f"estimating derivatives from frames needs their time step: got dt "
                        f"{dt}; give the data's dt (SequenceData(dt=...)) or its derivatives "
                        "(images_dot, images_ddot)")
    v = np.asarray(frames, dtype=np.float64)
    steps = v.shape[1]
    if method == "central" and steps < 4:
        raise UserError(f"central differences need sequences of 4 frames or more, got {steps}")
    if method == "smooth" and (window % 2 == 0 or window < 5 or window > steps):
        raise UserError(f"smooth derivatives with window {window}: use an odd number of frames "
                        f"from 5 to the sequences' {steps}")
    if method == "central":
        first = np.asarray(dx, np.float64) if dx is not None else _central(v, dt, 1)
        second = _central(first, dt, 1) if dx is not None else _central(v, dt, 2)
    else:
        from scipy.signal import savgol_filter

        def sg(a: np.ndarray, k: int) -> np.ndarray:
            return savgol_filter(a, window, 3, deriv=k, delta=dt, axis=1, mode="interp")

        first = np.asarray(dx, np.float64) if dx is not None else sg(v, 1)
        second = sg(first, 1) if dx is not None else sg(v, 2)
    out = (first,) if order == 1 else (first, second)
    return tuple(a.astype(np.float32) for a in out)


def characteristic_time(frames: np.ndarray, rate: np.ndarray, order: int) -> float:
    """How long the data take to change, from frames (N, ...) and their ``order``-th time
    derivatives ``rate`` (same shape): rms(x − x̄) / rms(ẋ), or √(rms(x − x̄) / rms(ẍ)), the
    means over samples and pixels. For x = a sin(ω t) both are 1/ω; a video of a system twice
    as fast has half the time."""
    x = np.asarray(frames, np.float64).reshape(len(frames), -1)
    spread = float(np.sqrt(((x - x.mean(0)) ** 2).mean()))
    speed = float(np.sqrt((np.asarray(rate, np.float64) ** 2).mean()))
    ratio = spread / speed if speed > 0 else math.inf
    return ratio if order == 1 else math.sqrt(ratio)


def motion_time(frames: np.ndarray, dt: float, rows: int = 2000) -> float:
    """How long the motion in frames (N, T+1, C, H, W) sampled every ``dt`` takes to change:
    rms(p − p̄) / rms(ṗ) of the centroid p of what differs from the still scene (each
    frame's |x − median frame| over channels, less :data:`NOISE_FLOOR` times the pixel
    noise's level, as weights; ṗ by central differences in time). A frame in which almost
    nothing stands out (under :data:`FAINT` of a moving frame's weight: an object resting
    where the still scene shows it, as a damped motion that has died out) reads no centroid.
    Unlike :func:`characteristic_time` of the pixels it holds on noisy frames, on any blob
    size and on any background (a pixel's intensity changes as fast as an edge passes it; the
    centroid moves as the object does): for an object that oscillates at ω it is about 1/ω.
    The median frame is taken over ``rows`` frames spread through the data. Where the
    centroid stays still (intensities that change in place), the first principal
    coordinate's rms(c − c̄) / rms(ċ) instead (1/ω for a sinusoid too)."""
    v = np.asarray(frames, np.float64)
    if v.ndim != 5 or v.shape[1] < 3:
        raise UserError(f"frames of shape {v.shape}: reading the motion's time needs "
                        "(N, T+1, C, H, W) with 3 frames a sequence or more")
    n, f, _, h, w = v.shape
    flat = v.reshape(n * f, -1, h * w)
    pick = np.linspace(0, len(flat) - 1, min(len(flat), rows)).round().astype(int)
    still = np.median(flat[pick], axis=0)
    weight = np.abs(flat - still).sum(1)  # (n f, h w)
    # pixel noise weighs every pixel of the frame, pulling the centroid to the frame's middle
    # and shaking it: only what stands out of the still scene's noise weighs (the noise's
    # level read where nothing moves, most pixels of most frames: their median deviation)
    floor = NOISE_FLOOR * 1.4826 * float(np.median(np.median(weight[pick], axis=1)))
    weight = np.maximum(weight - floor, 0.0)
    yy, xx = np.mgrid[0:h, 0:w]
    where = np.stack([xx.ravel(), yy.ravel()], 1).astype(np.float64)  # (h w, 2)
    total = weight.sum(1, keepdims=True)
    pos = (weight @ where) / np.maximum(total, 1e-300)
    # an object at rest where the still scene shows it (a damped motion that has died out)
    # differs from it in a few noisy pixels at most: their centroid is noise, which would
    # read as fast motion; such frames read no position
    faint = total[:, 0] < FAINT * np.percentile(total[pick, 0], 90)
    pos[faint] = np.nan
    pos = pos.reshape(n, f, 2)  # (the frames at the percentile itself are never faint)
    spread = float(np.sqrt(np.nanmean((pos - np.nanmean(pos, (0, 1))) ** 2)))
    if spread < STILL_CENTROID:  # nothing moves across the frame (intensities change in
        # place): the first principal coordinate's time instead
        flat = v.reshape(n * f, -1)
        mean = flat.mean(0)
        _, _, vt = np.linalg.svd(flat[pick] - mean, full_matrices=False)
        pos = ((flat - mean) @ vt[:1].T).reshape(n, f, 1)
        spread = float(np.sqrt(((pos - pos.mean((0, 1))) ** 2).mean()))
    rate = np.gradient(pos, dt, axis=1)
    speed = float(np.sqrt(np.nanmean(rate ** 2))) if not np.isnan(rate).all() else 0.0
    return spread / speed if speed > 0 else math.inf


#: What differs from the still scene weighs in the centroid beyond this many times the
#: pixel noise's level (:func:`motion_time`).
NOISE_FLOOR = 3.0
#: A frame whose weight (what stands out of the noise) is below this share of a moving
#: frame's (the 90th percentile) reads no centroid (:func:`motion_time`).
FAINT = 0.05
#: A centroid that moves less than this (pixels, rms) shows no object crossing the frame.
STILL_CENTROID = 0.5
