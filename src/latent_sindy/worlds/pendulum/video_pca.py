"""The pendulum video through a fixed linear compression, as the recovery study trains on it.

The frames pass the first ``k`` principal components of the training frames (2601 pixels ->
k coordinates, fitted once). Being linear, the map carries ẋ and ẍ exactly ("exact"), and
central differences of the coordinates are those of the frames ("central", taken at the
video's own dt = 0.02 before keeping every ``frames_every``-th frame).

    video = load_or_make(Path("out"), k=48, frames_every=5, derivatives="exact")
    data, lo, span = as_sequences(video)        # SequenceData of (1, 1, k) "images"
"""

from __future__ import annotations

import dataclasses
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from latent_sindy.atomic import atomic_path
from latent_sindy.data import SequenceData
from latent_sindy.errors import UserError

__all__ = ["DT", "PIXELS", "SPLITS", "STEPS", "Compressed", "as_sequences", "cache_name",
           "compressed_video", "load_or_make"]

PIXELS = 51 * 51
SPLITS = (100, 10, 10)
"""The benchmark's training, validation and test trajectories."""
STEPS = 500
DT = 0.02


@dataclass
class Compressed:
    """The video through a fixed linear map: c = (x − mean) V, V (pixels, k) orthonormal."""

    mean: np.ndarray  # (pixels,)
    basis: np.ndarray  # (pixels, k)
    coords: np.ndarray  # (N, F, 3, k): c, ċ, c̈
    states: np.ndarray  # (N, F, 2)
    split: np.ndarray  # (N,)
    dt: float


def compressed_video(k: int, frames_every: int, derivatives: str,
                     splits: tuple[int, int, int] = SPLITS, steps: int = STEPS,
                     omega2: float = 1.0, starts: str = "own_time") -> Compressed:
    """The benchmark's trajectories (``pendulum_video(seed=0)``'s starts and states; fewer
    with smaller ``splits``/``steps``; θ̈ = −ω² sin θ with ``omega2``, its ``starts`` as
    :func:`~latent_sindy.worlds.pendulum.video.pendulum_video` draws them), rendered one
    trajectory at a time and projected on the first ``k`` principal components of the
    training frames (every 5th frame of each fitted)."""
    from latent_sindy.models.derivatives import estimate_derivatives
    from latent_sindy.worlds.pendulum.video import blob_images, integrate, sample_starts

    fitted = splits[0] * len(range(0, steps, 5))
    if not 1 <= k <= min(fitted, PIXELS) or frames_every < 1 or min(splits) < 1:
        raise UserError(f"pendulum video: {k} components of {fitted} training frames, "
                        f"splits {splits}, every {frames_every}th frame: use 1 <= components "
                        f"<= {min(fitted, PIXELS)} and at least one trajectory per split")
    if derivatives not in ("exact", "central"):
        raise UserError(f"--derivatives {derivatives!r}: use exact or central")
    n = sum(splits)
    if starts not in ("own_time", "benchmark") or (starts == "benchmark" and omega2 < 1):
        raise UserError(f"starts {starts!r} with omega2 {omega2}: use own_time, or benchmark "
                        "with omega2 >= 1")
    first = sample_starts(n, np.random.default_rng(0), omega2 if starts == "own_time" else 1)
    states = integrate(first, steps, DT, omega2)  # (n, F, 2)
    fit = np.concatenate([blob_images(states[i, ::5, 0], states[i, ::5, 1])[0]
                          .reshape(-1, PIXELS) for i in range(splits[0])]).astype(np.float64)
    mean = fit.mean(0)
    basis = np.linalg.svd(fit - mean, full_matrices=False)[2][:k].T  # (pixels, k)
    keep = slice(None, None, frames_every)
    coords = []
    for i in range(n):
        rows = keep if derivatives == "exact" else slice(None)  # (central: every frame)
        x, dx, ddx = (a.reshape(-1, PIXELS).astype(np.float64)
                      for a in blob_images(states[i, rows, 0], states[i, rows, 1],
                                           omega2=omega2))
        c = (x - mean) @ basis
        if derivatives == "exact":
            dc, ddc = dx @ basis, ddx @ basis
        else:  # differences of the coordinates = the coordinates of the frames' differences
            dc, ddc = (r[0] for r in estimate_derivatives(c[None], DT, 2, derivatives))
        coords.append(np.stack([c, dc, ddc], 1)[slice(None) if derivatives == "exact"
                                                else keep])
    split = np.repeat(np.arange(3, dtype=np.uint8), splits)
    return Compressed(mean, basis, np.stack(coords).astype(np.float32), states[:, keep],
                      split, DT * frames_every)


def cache_name(k: int, frames_every: int, derivatives: str,
               splits: tuple[int, int, int] = SPLITS, steps: int = STEPS,
               omega2: float = 1.0, starts: str = "own_time") -> str:
    """The cache file's name; the benchmark's own sizes keep their historical name."""
    size = "" if (splits, steps) == (SPLITS, STEPS) else f"_{'-'.join(map(str, splits))}x{steps}"
    size += "" if omega2 == 1 else f"_w{omega2!r}" + ("" if starts == "own_time" else "b")
    return f"pendulum_pca_{k}_{frames_every}_{derivatives}{size}.npz"


def load_or_make(folder: Path, k: int, frames_every: int, derivatives: str,
                 splits: tuple[int, int, int] = SPLITS, steps: int = STEPS,
                 omega2: float = 1.0, starts: str = "own_time") -> Compressed:
    """The compressed video, read from ``folder``'s cache when there (a damaged or foreign
    file is made again), else made and cached atomically (``.npz``, no pickles)."""
    path = Path(folder) / cache_name(k, frames_every, derivatives, splits, steps, omega2,
                                     starts)
    n = sum(splits)
    frames = len(range(0, steps, frames_every))
    try:
        with np.load(path, allow_pickle=False) as f:
            video = Compressed(**{name: f[name] for name in
                                  ("mean", "basis", "coords", "states", "split")},
                               dt=DT * frames_every)
        if video.coords.shape == (n, frames, 3, k) and video.basis.shape == (PIXELS, k):
            return video
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        pass  # missing or unreadable: make it again
    video = compressed_video(k, frames_every, derivatives, splits, steps, omega2, starts)
    with atomic_path(path) as tmp:
        np.savez(tmp, **{f.name: getattr(video, f.name) for f in dataclasses.fields(video)
                         if f.name != "dt"})
    return video


def as_sequences(video: Compressed) -> tuple[SequenceData, float, float]:
    """The coordinates as a SequenceData of (1, 1, k) "images": scaled by one scalar into
    [0, 1] as SequenceData asks (the model's normaliser undoes it; an affine map keeps the
    derivatives exact), with the offset and scale to map back."""
    c = video.coords
    lo = float(c[:, :, 0].min())
    span = float(np.ptp(c[:, :, 0])) * 1.001
    images = (c[:, :, 0] - lo) / span
    n, f, k = images.shape
    data = SequenceData(images.reshape(n, f, 1, 1, k).clip(0, 1), None, split=video.split,
                        dt=video.dt, images_dot=(c[:, :, 1] / span).reshape(n, f, 1, 1, k),
                        images_ddot=(c[:, :, 2] / span).reshape(n, f, 1, 1, k),
                        world=None, source="<pendulum video, PCA>")
    return data, lo, span
