"""The pendulum video: the SINDy autoencoder's benchmark (Champion et al., PNAS 2019).

A frictionless pendulum θ̈ = −sin θ (θ = 0 hanging down; ``omega2`` sets another ω² in
θ̈ = −ω² sin θ) seen as a Gaussian blob on a 51×51 grid over [−1.5, 1.5]², with the
images' exact first and second time derivatives (chain rule through θ, θ̇, θ̈). Starts are
drawn uniformly, θ ∈ [−π, π], θ̇ ∈ [−2.1, 2.1], and rejected when |θ̇²/2 − cos θ| > 0.99, so
no pendulum turns full circles (rates and limit scaled by ω, ω²). The settings are those of the
paper's public example code (docs/design.md §6).

    >>> from latent_sindy.worlds.pendulum import pendulum_video
    >>> data = pendulum_video(n_train=4, n_val=1, n_test=1, steps=50, size=21)
    >>> data.images.shape, data.images_ddot.shape, data.split_counts()
    ((6, 50, 1, 21, 21), (6, 50, 1, 21, 21), {'train': 4, 'val': 1, 'test': 1})

Memory: the paper's 120 trajectories of 500 frames at 51×51 in float32 hold 624 MB per array,
1.9 GB with both derivatives; ``frames_every`` and ``steps`` make it smaller.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from latent_sindy.data.sequence import SequenceData
from latent_sindy.errors import UserError

__all__ = ["ENERGY_LIMIT", "WIDTH", "blob_images", "integrate", "pendulum_video",
           "sample_starts"]

ENERGY_LIMIT = 0.99
"""A start is kept when |θ̇²/2 − cos θ| <= this (the pendulum never goes over the top)."""
WIDTH = 0.05
"""The blob's squared width in exp(−d²/WIDTH)."""
_SUBSTEPS = 20  # RK4 steps per frame: at dt/20 = 1e-3 the error is ~1e-12 over 10 time units


def sample_starts(n: int, rng: np.random.Generator, omega2: float = 1.0) -> np.ndarray:
    """``n`` accepted starts (n, 2) of (θ, θ̇): uniform draws, those over the energy limit
    rejected, the accepted ones kept in the order drawn. For θ̈ = −ω² sin θ (``omega2`` =
    ω²) the rates are drawn ω times wider and the limit is ω² times the energy's: the same
    starts in the pendulum's own time, so that none turns full circles."""
    found: list[np.ndarray] = []
    count = 0
    omega = math.sqrt(omega2)
    while count < n:
        theta = rng.uniform(-np.pi, np.pi, 2 * n)
        rate = rng.uniform(-2.1 * omega, 2.1 * omega, 2 * n)
        ok = np.abs(rate ** 2 / 2 - omega2 * np.cos(theta)) <= ENERGY_LIMIT * omega2
        found.append(np.stack([theta[ok], rate[ok]], axis=1))
        count += int(ok.sum())
    return np.concatenate(found)[:n]


def _rhs(x: np.ndarray, omega2: float) -> np.ndarray:
    return np.stack([x[:, 1], -omega2 * np.sin(x[:, 0])], axis=1)


def integrate(starts: np.ndarray, frames: int, dt: float, omega2: float = 1.0) -> np.ndarray:
    """States (n, frames, 2) of θ̈ = −ω² sin θ (``omega2`` = ω²) at t = 0, dt, ...,
    (frames − 1)·dt, by classic Runge-Kutta at dt/20 (all trajectories at once, float64)."""
    x = np.asarray(starts, np.float64).copy()  # (n, 2)
    out = np.empty((len(x), frames, 2))
    h = dt / _SUBSTEPS
    out[:, 0] = x
    for k in range(1, frames):
        for _ in range(_SUBSTEPS):
            k1 = _rhs(x, omega2)
            k2 = _rhs(x + h / 2 * k1, omega2)
            k3 = _rhs(x + h / 2 * k2, omega2)
            k4 = _rhs(x + h * k3, omega2)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out[:, k] = x
    return out


def blob_images(theta: np.ndarray, rate: np.ndarray, size: int = 51,
                dtype: Any = np.float32, omega2: float = 1.0
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The images x, ẋ, ẍ (..., size, size) of the pendulum at θ, θ̇ (any equal shapes).

    x = exp(−((X − sin θ)² + (Y + cos θ)²)/0.05), the blob's centre (cos(θ − π/2),
    sin(θ − π/2)) = (sin θ, −cos θ). With f(θ) the image, ẋ = f′ θ̇ and ẍ = f″ θ̇² + f′ θ̈,
    θ̈ = −ω² sin θ (``omega2`` = ω²): f′ = f g, g = (2/0.05)(a cos θ + b sin θ), f″ = f (g² + g′),
    g′ = (2/0.05)(b cos θ − a sin θ − 1), a = X − sin θ, b = Y + cos θ.
    """
    axis = np.linspace(-1.5, 1.5, size)
    X, Y = np.meshgrid(axis, axis[::-1])  # X left to right, Y top (1.5) to bottom (−1.5)
    th = np.asarray(theta, np.float64)[..., None, None]
    w = np.asarray(rate, np.float64)[..., None, None]
    s, c = np.sin(th), np.cos(th)
    a, b = X - s, Y + c
    f = np.exp(-(a ** 2 + b ** 2) / WIDTH)
    g = (2 / WIDTH) * (a * c + b * s)
    dg = (2 / WIDTH) * (b * c - a * s - 1)
    f1 = f * g
    x_dot = f1 * w
    x_ddot = f * (g ** 2 + dg) * w ** 2 + f1 * (-omega2 * s)
    return f.astype(dtype), x_dot.astype(dtype), x_ddot.astype(dtype)


def pendulum_video(n_train: int = 100, n_val: int = 10, n_test: int = 10, seed: int = 0,
                   steps: int = 500, dt: float = 0.02, size: int = 51, frames_every: int = 1,
                   dtype: Any = np.float32, omega2: float = 1.0,
                   starts: str = "own_time") -> SequenceData:
    """The pendulum video benchmark as :class:`~latent_sindy.data.SequenceData`.

    Args:
        n_train, n_val, n_test: trajectories of each split (labelled in this order).
        seed: seeds the starts (the same seed gives the same data, bit for bit).
        steps: time samples per trajectory, t = 0, dt, ..., (steps − 1)·dt (the paper's
            t ∈ [0, 10) at dt 0.02 is 500 samples, so ``data.steps`` is 499).
        dt: the time between samples; size: the image's side in pixels.
        frames_every: keep every k-th sample (the data's ``dt`` is then k·dt).
        dtype: floating-point type of the images and their derivatives.
        omega2: ω² of θ̈ = −ω² sin θ (the benchmark's 1).
        starts: "own_time" (the benchmark's starts in the pendulum's own time: rates drawn ω
            times wider, the energy limit ω² times larger) or "benchmark" (the starts drawn
            as for ω² = 1, whatever ω²: relatively smaller swings for ω² > 1; refused below
            1, where some would turn full circles).

    Returns images (N, F, 1, size, size) in [0, 1], ``images_dot`` and ``images_ddot`` of the
    same shape, states (θ, θ̇) with θ's period 2π, no actions, world "pendulum-video".
    """
    n = n_train + n_val + n_test
    if min(n_train, n_val, n_test) < 0 or n < 1:
        raise UserError(f"pendulum_video needs trajectory counts >= 0 and at least one, got "
                        f"n_train={n_train}, n_val={n_val}, n_test={n_test}")
    if not (isinstance(frames_every, int) and frames_every >= 1):
        raise UserError(f"frames_every {frames_every!r}: use an integer >= 1")
    if not (isinstance(steps, int) and len(range(0, steps, frames_every)) >= 2):
        raise UserError(f"steps {steps!r} with frames_every {frames_every} keeps fewer than two "
                        "frames: use more steps or a smaller frames_every")
    if not (math.isfinite(dt) and dt > 0) or not (isinstance(size, int) and size >= 2):
        raise UserError(f"dt {dt!r} and size {size!r}: use dt > 0 and an integer size >= 2")
    if not (math.isfinite(omega2) and omega2 > 0):
        raise UserError(f"omega2 {omega2!r}: use a number > 0 (the benchmark's is 1)")
    if starts not in ("own_time", "benchmark") or (starts == "benchmark" and omega2 < 1):
        raise UserError(f"starts {starts!r} with omega2 {omega2}: use own_time, or benchmark "
                        "with omega2 >= 1 (below, some of its starts turn full circles)")
    if not np.issubdtype(np.dtype(dtype), np.floating):
        raise UserError(f"dtype {dtype!r}: the images are floating point (float32 or float64)")
    first = sample_starts(n, np.random.default_rng(seed), omega2 if starts == "own_time" else 1)
    states = integrate(first, steps, dt, omega2)[:, ::frames_every]  # (n, F, 2)
    shape = (n, states.shape[1], 1, size, size)
    x, x_dot, x_ddot = (np.empty(shape, dtype) for _ in range(3))
    for i in range(n):  # one trajectory at a time: the float64 temporaries stay small
        x[i, :, 0], x_dot[i, :, 0], x_ddot[i, :, 0] = blob_images(
            states[i, :, 0], states[i, :, 1], size, dtype, omega2)
    split = np.repeat(np.arange(3, dtype=np.uint8), [n_train, n_val, n_test])
    settings = {"steps": steps, "dt": dt, "size": size, "frames_every": frames_every,
                "energy_limit": ENERGY_LIMIT, "width": WIDTH, "omega2": omega2,
                "starts": starts}
    return SequenceData(
        x, None, states=states.astype(dtype), state_names=("θ", "θ_dot"),
        state_periods=(2 * math.pi, None), split=split, dt=dt * frames_every,
        world="pendulum-video", images_dot=x_dot, images_ddot=x_ddot,
        record={"video": settings}, seed=seed,
        source=f"<pendulum video, seed {seed}>")
