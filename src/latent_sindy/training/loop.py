"""The training loop: a latent model (autoencoder + SINDy, linear or MLP dynamics) on a
trajectory file, written into a run folder (:mod:`latent_sindy.training.runs`).

The paper's recipe (docs/design.md): AdamW on the loss of
:meth:`~latent_sindy.models.latent_model.LatentModel.loss` over windows of ``window`` pushes,
mini-batches (of windows, or of whole trajectories whose frames are encoded once: ``batching``)
shuffled by a generator seeded from ``seed``, and every ``threshold_every`` epochs
SINDy coefficients with ``|Ψ| < threshold`` are pruned for good (the mask only turns off).
``resume=True`` continues from the run's checkpoint to the same final model, bit for bit on
CPU (for the same torch thread count), as an uninterrupted run with the same settings. The
validation loss is computed every ``eval_every`` epochs (it never changes the training). With
``keep_best`` (the default) the saved model is that of the validated epoch with the lowest
validation objective among those since the last pruning that removed a term, so it has the
final sparsity mask (:class:`BestValidation`); the checkpoint carries it. On CUDA
(``device``) the same code runs with the data, model and optimiser on the GPU; the shuffling
generator stays on the CPU, so both devices see the same mini-batches.

    latent-sindy train sindy --order 2 --data data/push.h5 --out runs/sindy2
"""

from __future__ import annotations

import contextlib
import ctypes
import dataclasses
import functools
import json
import math
import time
from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import torch

from latent_sindy.atomic import check_memory
from latent_sindy.configs import from_json, to_json
from latent_sindy.data.store import Trajectories, read_trajectories
from latent_sindy.data.windows import OBSERVATIONS, Normalizer, WindowDataset
from latent_sindy.errors import UserError
from latent_sindy.models.latent_model import LOSS_TERMS, LatentModel, LossWeights, ModelConfig
from latent_sindy.plots import loss_histories
from latent_sindy.progress import Progress, Silent
from latent_sindy.sindy import STLSQ
from latent_sindy.training.config import (
    TrainConfig,
    resolve_batching,
    resolve_device,
    resolve_parallel,
)
from latent_sindy.training.runs import METRIC_COLUMNS, RUN_FORMAT, RUN_FORMAT_VERSION, RunDir
from latent_sindy.worlds.push.camera import moment_frame

__all__ = ["BestValidation", "TrainingDiverged", "evaluate", "run_record", "train"]


class TrainingDiverged(UserError):
    """A loss term or a parameter became NaN or infinite."""


# ----------------------------------------------------------------------------- the run record
def _data_identity(data: Trajectories, path: Path) -> dict[str, Any]:
    return {
        "path": str(path.resolve()),
        "fingerprint": data.fingerprint(),
        "seed": data.seed,
        "trajectories": data.n,
        "steps": data.steps,
        "splits": data.split_counts(),
    }


def run_record(cfg: TrainConfig, data: Trajectories) -> dict[str, Any]:
    """What RUN/config.json holds for training ``cfg`` on ``data`` (JSON values).

    Resolves the model's shapes from the data; raises UserError where they contradict it.
    """
    from latent_sindy import __version__

    _, _, channels, size, _ = data.images.shape
    model_cfg = cfg.model.resolve(channels, size, data.actions.shape[-1], source=str(cfg.data))
    if getattr(model_cfg.encoder, "encoder", None) == "moments":
        _check_symmetry("--moment-order", model_cfg.encoder.moment_order, data, cfg.data)
    library = getattr(model_cfg.dynamics, "library", None)
    if library in ("face", "frame"):
        _check_symmetry("--angle-frequency", model_cfg.dynamics.angle_frequency, data,
                        cfg.data)
    if library is not None:
        model_cfg = _resolve_frame(model_cfg, data, cfg.data)
    if library in ("face", "frame") and data.env_config.push != "symmetric":
        raise UserError(f"--library {library} writes pushes given as world directions, but "
                        f"{cfg.data} was collected with push style '{data.env_config.push}' "
                        "(the angle relative to the block): use --library push")
    record = {
        "format": RUN_FORMAT,
        "format_version": RUN_FORMAT_VERSION,
        "package_version": __version__,
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        "train": to_json(cfg),
        "batching": resolve_batching(cfg),  # what train.batching ("auto") batched
        "model": to_json(model_cfg),
        "normalizer": OBSERVATIONS[model_cfg.encoder.kind].normalizer(data).to_dict(),
        "data": _data_identity(data, cfg.data),
        "env": to_json(data.env_config),  # the world the images came from, for control
    }
    return json.loads(json.dumps(record))  # as config.json will hold it


def _prepare(run: RunDir, cfg: TrainConfig, record: dict[str, Any]) -> dict[str, Any] | None:
    """Check the run folder against the resume/overwrite flags, before anything is touched;
    returns the checkpoint to resume from. Nothing is removed here (see :func:`train`)."""
    if run.path.exists() and not run.path.is_dir():
        raise UserError(f"--out {run.path} is a file; give a folder for the run")
    if cfg.overwrite:
        return None
    if cfg.resume:
        if (run / run.CONFIG).exists():
            diffs = run.differences(record)
            if diffs:
                raise UserError(
                    f"cannot resume {run.path}: settings differ from its {run.CONFIG}: "
                    f"{'; '.join(diffs)}. Resume with the run's settings or start over "
                    "with --overwrite")
        if (run / run.CHECKPOINT).exists():
            ckpt = run.load_torch(run.CHECKPOINT)
            if ckpt["epoch"] > cfg.epochs:
                raise UserError(
                    f"{run / run.CHECKPOINT} is at epoch {ckpt['epoch']}, past --epochs "
                    f"{cfg.epochs}: resume with --epochs {ckpt['epoch']} or more")
            return ckpt
        if run.finished:
            raise UserError(f"cannot resume {run.path}: it has {run.MODEL} but no "
                            f"{run.CHECKPOINT}; start over with --overwrite")
    elif run.finished:
        raise UserError(
            f"{run.path} already holds a trained model ({run / run.MODEL}): pass --resume to "
            "train it for more epochs, --overwrite to replace it, or choose another --out")
    elif run.interrupted:
        raise UserError(f"{run.path} holds an interrupted run ({run / run.CHECKPOINT}): pass "
                        "--resume to continue it or --overwrite to start over")
    return None


# ----------------------------------------------------------------------------- training
@torch.inference_mode()
def evaluate(
    model: LatentModel,
    x: torch.Tensor,
    u: torch.Tensor,
    weights: LossWeights | None = None,
    batch_size: int = 500,
    poses: torch.Tensor | None = None,
) -> dict[str, float]:
    """Mean loss terms over windows x (W, H+1, C, S, S), u (W, H, nu), in batches (on the
    device of the model and the windows); ``poses`` (W, H+1, 4) for a pose head's term."""
    was_training = model.training
    model.eval()
    sums = torch.zeros(len(LOSS_TERMS), dtype=torch.float64)
    for b in range(0, len(x), batch_size):
        s = None if poses is None else poses[b : b + batch_size]
        terms = model.loss(x[b : b + batch_size], u[b : b + batch_size], weights, s)
        values = torch.stack([terms[k] for k in LOSS_TERMS]).double().cpu()
        sums += values * len(x[b : b + batch_size])
    model.train(was_training)
    return dict(zip(LOSS_TERMS, (sums / max(len(x), 1)).tolist(), strict=True))


def _diverged(cfg: TrainConfig, epoch: int, what: str, last_ckpt: int | None) -> TrainingDiverged:
    kept = (
        f"the last good checkpoint is {cfg.out / RunDir.CHECKPOINT} (epoch {last_ckpt})"
        if last_ckpt
        else "no checkpoint was written yet"
    )
    return TrainingDiverged(
        f"training diverged at epoch {epoch}: {what} is not finite; {kept}. "
        f"Lower --lr (now {cfg.lr}) and start over with --overwrite"
    )


class _Gradients:
    """Loss terms and gradients of one mini-batch, on one thread or split across several.

    With ``parts`` > 1 the batch is cut into that many slices whose losses and gradients
    that many threads compute at once, each with one torch thread (torch's own threads are
    set to 1 until :meth:`close`), and the gradients are added in slice order; the loss terms
    are means, so each slice counts by its share of the sequences. Deterministic: every
    slice runs single-threaded and the sums have a fixed order. With ``parts`` = 1 it is one
    ``loss(...).backward()``.
    """

    def __init__(self, model: LatentModel, parts: int) -> None:
        self.model, self.parts = model, parts
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

    def __call__(self, x: torch.Tensor, u: torch.Tensor, weights: LossWeights,
                 poses: torch.Tensor | None, window: int) -> dict[str, torch.Tensor]:
        """Set every parameter's ``.grad`` to d total / d parameter on sequences x, u;
        returns the loss terms (detached)."""
        if self._pool is None or len(x) < 2:
            terms = self.model.loss(x, u, weights, poses, window=window)
            for p in self.params:
                p.grad = None
            terms["total"].backward()
            return {k: v.detach() for k, v in terms.items()}
        bounds = torch.linspace(0, len(x), min(self.parts, len(x)) + 1).round().long().tolist()

        def part(a: int, b: int) -> tuple[dict[str, torch.Tensor], tuple]:
            share = (b - a) / len(x)
            terms = self.model.loss(x[a:b], u[a:b], weights,
                                    None if poses is None else poses[a:b], window=window)
            g = torch.autograd.grad(terms["total"] * share, self.params, allow_unused=True)
            return {k: v.detach() * share for k, v in terms.items()}, g

        results = list(self._pool.map(part, bounds[:-1], bounds[1:]))
        terms = {k: functools.reduce(torch.add, [r[0][k] for r in results])
                 for k in results[0][0]}
        for i, p in enumerate(self.params):
            gs = [r[1][i] for r in results if r[1][i] is not None]
            p.grad = None if not gs else functools.reduce(torch.add, gs)
        return terms


def _train_epoch(
    grads: _Gradients,
    opt: torch.optim.Optimizer,
    x: torch.Tensor,
    u: torch.Tensor,
    cfg: TrainConfig,
    per_batch: int,
    gen: torch.Generator,
    epoch: int,
    last_ckpt: int | None,
    poses: torch.Tensor | None = None,
) -> dict[str, float]:
    """One shuffled pass over sequences x (N, T+1, ...), u (N, T, nu) (windows or whole
    trajectories), ``per_batch`` of them per batch; mean loss terms per sequence (as seen
    before each batch's update). ``poses`` (N, T+1, 4): the sequences' true pose features,
    for a pose head."""
    weights = cfg.loss
    # The generator lives on the CPU: the same mini-batches on every device.
    order = torch.randperm(len(x), generator=gen).to(x.device)
    sums = torch.zeros(len(LOSS_TERMS), dtype=torch.float64)
    for b in range(0, len(x), per_batch):
        idx = order[b : b + per_batch]
        terms = grads(x[idx], u[idx], weights, None if poses is None else poses[idx],
                      cfg.window)
        values = torch.stack([terms[k] for k in LOSS_TERMS])  # (7,)
        if not torch.isfinite(values).all():
            bad = next(
                k
                for k in ("recon", "pred_x", "pred_z", "l1", "pose", "total")
                if not torch.isfinite(terms[k])
            )
            value = float(terms[bad])
            raise _diverged(cfg, epoch, f"loss term {bad} ({value})", last_ckpt)
        opt.step()
        sums += values.double().cpu() * len(idx)
    for name, p in grads.model.named_parameters():
        if not torch.isfinite(p).all():
            raise _diverged(cfg, epoch, f"parameter {name}", last_ckpt)
    return dict(zip(LOSS_TERMS, (sums / len(x)).tolist(), strict=True))


@torch.no_grad()
def _prune(model: LatentModel, opt: torch.optim.Optimizer, tau: float) -> int:
    """Threshold SINDy coefficients; clear AdamW's moments of pruned entries so Ψ stays 0."""
    dyn = model.dynamics
    pruned = dyn.threshold(tau)
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
        self.epoch, self.objective, self.state, self.since = None, math.inf, None, epoch

    def offer(self, epoch: int, objective: float, model: torch.nn.Module) -> bool:
        """Keep ``model``'s weights if ``objective`` is the lowest so far (ties: the earlier)."""
        if objective >= self.objective:
            return False
        self.epoch, self.objective = epoch, objective
        self.state = {k: v.detach().clone() for k, v in model.state_dict().items()}
        return True

    def to_checkpoint(self) -> dict[str, Any]:
        return {"epoch": self.epoch, "objective": self.objective, "since": self.since,
                "model": None if self.state is None else _cpu(self.state)}

    @classmethod
    def from_checkpoint(cls, saved: dict[str, Any] | None, device: torch.device,
                        resumed_at: int) -> BestValidation:
        """Rebuilt from :meth:`to_checkpoint`; ``saved`` None (a checkpoint written before
        selection existed): candidates start after ``resumed_at``."""
        best = cls()
        if saved is None:
            best.since = resumed_at + 1
            return best
        best.epoch, best.objective, best.since = saved["epoch"], saved["objective"], saved["since"]
        if saved["model"] is not None:
            best.state = {k: v.to(device) for k, v in saved["model"].items()}
        return best


_MEMORY_KEPT = False


def _keep_freed_memory() -> None:
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


def _cpu(obj: Any) -> Any:
    """A state dict (nested dicts and lists of tensors) with every tensor on the CPU, so that
    run files load anywhere."""
    if isinstance(obj, torch.Tensor):
        return obj.cpu()
    if isinstance(obj, dict):
        return {k: _cpu(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return type(obj)(_cpu(v) for v in obj)
    return obj


def _kept(cfg: TrainConfig, best: BestValidation, metrics: list[dict[str, Any]]
          ) -> dict[str, Any]:
    """Which epoch's weights the run saves as its model, for config.json's "kept"."""
    last = metrics[-1] if metrics else {}
    if cfg.keep_best and best.state is not None:
        return {"epoch": best.epoch, "selection": "best validation",
                "val_objective": best.objective, "candidates_from": best.since}
    return {"epoch": cfg.epochs, "selection": "last epoch",
            "val_objective": last.get("val/objective"), "candidates_from": None}


def _resolve_frame(model_cfg: ModelConfig, data: Trajectories, path: Path) -> ModelConfig:
    """A SINDy config with the frame library's orientation sense and offset stated: for the
    frame library on the moments latent the data's camera's (a value given must match), else
    1 and 0 where unset (world angles; the other libraries do not read them)."""
    dyn = model_cfg.dynamics
    moments = getattr(model_cfg.encoder, "encoder", None) == "moments"
    if dyn.library == "frame" and moments:
        sense, offset = moment_frame(data.env_config)
        off = dyn.frame_offset is not None and abs(
            math.remainder(dyn.frame_offset - offset, 2 * math.pi)) > 1e-4
        if dyn.frame_sense not in (None, sense) or off:
            raise UserError(f"--library frame on the moments latent of {path}: its camera "
                            f"shows the world's angles with sense {sense} and offset "
                            f"{offset:.6f}: leave --frame-sense and --frame-offset out to "
                            f"use them, or give --frame-sense {sense} --frame-offset "
                            f"{offset:.6f}")
    else:
        sense = 1 if dyn.frame_sense is None else dyn.frame_sense
        offset = 0.0 if dyn.frame_offset is None else dyn.frame_offset
    return dataclasses.replace(model_cfg, dynamics=dataclasses.replace(
        dyn, frame_sense=sense, frame_offset=offset))


def _check_symmetry(flag: str, value: float, data: Trajectories, path: Path) -> None:
    """UserError unless ``value`` is the data's visible symmetry, 2π / its angle period."""
    f = 2 * math.pi / data.env_config.angle_period
    if abs(value - f) > 1e-9:
        raise UserError(f"{flag} {value:g} does not match {path}: its block looks alike every "
                        f"{math.degrees(data.env_config.angle_period):g}°, so use {flag} {f:g}")


def _regression_init(cfg: TrainConfig, model: LatentModel) -> bool:
    """Whether SINDy's coefficients start at the sparse-regression fit (``--sindy-init``);
    UserError where a setting would be ignored."""
    sindy = hasattr(model.dynamics, "fit_state_data")
    if cfg.sindy_init == "regression" and not sindy:
        raise UserError(f"--sindy-init regression fits SINDy coefficients, but the model's "
                        f"dynamics are {model.dynamics.kind}: drop --sindy-init")
    fixed = model.config.encoder.fixed_encoder  # its latents are data
    if cfg.sindy_init == "regression" and not fixed:
        raise UserError("--sindy-init regression fits the dynamics to fixed latents, but "
                        "this model's encoder learns: use --sindy-init random or auto, or "
                        "the state or moments encoder")
    regression = sindy and cfg.sindy_init != "random" and fixed
    if cfg.sindy_init_threshold > 0 and not regression:
        raise UserError(f"--sindy-init-threshold {cfg.sindy_init_threshold} is for a SINDy "
                        "model that starts from regression (a state or moments encoder, "
                        "--sindy-init auto or regression): drop it")
    return regression


@torch.no_grad()
def _fit_dynamics(model: LatentModel, x: torch.Tensor, u: torch.Tensor,
                  device: torch.device, threshold: float) -> None:
    """Sparse regression (STLSQ at ``threshold``) of every encoded training transition
    (x (N, T+1, ..), u (N, T, nu)) on the SINDy library: the coefficients and the mask
    training starts from."""
    z = model.encode(x.to(device).flatten(0, 1)).reshape(*x.shape[:2], -1)
    nz, nu = z.shape[-1], u.shape[-1]
    model.dynamics.fit_state_data(z[:, :-1].reshape(-1, nz), u.to(device).reshape(-1, nu),
                                  z[:, 1:].reshape(-1, nz), optimizer=STLSQ(threshold=threshold))


def train(cfg: TrainConfig, progress: Progress | None = None) -> Path:
    """Train the model `cfg` describes into the run folder ``cfg.out``; returns that folder.

    Every setting, the data and the run folder are checked before a file is written or
    removed; ``overwrite`` then removes the old run whole. Raises :class:`UserError` for
    unusable settings, data or run folders and :class:`TrainingDiverged` (a UserError) when a
    loss becomes NaN/inf; the last checkpoint stays loadable then.
    """
    progress = progress or Silent()
    device = torch.device(resolve_device(cfg.device))
    if device.type == "cpu":
        _keep_freed_memory()
    data = read_trajectories(cfg.data)
    if cfg.window > data.steps:
        raise UserError(
            f"--window {cfg.window} is longer than the trajectories of {cfg.data} "
            f"({data.steps} pushes): use 1..{data.steps}"
        )
    record = run_record(cfg, data)
    n_windows = data.n * (data.steps - cfg.window + 1)
    check_memory(4 * n_windows * (cfg.window + 1) * data.images[0, 0].size * 3,
                 f"training windows of {cfg.window} pushes", "use a smaller --window")
    run = RunDir(cfg.out)
    ckpt = _prepare(run, cfg, record)
    norm = Normalizer.from_dict(record["normalizer"])
    model_cfg = from_json(ModelConfig, record["model"], "model")

    with torch.random.fork_rng(devices=[]):  # seeded init without touching the caller's RNG
        torch.manual_seed(cfg.seed)
        model = LatentModel(model_cfg)  # initialised on the CPU: the same weights everywhere
    model.to(device)
    regression = _regression_init(cfg, model)  # (checks the settings before anything is written)
    opt = torch.optim.AdamW(
        model.parameters(), lr=cfg.lr, betas=cfg.betas, weight_decay=cfg.weight_decay
    )
    gen = torch.Generator().manual_seed(cfg.seed)  # the only randomness after the init
    threads = torch.get_num_threads()
    parallel = resolve_parallel(cfg, device.type, threads)
    metrics: list[dict[str, Any]] = []
    done = 0
    best = BestValidation()
    if ckpt is not None:
        try:
            model.load_state_dict(ckpt["model"])
            opt.load_state_dict(ckpt["optimizer"])
            gen.set_state(ckpt["generator"])
            best = BestValidation.from_checkpoint(ckpt.get("best"), device, int(ckpt["epoch"]))
        except (KeyError, RuntimeError, ValueError, TypeError) as e:
            raise UserError(
                f"{run / run.CHECKPOINT} does not fit this model ({e}); start "
                "over with --overwrite"
            ) from e
        metrics, done = list(ckpt["metrics"]), int(ckpt["epoch"])
        if "best" not in ckpt and cfg.keep_best:
            progress.note(f"{run / run.CHECKPOINT} is from before model selection: the kept "
                          f"weights are chosen among epochs {done + 1} to {cfg.epochs}")
        was = (ckpt.get("device", "cpu"), ckpt.get("threads"), ckpt.get("parallel", "ops"))
        now = (device.type, threads, parallel)
        if was[1] is not None and was != now:  # older checkpoints did not record them
            progress.note(f"resuming on {now[0]} with {now[1]} thread(s) ({now[2]}) a run "
                          f"trained on {was[0]} with {was[1]} ({was[2]}): the result will "
                          "differ in the last bits from an uninterrupted run")
    if cfg.overwrite:
        run.clear()
    run.path.mkdir(parents=True, exist_ok=True)
    run.write_record(record)
    run.write_metrics(metrics)  # drops rows logged after the checkpoint

    kind = model_cfg.encoder.kind
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
    s = sv = None  # the true pose features of x and xv: a pose head's privileged data
    if model.pose_head is not None:
        s = (train_windows.poses if by_trajectory else train_windows.pose_tensors()).to(device)
        sv = val_windows.pose_tensors().to(device) if val_windows else None
    if ckpt is None:  # a resumed model has its statistics in its state
        model.fit_statistics(train_windows.images.to(device),
                             train_windows.poses if model.pose_head is not None else None)
        if regression:
            _fit_dynamics(model, *train_windows.trajectories(), device,
                          cfg.sindy_init_threshold)
    if val.n == 0:
        progress.note(f"{cfg.data} has no validation trajectories: val/* metrics stay empty")
    sindy = hasattr(model.dynamics, "threshold")  # a sparse model: SINDy
    prune = sindy and cfg.threshold_every > 0

    last_ckpt = done or None
    model.train()
    grads = _Gradients(model, threads if parallel == "batch" else 1)
    progress.start(cfg.epochs, done)
    try:
        for epoch in range(done + 1, cfg.epochs + 1):
            t0 = time.perf_counter()
            row: dict[str, Any] = dict.fromkeys(METRIC_COLUMNS)
            row["epoch"] = epoch
            train_terms = _train_epoch(grads, opt, x, u, cfg, per_batch, gen, epoch,
                                       last_ckpt, s)
            row.update({f"train/{k}": v for k, v in train_terms.items()})
            if prune and epoch % cfg.threshold_every == 0:
                row["sindy/pruned"] = _prune(model, opt, cfg.threshold)
                if row["sindy/pruned"]:
                    best.mask_changed(epoch)
            if xv is not None and (epoch % cfg.eval_every == 0 or epoch == cfg.epochs):
                val_terms = evaluate(model, xv, uv, cfg.loss, cfg.batch_size, sv)
                if not math.isfinite(val_terms["total"]):
                    raise _diverged(cfg, epoch, "the validation loss", last_ckpt)
                row.update({f"val/{k}": v for k, v in val_terms.items()})
                # A pose head's reading is what its model plans on: it counts in the choice.
                best.offer(epoch, val_terms["objective"]
                           + cfg.loss.lambda_pose * val_terms.get("pose", 0.0), model)
            if sindy:
                row["sindy/active"] = model.dynamics.n_active()
                row["sindy/sparsity"] = model.dynamics.sparsity()
            row["time_s"] = time.perf_counter() - t0
            metrics.append(row)
            run.append_metrics(row)
            if epoch % cfg.checkpoint_every == 0 or epoch == cfg.epochs:
                run.save_torch(run.CHECKPOINT, {
                    "epoch": epoch, "model": _cpu(model.state_dict()),
                    "optimizer": _cpu(opt.state_dict()),
                    "generator": gen.get_state(), "metrics": metrics,
                    "best": best.to_checkpoint(),
                    "device": device.type, "threads": threads, "parallel": parallel})
                last_ckpt = epoch
            progress.update(epoch, row)
        kept = _kept(cfg, best, metrics)
        if kept["selection"] == "best validation":
            progress.note(f"kept the weights of epoch {kept['epoch']} of {cfg.epochs}: the "
                          f"lowest validation objective ({kept['val_objective']:.6g}) since "
                          f"epoch {kept['candidates_from']}")
    except TrainingDiverged:
        with contextlib.suppress(Exception):  # the plot is a convenience; the error matters
            loss_histories({"run": metrics}, {}, run / run.PLOT, dpi=100)
        raise
    finally:
        grads.close()
        progress.close()
    from latent_sindy import __version__

    state = best.state if kept["selection"] == "best validation" else model.state_dict()
    run.write_record({**record, "kept": kept})  # before model.pt, which marks the run finished
    run.save_torch(run.MODEL, {"epoch": kept["epoch"], "epochs": cfg.epochs,
                               "selection": kept["selection"], "model": _cpu(state),
                               "model_config": record["model"],
                               "normalizer": record["normalizer"],
                               "package_version": __version__})
    loss_histories({"run": metrics}, {}, run / run.PLOT, dpi=100)
    return run.path
