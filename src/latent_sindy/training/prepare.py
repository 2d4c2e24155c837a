"""The tensors a fit trains on, cut from the data as the settings ask, and the model's start:
its data statistics and, for SINDy on fixed latents, the sparse-regression coefficients.
A continuous-time model trains on single frames with their time derivatives instead
(:func:`derivative_samples`: :class:`~latent_sindy.training.samples.DerivativeSamples`), or,
behind a principal-component front, on their coordinates on it (``CoordinateSamples``).

    tensors = training_tensors(model, data, normalizer, cfg, torch.device("cpu"))
    fit(model, opt, gen, tensors.train, tensors.val, cfg, per_batch=tensors.per_batch)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import torch

from latent_sindy.data import SequenceData
from latent_sindy.data.windows import Normalizer, WindowDataset
from latent_sindy.errors import UserError
from latent_sindy.models.derivatives import estimate_derivatives
from latent_sindy.models.latent_model import LatentModel
from latent_sindy.models.reward_head import Targets
from latent_sindy.sindy import STLSQ
from latent_sindy.training.config import TrainConfig, auto_batch_size, resolve_batching
from latent_sindy.training.fit_loop import ENCODE_CHUNK
from latent_sindy.training.samples import CoordinateSamples, DerivativeSamples, Samples, Sequences

__all__ = [
    "STENCIL_SPAN",
    "TrainingTensors",
    "derivative_samples",
    "derivative_source",
    "fit_after",
    "frame_windows",
    "new_model",
    "regression_init",
    "settle_model",
    "settle_settings",
    "stencil_stride",
    "stencil_tensors",
    "training_tensors",
]


def settle_settings(cfg: TrainConfig, data: SequenceData) -> TrainConfig:
    """``cfg`` with what it leaves to the data chosen: the batch size (None: about
    :data:`~latent_sindy.training.config.UPDATES_PER_EPOCH` updates an epoch over the
    training split's windows, or a continuous-time model's frames); UserError where the
    window is longer than the sequences."""
    if cfg.window > data.steps:
        raise UserError(f"--window {cfg.window} is longer than the sequences of {data.source} "
                        f"({data.steps} steps): use 1..{data.steps}")
    if cfg.batch_size is not None:
        return cfg
    n = data.split("train").n
    if cfg.model.dynamics.kind == "continuous":
        samples = n * (data.steps + 1)
    else:
        samples = n * max(1, data.steps - cfg.window + 1)
    return replace(cfg, batch_size=auto_batch_size(samples))


def new_model(model_cfg, cfg: TrainConfig, device: torch.device
              ) -> tuple[LatentModel, torch.optim.Optimizer, torch.Generator]:
    """A freshly initialised model (seeded by ``cfg.seed``, on the CPU so that every device
    starts from the same weights, then moved), its AdamW optimiser and the mini-batch
    generator (the only randomness after the initialisation)."""
    with torch.random.fork_rng(devices=[]):  # seeded init without touching the caller's RNG
        torch.manual_seed(cfg.seed)
        model = LatentModel(model_cfg)
    model.to(device)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, betas=cfg.betas,
                            weight_decay=cfg.weight_decay)
    return model, opt, torch.Generator().manual_seed(cfg.seed)


@dataclass
class TrainingTensors:
    """What :func:`~latent_sindy.training.fit_loop.fit` trains and validates on."""

    train: Samples
    """Sequences (windows or whole trajectories), or a continuous-time model's samples."""
    val: Samples | None
    per_batch: int
    prime: Callable[[LatentModel], None] | None = None
    """Give another fresh model of the same config what these tensors gave theirs (its data
    statistics, its SINDy start), without building the tensors again (several starts)."""


def regression_init(cfg: TrainConfig, model: LatentModel) -> bool:
    """Whether SINDy's coefficients start at the sparse-regression fit (``sindy_init``);
    UserError where a setting would be ignored."""
    sindy = model.dynamics.sparse
    if cfg.sindy_init == "regression" and model.dynamics.continuous:
        raise UserError("--sindy-init regression fits transitions; continuous-time dynamics "
                        "are trained on derivatives: use --sindy-init random or auto")
    if cfg.sindy_init == "regression" and not sindy:
        raise UserError(f"--sindy-init regression fits SINDy coefficients, but the model's "
                        f"dynamics are {model.dynamics.kind}: drop --sindy-init")
    fixed = model.config.observation.fixed_encoder  # its latents are data
    if cfg.sindy_init == "regression" and not fixed:
        raise UserError("--sindy-init regression fits the dynamics to fixed latents, but "
                        "this model's encoder learns: use --sindy-init random or auto, or "
                        "the state or moments encoder")
    regression = sindy and cfg.sindy_init != "random" and fixed and (
        not model.dynamics.continuous)
    if cfg.sindy_fit == "after" and (not sindy or model.dynamics.continuous):
        raise UserError("--sindy-fit after fits SINDy coefficients to the trained encoder's "
                        "transitions: use it with discrete-time SINDy dynamics, or drop it")
    if cfg.sindy_init_share > 0 and not regression and cfg.sindy_fit != "after":
        raise UserError(f"--sindy-init-share {cfg.sindy_init_share} is for a SINDy "
                        "model that starts from regression (a state or moments encoder, "
                        "--sindy-init auto or regression) or --sindy-fit after: drop it")
    return regression


@torch.no_grad()
def fit_dynamics(model: LatentModel, x: torch.Tensor, u: torch.Tensor,
                 device: torch.device, min_share: float) -> None:
    """Sparse regression (STLSQ at ``min_share``) of every encoded training transition
    (x (N, T+1, ..), u (N, T, nu)) on the SINDy library: the coefficients and the mask
    training starts from."""
    frames = x.flatten(0, 1)
    z = torch.cat([model.encode(frames[i:i + ENCODE_CHUNK].to(device))
                   for i in range(0, len(frames), ENCODE_CHUNK)]).reshape(*x.shape[:2], -1)
    nz, nu = z.shape[-1], u.shape[-1]
    model.dynamics.fit_state_data(z[:, :-1].reshape(-1, nz), u.to(device).reshape(-1, nu),
                                  z[:, 1:].reshape(-1, nz), optimizer=STLSQ(min_share=min_share))


#: The moment order a mask_moments encoder is first fitted at when the data chooses it.
PROVISIONAL_ORDER = 2


def choose_moment_order(model_cfg, data: SequenceData, norm: Normalizer, cfg: TrainConfig,
                        device: torch.device):
    """``model_cfg`` (resolved but for the order) with a mask_moments encoder's
    ``moment_order`` 0 chosen from the data: ``cfg.order_epochs`` of training at order
    :data:`PROVISIONAL_ORDER` (same seed, loss and batches), then the trained encoder's
    :meth:`~latent_sindy.models.encoders.MaskMomentEncoder.symmetry_order` on the training
    images; any other config as it is."""
    from latent_sindy.training.fit_loop import fit

    if not getattr(model_cfg.observation, "order_from_data", False):
        return model_cfg
    first = model_cfg.with_moment_order(PROVISIONAL_ORDER)
    short = replace(cfg, epochs=cfg.order_epochs, refine_epochs=0, prune_every=0,
                    sindy_fit="joint")
    model, opt, gen = new_model(first, short, device)
    regression_init(cfg, model)  # the real fit's settings refused before the short one
    tensors = training_tensors(model, data, norm, short, device)
    result = fit(model, opt, gen, tensors.train, tensors.val, short, per_batch=tensors.per_batch)
    model.load_state_dict(result.state)
    model.eval()
    images = WindowDataset(data.split("train"), 1, norm, "image").images.flatten(0, 1)
    with torch.no_grad():
        order = model.autoencoder.encoder.symmetry_order(images[:ENCODE_CHUNK].to(device))
    return model_cfg.with_moment_order(order)


def settle_model(record: dict, data: SequenceData, norm: Normalizer, cfg: TrainConfig,
                 device: torch.device, earlier: dict | None = None):
    """The model config of a run's ``record`` with what training chooses from the data
    chosen (:func:`choose_moment_order`) and written back into ``record["model"]``;
    ``earlier``: the record of the run being resumed, whose choice stands."""
    import json

    from latent_sindy.configs import from_json, to_json
    from latent_sindy.models.latent_model import ModelConfig

    model_cfg = from_json(ModelConfig, record["model"], "model")
    if not getattr(model_cfg.observation, "order_from_data", False):
        return model_cfg
    if earlier is not None:
        model_cfg = from_json(ModelConfig, earlier["model"], "model")
    else:
        model_cfg = choose_moment_order(model_cfg, data, norm, cfg, device)
    record["model"] = json.loads(json.dumps(to_json(model_cfg)))
    return model_cfg


def fit_after(model: LatentModel, data: SequenceData, norm: Normalizer, cfg: TrainConfig,
              device: torch.device) -> None:
    """``--sindy-fit after``: the trained encoder's training transitions fitted by STLSQ at
    ``cfg.sindy_init_share`` (the coefficients and the mask; the encoder as it is)."""
    windows = WindowDataset(data.split("train"), 1, norm, model.config.observation.kind)
    model.eval()
    fit_dynamics(model, *windows.trajectories(), device, cfg.sindy_init_share)


def training_tensors(model: LatentModel, data: SequenceData, norm: Normalizer,
                     cfg: TrainConfig, device: torch.device, fresh: bool = True,
                     regression: bool = False) -> TrainingTensors:
    """The training and validation tensors of ``data`` on ``device``; for a ``fresh`` model
    (not resumed) also its data statistics and, with ``regression``, its SINDy start."""
    if model.dynamics.continuous and derivative_source(
            cfg, data, model.dynamics.derivative_order) == "latent":
        return stencil_tensors(model, data, norm, cfg, device, fresh)
    if model.dynamics.continuous:
        order = model.dynamics.derivative_order
        train = derivative_samples(data.split("train"), norm, order, cfg)
        val = data.split("val")
        samples = derivative_samples(val, norm, order, cfg) if val.n else None
        if fresh:
            model.fit_statistics(train.frames[:, 0].to(device), None)
        front = model.front()
        if front is None:
            def prime_continuous(m: LatentModel) -> None:
                m.fit_statistics(train.frames[:, 0].to(device), None)

            return TrainingTensors(train.to(device), None if samples is None else
                                   samples.to(device), cfg.batch_size, prime_continuous)
        # Behind a principal-component front the frames train as their coordinates on it
        # (the same loss up to rounding, without the pixels); another start gets this front.
        maps = [(m.weight.clone(), m.bias.clone()) for m in front]

        def prime_front(m: LatentModel) -> None:
            for target, (weight, bias) in zip(m.front(), maps, strict=True):
                target.set(weight, bias)

        return TrainingTensors(
            CoordinateSamples.of(train.to(device), model),
            None if samples is None else CoordinateSamples.of(samples.to(device), model),
            cfg.batch_size, prime_front)
    kind = model.config.observation.kind
    train_windows = WindowDataset(data.split("train"), cfg.window, norm, kind)
    by_trajectory = resolve_batching(cfg) == "trajectories"
    if by_trajectory:  # (N, T+1, ..), (N, T, nu)
        x, u = train_windows.trajectories()
        per_batch = max(1, cfg.batch_size // (data.steps - cfg.window + 1))
    else:  # (W, H+1, ..), (W, H, nu)
        x, u = train_windows.tensors()
        per_batch = cfg.batch_size
    x, u = x.to(device), u.to(device)
    val = data.split("val")
    val_windows = WindowDataset(val, cfg.window, norm, kind) if val.n else None
    xv, uv = ((t.to(device) for t in val_windows.tensors()) if val_windows else (None, None))
    s = sv = None  # the true state features of x and xv: a pose head's privileged data
    if model.pose_head is not None:
        s = (train_windows.poses if by_trajectory else train_windows.pose_tensors()).to(device)
        sv = val_windows.pose_tensors().to(device) if val_windows else None
    if model.reward_head is not None:  # and the rewards beside them, for a reward head
        r = train_windows.rewards if by_trajectory else train_windows.reward_tensors()
        s = Targets(s, r).to(device)
        sv = Targets(sv, val_windows.reward_tensors()).to(device) if val_windows else None
    def prime(m: LatentModel) -> None:
        m.fit_statistics(train_windows.images.to(device),
                         train_windows.poses if m.pose_head is not None else None)
        if regression:
            fit_dynamics(m, *train_windows.trajectories(), device, cfg.sindy_init_share)

    if fresh:  # a resumed model has its statistics in its state
        prime(model)
    return TrainingTensors(Sequences(x, u, s), None if xv is None else Sequences(xv, uv, sv),
                           per_batch, prime)


def derivative_source(cfg: TrainConfig, data: SequenceData, order: int | None = None) -> str:
    """Where a continuous-time model's derivatives come from: "given" (the data's exact
    ones), "latent" (the encoder's latents of nearby frames differentiated) or a method
    that differentiates the frames ("central", "smooth"). ``--derivatives auto``: the
    data's where it has them, else the latent's (central differences of the frames for
    sequences too short for a stencil, under five frames). ``order``: the model's
    derivative order (None: ``cfg``'s model's)."""
    order = cfg.model.dynamics.derivative_order if order is None else order
    given = [data.images_dot, data.images_ddot][:order]
    if cfg.derivatives == "auto":
        if all(g is not None for g in given):
            return "given"
        return "latent" if data.steps + 1 >= 5 else "central"
    return cfg.derivatives


#: The latent's stencil spans about this much of the motion's time (h ω, the model's time
#: unit standing for 1/ω), where the frames allow: its fourth-order differences are then
#: within (ωh)^4/90 < 1e-4 of z̈, and pixel noise is averaged over more time than dt.
STENCIL_SPAN = 0.3


def stencil_stride(unit: float, dt: float, frames: int) -> int:
    """Frames between a stencil's five points: near :data:`STENCIL_SPAN` · ``unit`` / ``dt``,
    at least 1, at most (frames − 1) // 8 so that half of each sequence's frames are
    centres."""
    want = round(STENCIL_SPAN * unit / dt)
    return max(1, min(want, max(1, (frames - 1) // 8)))


def frame_windows(data: SequenceData, norm: Normalizer, stride: int
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``data``'s frames normalised, one after another (N (T+1), C, H, W), the indices of
    every window of five frames ``stride`` apart within a sequence (B, 5), and the action
    acting at each window's middle frame (B, nu) (the last frame keeps the last action)."""
    n, f = data.n, data.steps + 1
    frames = norm.normalize(data.images).flatten(0, 1)
    centres = torch.arange(2 * stride, f - 2 * stride)
    offsets = stride * torch.arange(-2, 3)
    idx = (torch.arange(n)[:, None, None] * f + centres[None, :, None]
           + offsets[None, None, :]).flatten(0, 1)  # (B, 5)
    a = torch.as_tensor(data.actions, dtype=torch.float32)  # (N, T, nu)
    u = torch.cat([a, a[:, -1:]], 1).flatten(0, 1)[idx[:, 2]]
    frames = frames.masked_fill(frames.abs() < torch.finfo(frames.dtype).tiny, 0.0)
    return frames, idx, u


def stencil_tensors(model: LatentModel, data: SequenceData, norm: Normalizer,
                    cfg: TrainConfig, device: torch.device, fresh: bool) -> TrainingTensors:
    """A continuous-time model's tensors on frames without derivatives: windows of five
    frames (``DerivativeSamples`` with ``stencil`` h), or behind a principal-component
    front their coordinates, each frame projected once (``CoordinateSamples``)."""
    dyn = model.dynamics
    train, val = data.split("train"), data.split("val")
    dt = float(data.dt)
    stride = stencil_stride(dyn.time_unit, dt, data.steps + 1)
    h = stride * dt
    parts = [frame_windows(train, norm, stride)]
    if val.n and val.steps + 1 > 4 * stride:
        parts.append(frame_windows(val, norm, stride))
    if fresh:
        model.fit_statistics(parts[0][0].to(device), None)
    front = model.front()
    if front is None:
        samples = [DerivativeSamples(f[i], u, h).to(device) for f, i, u in parts]

        def prime_frames(m: LatentModel) -> None:
            m.fit_statistics(parts[0][0].to(device), None)

        return TrainingTensors(samples[0], samples[1] if len(samples) > 1 else None,
                               cfg.batch_size, prime_frames)
    maps = [(m.weight.clone(), m.bias.clone()) for m in front]

    def prime_front(m: LatentModel) -> None:
        for target, (weight, bias) in zip(m.front(), maps, strict=True):
            target.set(weight, bias)

    coords = []
    for f, i, u in parts:
        c, left = model.coordinates(f.to(device)[:, None])  # (M, 1, K), (M, 1)
        i = i.to(device)
        coords.append(CoordinateSamples(c[:, 0][i], u.to(device), left[:, 0][i], h))
    return TrainingTensors(coords[0], coords[1] if len(coords) > 1 else None, cfg.batch_size,
                           prime_front)


def derivative_samples(data: SequenceData, norm: Normalizer, order: int, cfg: TrainConfig
                       ) -> DerivativeSamples:
    """Every frame of ``data`` with its ``order`` time derivatives, normalised as the frames
    (derivatives divided by the pixel std), frames (N (T+1), 1 + order, C, H, W), and the
    action acting at it, actions (N (T+1), nu) (the last frame keeps the last action). The
    derivatives are the data's where it has them and ``cfg.derivatives`` is "auto", else
    estimated from the frames (:func:`~latent_sindy.models.derivatives.estimate_derivatives`,
    ``data.dt`` apart).
    """
    given = [data.images_dot, data.images_ddot][:order] if cfg.derivatives == "auto" else []
    if len(given) == order and all(g is not None for g in given):
        rates = [np.asarray(g, np.float32) for g in given]
    else:
        method = "central" if cfg.derivatives == "auto" else cfg.derivatives
        exact = given[0] if given and order == 2 else None  # ẍ then from the exact ẋ
        rates = list(estimate_derivatives(data.images, data.dt, order, method,
                                          cfg.derivative_window, dx=exact))
    parts = [norm.normalize(data.images)]
    parts += [torch.as_tensor(r) / norm.std for r in rates]
    x = torch.stack(parts, 2).flatten(0, 1)  # (N (T+1), 1 + order, C, H, W)
    # Subnormal values (a rendered blob's tails, ~1e-40) make every product with them 10x
    # slower on CPUs: on the pendulum video, 5.0 s against 0.41 s a step at batch 1000.
    x = x.masked_fill(x.abs() < torch.finfo(x.dtype).tiny, 0.0)
    a = torch.as_tensor(data.actions, dtype=torch.float32)  # (N, T, nu)
    u = torch.cat([a, a[:, -1:]], 1).flatten(0, 1)  # (N (T+1), nu)
    return DerivativeSamples(x, u)
