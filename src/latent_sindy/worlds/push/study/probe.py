"""What the latent knows: a linear and a nonlinear probe to the block's pose, and where
predicted images put the block.

* :func:`latent_probe`: R² of a ridge regression from the latent z = enc(x) to the block's
  pose features (x, y and the symmetry-respecting angle features cos(2πθ/P), sin(2πθ/P) of
  :func:`~latent_sindy.data.windows.pose_features`), fitted on the training split's images
  and scored on the held-out ones;
* :func:`kernel_probe`: the same with :class:`KernelProbe` (kernel ridge regression with an
  RBF kernel), so that a latent holding the pose nonlinearly (corner positions, say) is seen
  to hold it; :func:`latent_probes` gives both, as the study records them;
* :func:`block_position`: the block's (x, y) in metres read from images: the centroid of the
  pixels darker than the table, back-projected through the camera of the world's config
  (:class:`~latent_sindy.worlds.push.camera.Camera`) onto the plane of the block's centre;
* :func:`position_errors`: the block position error (cm) of the model's decoded open-loop
  predictions h = 1..T pushes ahead against the true pose, beside reading the true images
  (the reader's own error) and "nothing moves" (the block where the first image shows it);
* :func:`state_position_errors`: the same for a state-space model, whose predictions are poses
  (the bound an image model's predictions are measured against).

    run = load_run("results/runs/seed0/sindy2")
    data = read_sequences("results/data.h5")
    latent_probe(run.model, data, run.normalizer)   # {"x": 0.97, "y": 0.98, ...}
    kernel_probe(run.model, data, run.normalizer)   # {"x": 0.98, ..., "cos": -0.02, ...}
    position_errors(run.model, data, run.normalizer)["model"][0]  # cm, 1 push ahead
"""

from __future__ import annotations

import functools

import numpy as np
import torch

from latent_sindy.data import SequenceData
from latent_sindy.data.windows import Normalizer, pose_features
from latent_sindy.errors import UserError
from latent_sindy.models.latent_model import LatentModel
from latent_sindy.worlds.push.camera import Camera
from latent_sindy.worlds.push.config import BLOCK_SIZE, PushEnvConfig
from latent_sindy.worlds.push.scene import CameraView

__all__ = ["FEATURES", "GRAY", "KernelProbe", "block_levels", "block_position", "kernel_probe",
           "latent_probe", "latent_probes", "position_errors", "state_position_errors"]

#: The probe's targets, in :func:`pose_features` order.
FEATURES = ("x", "y", "cos", "sin")
#: Grayscale weights of R, G, B (the environment's own conversion).
GRAY = (0.2989, 0.587, 0.114)
#: Pixels count as block where their darkness (table − pixel, in units of the table−block
#: contrast) exceeds this, or half the image's darkest pixel's where that is fainter (a
#: fading predicted block); a ground-truth image's block is at least 1.
DARK_FLOOR = 0.25
#: Ridge strength relative to the number of training samples (on standardised latents).
RIDGE = 1e-3


def _gray(images: np.ndarray) -> np.ndarray:
    """(..., C, S, S) pixel values -> (..., S, S) float64 gray."""
    x = np.asarray(images, dtype=np.float64)
    if x.shape[-3] == 1:
        return x[..., 0, :, :]
    return np.tensordot(x, np.array(GRAY), axes=([-3], [0]))


@functools.cache
def block_levels(cfg: PushEnvConfig) -> tuple[float, float]:
    """(table, block) gray levels the world renders: the table's, and the lightest of the
    block's faces (so that every block pixel of a true image is at least that dark).

    Rendered once per config with the block at the centre of the workspace.
    """
    view = CameraView(cfg)
    try:
        centre = [(lo + hi) / 2 for lo, hi in zip(cfg.workspace_low, cfg.workspace_high,
                                                   strict=True)]
        img = _gray(view.observe((centre[0], centre[1], 0.0)))
    finally:
        view.close()
    values, counts = np.unique(img, return_counts=True)
    table = float(values[np.argmax(counts)])
    block = img[img < table - 1.0]
    if block.size == 0:
        raise UserError("the world renders no block darker than its table: block positions "
                        "cannot be read from its images")
    return table, float(block.max())


def block_position(images: np.ndarray | torch.Tensor, env_config: PushEnvConfig,
                   levels: tuple[float, float] | None = None) -> np.ndarray:
    """The block's (x, y) in metres (..., 2) in images (..., C, S, S) of pixel values.

    The table level is each image's median (the block covers about 2 % of it); a pixel's
    darkness is (table − pixel) / (table − block) with the world's levels
    (:func:`block_levels`, or ``levels``). The centroid of the pixels darker than
    :data:`DARK_FLOOR` (or than half the image's darkest, for a faded block), weighted by
    darkness clipped to 1, is back-projected through the camera onto the plane of the
    block's centre: the silhouette of top and visible sides is about centred on it. An
    image with no pixel darker than its median gives NaN.
    """
    x = _gray(images.numpy() if isinstance(images, torch.Tensor) else images)
    s = env_config.image_size
    if x.shape[-2:] != (s, s):
        raise UserError(f"images of {x.shape[-2]}x{x.shape[-1]} pixels, but the world renders "
                        f"{s}x{s}")
    table_ref, block_ref = levels if levels is not None else block_levels(env_config)
    flat = x.reshape(-1, s, s)
    table = np.median(flat.reshape(len(flat), -1), axis=1)[:, None, None]
    dark = (table - flat) / (table_ref - block_ref)  # (M, S, S)
    peak = dark.max(axis=(1, 2), keepdims=True)
    floor = np.minimum(DARK_FLOOR, peak / 2)
    w = np.where((dark > floor) & (peak > 0), np.minimum(dark, 1.0), 0.0)
    total = w.sum(axis=(1, 2))
    rows, cols = np.mgrid[0:s, 0:s]
    with np.errstate(invalid="ignore", divide="ignore"):
        rc = np.stack([(w * rows).sum(axis=(1, 2)) / total,
                       (w * cols).sum(axis=(1, 2)) / total], -1)
    xy = Camera(env_config).pixel_to_world(rc, BLOCK_SIZE[2] / 2)
    return xy.reshape(*x.shape[:-2], 2)


def _cm(xy: np.ndarray, poses: np.ndarray) -> np.ndarray:
    return 100 * np.linalg.norm(xy - poses[..., :2], axis=-1)


@torch.no_grad()
def _latents(model: LatentModel, data: SequenceData, normalizer: Normalizer) -> np.ndarray:
    x = normalizer.normalize(data.images).flatten(0, 1)  # (N (T+1), C, S, S)
    return model.encode(x).double().numpy()


def _probe_data(model: LatentModel, data: SequenceData, normalizer: Normalizer,
                held_out: str) -> tuple[np.ndarray, ...]:
    """Latents and pose features of every image: z_tr (M, nz), y_tr (M, 4), z_te, y_te, and
    each training image's trajectory (M,)."""
    train, test = data.split("train"), data.split(held_out)
    if train.n == 0 or test.n == 0:
        raise UserError(f"{data.source}: the probe needs training and {held_out} trajectories "
                        f"(splits {data.split_counts()})")
    model.eval()
    period = data.world_config.angle_period
    z_tr, z_te = _latents(model, train, normalizer), _latents(model, test, normalizer)
    y_tr = pose_features(train.poses, period).double().numpy().reshape(len(z_tr), -1)
    y_te = pose_features(test.poses, period).double().numpy().reshape(len(z_te), -1)
    return z_tr, y_tr, z_te, y_te, np.repeat(np.arange(train.n), train.steps + 1)


def _r2(pred: np.ndarray, y: np.ndarray) -> dict[str, float]:
    """R² per feature, SST about the held-out targets' own mean (NaN for a constant one)."""
    sse = ((pred - y) ** 2).sum(0)
    sst = ((y - y.mean(0)) ** 2).sum(0)
    r2 = np.where(sst > 0, 1 - sse / np.maximum(sst, 1e-300), np.nan)
    return {f: float(v) for f, v in zip(FEATURES, r2, strict=True)}


def latent_probe(model: LatentModel, data: SequenceData, normalizer: Normalizer,
                 held_out: str = "test") -> dict[str, float]:
    """R² per pose feature (:data:`FEATURES`) of a ridge regression from the latent, fitted
    on every image of the training split, scored on every image of ``held_out``.

    R² = 1 − SSE / SST on the held-out images (SST about their own mean): 1 is perfect, 0
    no better than a constant, negative worse.
    """
    z_tr, y_tr, z_te, y_te, _ = _probe_data(model, data, normalizer, held_out)
    return _ridge_r2(z_tr, y_tr, z_te, y_te)


def _ridge_r2(z_tr: np.ndarray, y_tr: np.ndarray, z_te: np.ndarray, y_te: np.ndarray
              ) -> dict[str, float]:
    mu, sd = z_tr.mean(0), z_tr.std(0) + 1e-12
    a_tr = np.column_stack([(z_tr - mu) / sd, np.ones(len(z_tr))])
    a_te = np.column_stack([(z_te - mu) / sd, np.ones(len(z_te))])
    reg = RIDGE * len(a_tr) * np.eye(a_tr.shape[1])
    reg[-1, -1] = 0.0  # the intercept is not shrunk
    beta = np.linalg.solve(a_tr.T @ a_tr + reg, a_tr.T @ y_tr)
    return _r2(a_te @ beta, y_te)


def kernel_probe(model: LatentModel, data: SequenceData, normalizer: Normalizer,
                 held_out: str = "test", seed: int = 0) -> dict[str, float]:
    """R² per pose feature of a :class:`KernelProbe` from the latent, fitted on the training
    split's images (its settings chosen on a fifth of its trajectories, drawn with
    ``seed``), scored on every image of ``held_out`` as :func:`latent_probe` scores."""
    return _kernel_r2(*_probe_data(model, data, normalizer, held_out), seed)


def latent_probes(model: LatentModel, data: SequenceData, normalizer: Normalizer,
                  held_out: str = "test", seed: int = 0) -> dict[str, float]:
    """Both probes from one encoding of the images: :func:`latent_probe`'s R² under
    :data:`FEATURES`, :func:`kernel_probe`'s under ``kernel/<feature>``, and
    ``kernel/angle`` the mean of its cos and sin (the study's evaluation record)."""
    z_tr, y_tr, z_te, y_te, groups = _probe_data(model, data, normalizer, held_out)
    kernel = _kernel_r2(z_tr, y_tr, z_te, y_te, groups, seed)
    return {**_ridge_r2(z_tr, y_tr, z_te, y_te),
            **{f"kernel/{k}": v for k, v in kernel.items()},
            "kernel/angle": (kernel["cos"] + kernel["sin"]) / 2}


def _kernel_r2(z_tr: np.ndarray, y_tr: np.ndarray, z_te: np.ndarray, y_te: np.ndarray,
               groups: np.ndarray, seed: int) -> dict[str, float]:
    # Too few frames to choose its settings on, or a diverged encoder: no figure.
    if len(z_tr) < 4 or not (np.isfinite(z_tr).all() and np.isfinite(z_te).all()):
        return dict.fromkeys(FEATURES, float("nan"))
    return _r2(KernelProbe(seed=seed).fit(z_tr, y_tr, groups).predict(z_te), y_te)


def _rbf(a: torch.Tensor, b: torch.Tensor, gamma: float) -> torch.Tensor:
    """exp(−γ |a_i − b_j|²): (M, nz), (M', nz) -> (M, M')."""
    return torch.exp(-gamma * torch.cdist(a, b).square())


class KernelProbe:
    """Kernel ridge regression with an RBF kernel on standardised latents and targets.

    For each target its own kernel width γ = ``gamma`` / nz (nz: the latent's size) and
    ridge λ (on the kernel, times the number of frames) are chosen from the grids by the
    error on ``held_out`` of the trajectories (drawn with ``seed``), then refitted on all.
    Over ``max_frames`` training frames, a random subset of whole trajectories of at most
    that many is used (the cost grows with their cube). Float64 torch: deterministic on one
    thread.

        KernelProbe(seed=0).fit(z, y, groups).predict(z_test)   # (M', ny)
    """

    def __init__(self, gammas: tuple[float, ...] = (0.1, 0.3, 1.0, 3.0),
                 ridges: tuple[float, ...] = (1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0),
                 held_out: float = 0.2, max_frames: int = 2000, seed: int = 0) -> None:
        if not (gammas and ridges and min(gammas) > 0 and min(ridges) > 0):
            raise UserError(f"KernelProbe: gammas {gammas} and ridges {ridges} must be "
                            "non-empty and positive")
        if not 0 < held_out < 1:
            raise UserError(f"KernelProbe: held_out={held_out} must be a fraction in (0, 1)")
        self.gammas, self.ridges, self.held_out = gammas, ridges, held_out
        self.max_frames = max_frames
        self.seed = seed

    def fit(self, z: np.ndarray, y: np.ndarray, groups: np.ndarray | None = None
            ) -> KernelProbe:
        """z (M, nz) latents, y (M, ny) targets, groups (M,) each frame's trajectory (None or
        a single one: frames are held out one by one)."""
        z, y = np.asarray(z, np.float64), np.asarray(y, np.float64)
        if z.ndim != 2 or y.ndim != 2 or len(z) != len(y) or len(z) < 4:
            raise UserError(f"KernelProbe: latents {z.shape} and targets {y.shape} must be "
                            "(M, nz) and (M, ny) with the same M >= 4")
        rng = np.random.default_rng(self.seed)
        groups = np.arange(len(z)) if groups is None else np.asarray(groups)
        ids = np.unique(groups)
        if len(ids) < 2:
            groups = np.arange(len(z))
            ids = np.arange(len(z))
        if len(z) > self.max_frames:  # whole trajectories, as many as fit
            keep = rng.permutation(ids)[: max(2, len(ids) * self.max_frames // len(z))]
            z = z[np.isin(groups, keep)]
            y = y[np.isin(groups, keep)]
            groups = groups[np.isin(groups, keep)]
            ids = np.unique(groups)
        val = np.isin(groups, rng.permutation(ids)[: max(1, round(self.held_out * len(ids)))])
        self.mean_, self.scale_ = z.mean(0), z.std(0) + 1e-12
        self.y_mean_, self.y_scale_ = y.mean(0), y.std(0) + 1e-12
        x = torch.as_tensor((z - self.mean_) / self.scale_)
        t = torch.as_tensor((y - self.y_mean_) / self.y_scale_)
        fit, v = torch.as_tensor(~val), torch.as_tensor(val)
        best = np.full(t.shape[1], np.inf)
        self.gamma_, self.ridge_ = np.zeros(t.shape[1]), np.zeros(t.shape[1])
        for g in self.gammas:
            k_fit = _rbf(x[fit], x[fit], g / x.shape[1])
            k_val = _rbf(x[v], x[fit], g / x.shape[1])
            for lam in self.ridges:
                err = ((k_val @ self._solve(k_fit, t[fit], lam) - t[v]) ** 2).mean(0).numpy()
                better = err < best
                best[better] = err[better]
                self.gamma_[better] = g
                self.ridge_[better] = lam
        self.centres_ = x
        self.coef_ = torch.zeros_like(t)  # (M, ny): one column per target, its own kernel
        for g, lam in sorted(set(zip(self.gamma_, self.ridge_, strict=True))):
            cols = torch.as_tensor((self.gamma_ == g) & (self.ridge_ == lam))
            self.coef_[:, cols] = self._solve(_rbf(x, x, g / x.shape[1]), t[:, cols], lam)
        return self

    @staticmethod
    def _solve(k: torch.Tensor, t: torch.Tensor, lam: float) -> torch.Tensor:
        """(K + λ M I)⁻¹ t by Cholesky (cheaper than an eigendecomposition per width)."""
        eye = torch.eye(len(k), dtype=k.dtype)
        return torch.cholesky_solve(t, torch.linalg.cholesky(k + lam * len(k) * eye))

    def predict(self, z: np.ndarray) -> np.ndarray:
        """(M', nz) latents -> (M', ny) predicted targets."""
        x = torch.as_tensor((np.asarray(z, np.float64) - self.mean_) / self.scale_)
        out = torch.zeros(len(x), self.coef_.shape[1], dtype=torch.float64)
        for g in sorted(set(self.gamma_)):
            cols = torch.as_tensor(self.gamma_ == g)
            out[:, cols] = _rbf(x, self.centres_, g / x.shape[1]) @ self.coef_[:, cols]
        return out.numpy() * self.y_scale_ + self.y_mean_


@torch.no_grad()
def position_errors(model: LatentModel | None, data: SequenceData, normalizer: Normalizer,
                    levels: tuple[float, float] | None = None,
                    predictions: list[torch.Tensor] | None = None
                    ) -> dict[str, list[float] | float]:
    """Block position error (cm, mean over every start t with t + h <= T of every
    trajectory of ``data``) at horizon h = 1..T (index h − 1).

    Returns ``reader`` (reading the true images; the measure's own floor, over all frames),
    ``still`` per h ("nothing moves": the block where image t shows it, against the true pose
    at t + h), and, given a model, ``recon`` (its reconstructions dec(enc(x_t))) and
    ``model`` per h (its decoded open-loop predictions from x_t with the true actions).
    ``predictions``: item t the model's normalised predictions from x_t, (N, T-t+1, C, S, S)
    (:func:`latent_sindy.study.evaluation.rollouts`), when already made.
    """
    cfg = data.world_config
    levels = levels if levels is not None else block_levels(cfg)
    seen = block_position(data.images, cfg, levels)  # (N, T+1, 2)
    steps = data.steps
    still = [float(np.nanmean(_cm(seen[:, :-h], data.poses[:, h:]))) for h in range(1, steps + 1)]
    out: dict[str, list[float] | float] = {
        "reader": float(np.nanmean(_cm(seen, data.poses))), "still": still}
    if model is None:
        return out
    model.eval()
    x = normalizer.normalize(data.images)  # (N, T+1, C, S, S)
    u = torch.as_tensor(data.actions, dtype=torch.float32)  # (N, T, nu)
    sums, counts = np.zeros(steps), np.zeros(steps)
    recon = []
    for t in range(steps):
        rollout = predictions[t] if predictions is not None else model.predict(x[:, t], u[:, t:])
        pred = normalizer.denormalize(rollout).numpy()  # (N, T-t+1, C, S, S)
        xy = block_position(pred, cfg, levels)  # (N, T-t+1, 2)
        err = _cm(xy[:, 1:], data.poses[:, t + 1:])  # (N, T-t); NaN: no block in the image
        # A diverged prediction (non-finite pixels) counts as infinitely far, never left out.
        finite = np.isfinite(pred.reshape(*pred.shape[:2], -1)).all(-1)[:, 1:]
        err = np.where(finite, err, np.inf)
        sums[: steps - t] += np.nansum(err, axis=0)
        counts[: steps - t] += (~np.isnan(err)).sum(axis=0)
        recon.append(_cm(xy[:, 0], data.poses[:, t]))
    last = normalizer.denormalize(model.decode(model.encode(x[:, steps]))).numpy()
    recon.append(_cm(block_position(last, cfg, levels), data.poses[:, steps]))
    out["recon"] = float(np.nanmean(np.concatenate(recon)))
    out["model"] = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan).tolist()
    return out


def state_position_errors(data: SequenceData, predictions: list[torch.Tensor]
                          ) -> dict[str, list[float] | float]:
    """Block position error (cm) of a state-space model's open-loop predictions, averaged as
    :func:`position_errors` averages (every start t with t + h <= T), so the two compare.

    ``predictions``: item t the predicted encoded poses from the true pose at t,
    (N, T-t+1, 4) (:func:`latent_sindy.study.evaluation.rollouts`). A state model sees
    the pose itself: ``recon`` is 0, and ``still`` ("nothing moves") is the true pose at t
    against that at t + h. A non-finite prediction counts as infinitely far.
    """
    steps = data.steps
    still = [float(np.mean(_cm(data.poses[:, :-h, :2], data.poses[:, h:])))
             for h in range(1, steps + 1)]
    sums, counts = np.zeros(steps), np.zeros(steps)
    for t in range(steps):
        pred = predictions[t].double().numpy()[:, 1:, :2]  # (N, T-t, 2)
        err = _cm(pred, data.poses[:, t + 1:])
        err = np.where(np.isfinite(pred).all(-1), err, np.inf)
        sums[: steps - t] += err.sum(axis=0)
        counts[: steps - t] += err.shape[0]
    return {"recon": 0.0, "still": still, "model": (sums / np.maximum(counts, 1)).tolist()}
