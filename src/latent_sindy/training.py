"""Train a latent model (autoencoder + SINDy, linear or MLP dynamics) on a trajectory file.

The paper's recipe (DESIGN §3): AdamW on the loss of
:meth:`~latent_sindy.models.latent_model.LatentModel.loss` over windows of ``horizon`` pushes,
mini-batches shuffled by a generator seeded from ``seed``, and every ``threshold_every`` epochs
SINDy coefficients with ``|Ψ| < threshold`` are pruned for good (the mask only turns off).

A run folder describes itself; every later command needs only it::

    RUN/config.json      TrainConfig, resolved ModelConfig, normaliser, data identity, version
    RUN/model.pt         final weights (mask included) + model config + normaliser
    RUN/checkpoint.pt    model, optimizer, epoch, shuffle-generator state, metrics so far
    RUN/metrics.csv      one row per epoch: train/*, val/*, sindy/*, time_s
    RUN/loss.png         train and validation objective per epoch (log scale)

Files are written atomically (temporary file + rename) and ``.pt`` files are read with
``torch.load(weights_only=True)`` only. ``resume=True`` continues from ``checkpoint.pt`` to
the same final model, bit for bit on CPU, as an uninterrupted run with the same settings.

    from latent_sindy.training import TrainConfig, train, load_run
    run = train(TrainConfig(data=Path("data/push.h5"), out=Path("runs/sindy2")))
    model, normalizer, cfg, env_config = load_run(run)
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import io
import json
import math
import os
import pickle
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, NamedTuple, Protocol

import torch

from latent_sindy.atomic import write_atomic
from latent_sindy.data.store import Trajectories, read_trajectories
from latent_sindy.data.windows import Normalizer, WindowDataset
from latent_sindy.envs.config import PushEnvConfig
from latent_sindy.errors import UserError, reject_unknown_fields
from latent_sindy.models.latent_model import LOSS_TERMS, LatentModel, LossWeights, ModelConfig

__all__ = [
    "METRIC_COLUMNS",
    "Progress",
    "Run",
    "TqdmProgress",
    "TrainConfig",
    "TrainingDiverged",
    "evaluate",
    "load_run",
    "plot_losses",
    "read_metrics",
    "train",
]

RUN_FORMAT = "latent-sindy-run"
RUN_FORMAT_VERSION = 1
CONFIG_FILE, MODEL_FILE, CHECKPOINT_FILE = "config.json", "model.pt", "checkpoint.pt"
METRICS_FILE, PLOT_FILE = "metrics.csv", "loss.png"
#: Files a run folder may hold; ``overwrite`` deletes exactly these.
RUN_FILES = (
    CONFIG_FILE,
    MODEL_FILE,
    CHECKPOINT_FILE,
    METRICS_FILE,
    PLOT_FILE,
    "coefficients.csv",
    "coefficients.json",
)
#: Columns of metrics.csv (empty cells: no validation split / not a SINDy model).
METRIC_COLUMNS = (
    "epoch",
    *(f"train/{t}" for t in LOSS_TERMS),
    *(f"val/{t}" for t in LOSS_TERMS),
    "sindy/active",
    "sindy/sparsity",
    "sindy/pruned",
    "time_s",
)
#: Settings that may change when resuming; everything else must match the run's config. The
#: data file may move: its identity (seed, sizes, splits, pixel statistics) is checked instead.
RESUMABLE = frozenset({"epochs", "resume", "overwrite", "checkpoint_every", "out", "data"})


@dataclass(frozen=True)
class TrainConfig:
    """Settings of one training run; with the data file they determine the final model."""

    data: Path = Path("data/push.h5")
    """Trajectory file (.h5) from `latent-sindy collect`."""
    out: Path = Path("runs/sindy")
    """Run folder to create (config, weights, checkpoint, metrics, loss plot)."""
    model: ModelConfig = field(default_factory=ModelConfig)
    """Architecture of the latent model."""
    horizon: int = 1
    """Pushes per training window H (1: the paper's single-step model)."""
    epochs: int = 300
    """Passes over the training windows (the paper: 3000; 300 trains in minutes on a CPU)."""
    batch_size: int = 500
    """Windows per mini-batch (the paper: 500)."""
    lr: float = 1e-3
    """AdamW learning rate (the paper: 1e-3)."""
    betas: tuple[float, float] = (0.9, 0.999)
    """AdamW betas (the paper: 0.9, 0.999)."""
    weight_decay: float = 0.01
    """AdamW decoupled weight decay (PyTorch's default, which the paper kept)."""
    # Loss weights. On a 60-trajectory set (SINDy order 2, 300 epochs): λ2 = 0.1 left the
    # latent prediction error 9x larger than λ2 = 1 for 6% better validation reconstruction.
    # On 100 training trajectories (conv decoder, 60 epochs): λ3 = 1e-3 pruned 90% of the
    # order-2 coefficients, 1e-2 pruned 98.5% for a 1% higher validation loss.
    lambda_pred_x: float = 1.0
    """λ1: weight of the image prediction loss, dec(ẑ_t) vs x_t."""
    lambda_pred_z: float = 1.0
    """λ2: weight of the latent prediction loss, ẑ_t vs enc(x_t) (latent MPPI relies on it)."""
    lambda_l1: float = 1e-2
    """λ3: weight of ‖M ⊙ Ψ‖₁, a sum over all coefficients (SINDy only)."""
    threshold: float = 1e-3
    """SINDy: prune coefficients with |Ψ| below this (the paper: 1e-3)."""
    threshold_every: int = 30
    """SINDy: prune every this many epochs, the last included; 0 never (the paper: 300 of 3000)."""
    checkpoint_every: int = 10
    """Write checkpoint.pt every this many epochs (and always at the end)."""
    seed: int = 0
    """Seeds the initial weights and the mini-batch order."""
    resume: bool = False
    """Continue the run in `out` from its checkpoint (settings must match; epochs may grow)."""
    overwrite: bool = False
    """Replace a finished or interrupted run in `out` instead of refusing."""

    def __post_init__(self) -> None:
        checks = (
            (self.epochs >= 1, f"--epochs {self.epochs}: train for at least 1 epoch"),
            (self.horizon >= 1, f"--horizon {self.horizon}: windows need at least 1 push"),
            (self.batch_size >= 1, f"--batch-size {self.batch_size}: use 1 or more"),
            (self.lr > 0 and math.isfinite(self.lr), f"--lr {self.lr}: use a positive number"),
            (
                all(0 <= b < 1 for b in self.betas) and len(self.betas) == 2,
                f"--betas {self.betas}: use two numbers in [0, 1)",
            ),
            (self.weight_decay >= 0, f"--weight-decay {self.weight_decay}: use 0 or more"),
            (
                min(self.lambda_pred_x, self.lambda_pred_z, self.lambda_l1) >= 0,
                "the loss weights --lambda-pred-x/--lambda-pred-z/--lambda-l1 must be >= 0",
            ),
            (self.threshold >= 0, f"--threshold {self.threshold}: use 0 or more"),
            (
                self.threshold_every >= 0,
                f"--threshold-every {self.threshold_every}: use 0 (never) or more",
            ),
            (
                self.checkpoint_every >= 1,
                f"--checkpoint-every {self.checkpoint_every}: use 1 or more",
            ),
            (self.seed >= 0, f"--seed {self.seed}: seeds are non-negative integers"),
            (
                not (self.resume and self.overwrite),
                "--resume and --overwrite contradict each other: choose one",
            ),
        )
        for ok, message in checks:
            if not ok:
                raise UserError(message)
        if not isinstance(self.model, ModelConfig):
            raise TypeError(f"TrainConfig.model must be a ModelConfig, got {type(self.model)}")

    @property
    def weights(self) -> LossWeights:
        return LossWeights(self.lambda_pred_x, self.lambda_pred_z, self.lambda_l1)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: paths as strings, the model config nested."""
        d = dataclasses.asdict(self)
        d.update(
            data=str(self.data),
            out=str(self.out),
            model=self.model.to_dict(),
            betas=list(self.betas),
        )
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> TrainConfig:
        reject_unknown_fields(cls, d, "training")
        d = dict(d)
        d.update(
            data=Path(d["data"]),
            out=Path(d["out"]),
            betas=tuple(d["betas"]),
            model=ModelConfig.from_dict(d["model"]),
        )
        return cls(**d)


class TrainingDiverged(UserError):
    """A loss term or a parameter became NaN or infinite."""


class Progress(Protocol):
    """What :func:`train` reports to: a progress bar, a logger, a test recorder."""

    def start(self, total: int, initial: int) -> None:
        """Training will run epochs initial+1..total."""

    def update(self, epoch: int, metrics: Mapping[str, float | None]) -> None:
        """Epoch `epoch` finished with this metrics row."""

    def note(self, text: str) -> None:
        """Something the user should know (e.g. no validation split)."""

    def close(self) -> None:
        """Training ended (normally or not)."""


class TqdmProgress:
    """A tqdm bar over epochs showing the current train/val objective and SINDy's terms."""

    def __init__(self, desc: str = "train") -> None:
        self.desc = desc
        self.bar: Any = None

    def start(self, total: int, initial: int) -> None:
        import sys

        from tqdm import tqdm

        self.bar = tqdm(
            total=total,
            initial=initial,
            desc=self.desc,
            unit="epoch",
            dynamic_ncols=True,
            file=sys.stderr,
        )

    def update(self, epoch: int, metrics: Mapping[str, float | None]) -> None:
        shown = {
            "train": metrics["train/objective"],
            "val": metrics["val/objective"],
            "active": metrics["sindy/active"],
        }
        self.bar.set_postfix(
            {k: f"{v:.4g}" for k, v in shown.items() if v is not None}, refresh=False
        )
        self.bar.update(1)

    def note(self, text: str) -> None:
        from tqdm import tqdm

        tqdm.write(text)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


class _Silent:
    def start(self, total: int, initial: int) -> None: ...
    def update(self, epoch: int, metrics: Mapping[str, float | None]) -> None: ...
    def note(self, text: str) -> None: ...
    def close(self) -> None: ...


class Run(NamedTuple):
    """What :func:`load_run` rebuilds from a run folder."""

    model: LatentModel
    normalizer: Normalizer
    config: TrainConfig
    env_config: PushEnvConfig


# ----------------------------------------------------------------------------- files
def _save_torch(obj: Any, path: Path) -> None:
    write_atomic(path, lambda f: torch.save(obj, f))


def _load_torch(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise UserError(f"{path} does not exist")
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except (RuntimeError, OSError, EOFError, ValueError, pickle.UnpicklingError) as e:
        raise UserError(
            f"{path} is damaged or not a latent-sindy file ({type(e).__name__}); retrain the run"
        ) from e
    if not isinstance(obj, dict) or obj.get("format") != RUN_FORMAT:
        raise UserError(f"{path} is not a latent-sindy run file; retrain the run")
    return obj


def _read_config_json(run: Path) -> dict[str, Any]:
    path = run / CONFIG_FILE
    if not run.is_dir():
        raise UserError(
            f"run folder {run} does not exist: train one with `latent-sindy train --out {run}`"
        )
    if not path.is_file():
        raise UserError(
            f"{run} is not a run folder (no {CONFIG_FILE}); give the --out folder "
            "of `latent-sindy train`"
        )
    try:
        record = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise UserError(f"{path} is damaged ({e}); retrain the run") from e
    if not isinstance(record, dict) or record.get("format") != RUN_FORMAT:
        raise UserError(f"{path} is not a latent-sindy run config")
    if record.get("format_version") != RUN_FORMAT_VERSION:
        raise UserError(
            f"{path} has run format version {record.get('format_version')}; this "
            f"latent-sindy reads version {RUN_FORMAT_VERSION}: retrain the run"
        )
    return record


def _write_metrics(path: Path, rows: list[dict[str, Any]]) -> None:
    def write(f: io.TextIOBase) -> None:
        w = csv.DictWriter(f, fieldnames=METRIC_COLUMNS)
        w.writeheader()
        w.writerows(rows)

    write_atomic(path, write, binary=False)


def _append_metrics(path: Path, row: dict[str, Any]) -> None:
    with path.open("a", newline="") as f:
        csv.DictWriter(f, fieldnames=METRIC_COLUMNS).writerow(row)


def read_metrics(run_dir: str | os.PathLike) -> list[dict[str, float | None]]:
    """RUN/metrics.csv as rows of numbers (None for empty cells)."""
    path = Path(run_dir) / METRICS_FILE
    if not path.is_file():
        raise UserError(f"{path} does not exist: {run_dir} is not a (started) run folder")
    with path.open(newline="") as f:
        return [
            {k: (float(v) if v != "" else None) for k, v in row.items()}
            for row in csv.DictReader(f)
        ]


def plot_losses(rows: list[Mapping[str, Any]], path: Path) -> None:
    """Train and validation objective per epoch, log scale; dotted lines at SINDy prunings."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    epochs = [r["epoch"] for r in rows]
    for split in ("train", "val"):
        pts = [
            (e, r[f"{split}/objective"])
            for e, r in zip(epochs, rows, strict=True)
            if r[f"{split}/objective"] is not None
        ]
        if pts:
            ax.plot(*zip(*pts, strict=True), label=f"{split} objective")
    for r in rows:
        if r.get("sindy/pruned"):
            ax.axvline(r["epoch"], color="gray", lw=0.5, ls=":")
    ax.set(xlabel="epoch", ylabel="loss (recon + λ1 pred_x + λ2 pred_z)", yscale="log")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    try:
        write_atomic(path, lambda f: fig.savefig(f, format="png", dpi=100))
    finally:
        plt.close(fig)


# ----------------------------------------------------------------------------- the run record
def _data_identity(data: Trajectories, path: Path) -> dict[str, Any]:
    return {
        "path": str(path.resolve()),
        "seed": data.seed,
        "trajectories": data.n,
        "steps": data.steps,
        "splits": data.split_counts(),
    }


def _flatten(d: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, Mapping):
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _check_resumable(run: Path, old: Mapping[str, Any], new: Mapping[str, Any]) -> None:
    """UserError naming every setting that differs between the run's record and this call."""
    was = _flatten(
        {
            "train": old["train"],
            "normalizer": old["normalizer"],
            "data": {k: v for k, v in old["data"].items() if k != "path"},
        }
    )
    now = _flatten(
        {
            "train": new["train"],
            "normalizer": new["normalizer"],
            "data": {k: v for k, v in new["data"].items() if k != "path"},
        }
    )
    diffs = [
        f"{k.removeprefix('train.')} (run {was.get(k)!r}, now {now.get(k)!r})"
        for k in sorted(set(was) | set(now))
        if k.removeprefix("train.") not in RESUMABLE and was.get(k) != now.get(k)
    ]
    if diffs:
        raise UserError(
            f"cannot resume {run}: settings differ from its {CONFIG_FILE}: "
            f"{'; '.join(diffs)}. Resume with the run's settings or start over "
            "with --overwrite"
        )


def _prepare_run_dir(cfg: TrainConfig, record: dict[str, Any]) -> dict[str, Any] | None:
    """Check what `cfg.out` holds against the resume/overwrite flags; the checkpoint to resume."""
    run = cfg.out
    if run.exists() and not run.is_dir():
        raise UserError(f"--out {run} is a file; give a folder for the run")
    ckpt_path, model_path = run / CHECKPOINT_FILE, run / MODEL_FILE
    if cfg.overwrite:
        for name in RUN_FILES:
            (run / name).unlink(missing_ok=True)
    elif cfg.resume:
        if (run / CONFIG_FILE).exists():
            _check_resumable(run, _read_config_json(run), record)
        if ckpt_path.exists():
            ckpt = _load_torch(ckpt_path)
            if ckpt["epoch"] > cfg.epochs:
                raise UserError(
                    f"{ckpt_path} is at epoch {ckpt['epoch']}, past --epochs "
                    f"{cfg.epochs}: resume with --epochs {ckpt['epoch']} or more"
                )
            return ckpt
        if model_path.exists():
            raise UserError(
                f"cannot resume {run}: it has {MODEL_FILE} but no {CHECKPOINT_FILE}; "
                "start over with --overwrite"
            )
    elif model_path.exists():
        raise UserError(
            f"{run} already holds a trained model ({model_path}): pass --resume to "
            "train it for more epochs, --overwrite to replace it, or choose another "
            "--out"
        )
    elif ckpt_path.exists():
        raise UserError(
            f"{run} holds an interrupted run ({ckpt_path}): pass --resume to "
            "continue it or --overwrite to start over"
        )
    run.mkdir(parents=True, exist_ok=True)
    return None


# ----------------------------------------------------------------------------- training
@torch.no_grad()
def evaluate(
    model: LatentModel,
    x: torch.Tensor,
    u: torch.Tensor,
    weights: LossWeights | None = None,
    batch_size: int = 500,
) -> dict[str, float]:
    """Mean loss terms over windows x (W, H+1, C, S, S), u (W, H, nu), in batches."""
    was_training = model.training
    model.eval()
    sums = torch.zeros(len(LOSS_TERMS), dtype=torch.float64)
    for b in range(0, len(x), batch_size):
        terms = model.loss(x[b : b + batch_size], u[b : b + batch_size], weights)
        sums += torch.stack([terms[k] for k in LOSS_TERMS]).double() * len(x[b : b + batch_size])
    model.train(was_training)
    return dict(zip(LOSS_TERMS, (sums / max(len(x), 1)).tolist(), strict=True))


def _diverged(cfg: TrainConfig, epoch: int, what: str, last_ckpt: int | None) -> TrainingDiverged:
    kept = (
        f"the last good checkpoint is {cfg.out / CHECKPOINT_FILE} (epoch {last_ckpt})"
        if last_ckpt
        else "no checkpoint was written yet"
    )
    return TrainingDiverged(
        f"training diverged at epoch {epoch}: {what} is not finite; {kept}. "
        f"Lower --lr (now {cfg.lr}) and start over with --overwrite"
    )


def _train_epoch(
    model: LatentModel,
    opt: torch.optim.Optimizer,
    x: torch.Tensor,
    u: torch.Tensor,
    cfg: TrainConfig,
    gen: torch.Generator,
    epoch: int,
    last_ckpt: int | None,
) -> dict[str, float]:
    """One shuffled pass; mean loss terms per window (as seen before each batch's update)."""
    weights = cfg.weights
    order = torch.randperm(len(x), generator=gen)
    sums = torch.zeros(len(LOSS_TERMS), dtype=torch.float64)
    for b in range(0, len(x), cfg.batch_size):
        idx = order[b : b + cfg.batch_size]
        terms = model.loss(x[idx], u[idx], weights)
        values = torch.stack([terms[k].detach() for k in LOSS_TERMS])  # (6,)
        if not torch.isfinite(values).all():
            bad = next(
                k
                for k in ("recon", "pred_x", "pred_z", "l1", "total")
                if not torch.isfinite(terms[k])
            )
            value = float(terms[bad].detach())
            raise _diverged(cfg, epoch, f"loss term {bad} ({value})", last_ckpt)
        opt.zero_grad(set_to_none=True)
        terms["total"].backward()
        opt.step()
        sums += values.double() * len(idx)
    for name, p in model.named_parameters():
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


def _checkpoint(
    model: LatentModel,
    opt: torch.optim.Optimizer,
    gen: torch.Generator,
    epoch: int,
    metrics: list[dict[str, Any]],
) -> dict[str, Any]:
    return {
        "format": RUN_FORMAT,
        "epoch": epoch,
        "model": model.state_dict(),
        "optimizer": opt.state_dict(),
        "generator": gen.get_state(),
        "metrics": metrics,
    }


def _model_file(model: LatentModel, norm: Normalizer, epoch: int) -> dict[str, Any]:
    from latent_sindy import __version__

    return {
        "format": RUN_FORMAT,
        "epoch": epoch,
        "model": model.state_dict(),
        "model_config": model.config.to_dict(),
        "normalizer": norm.to_dict(),
        "package_version": __version__,
    }


def train(cfg: TrainConfig, progress: Progress | None = None) -> Path:
    """Train the model `cfg` describes into the run folder ``cfg.out``; returns that folder.

    Raises :class:`UserError` for unusable settings, data or run folders and
    :class:`TrainingDiverged` (a UserError) when a loss becomes NaN/inf; the last checkpoint
    stays loadable then.
    """
    from latent_sindy import __version__

    progress = progress or _Silent()
    data = read_trajectories(cfg.data)
    if cfg.horizon > data.steps:
        raise UserError(
            f"--horizon {cfg.horizon} is longer than the trajectories of {cfg.data} "
            f"({data.steps} pushes): use 1..{data.steps}"
        )
    norm = Normalizer.from_trajectories(data)
    _, _, channels, size, _ = data.images.shape
    model_cfg = cfg.model.resolve(channels, size, source=str(cfg.data))
    record = {
        "format": RUN_FORMAT,
        "format_version": RUN_FORMAT_VERSION,
        "package_version": __version__,
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        "train": cfg.to_dict(),
        "model": model_cfg.to_dict(),
        "normalizer": norm.to_dict(),
        "data": _data_identity(data, cfg.data),
        "env": data.env_config.to_dict(),  # the world the images came from, for control
    }
    record = json.loads(json.dumps(record))  # as config.json will hold it (tuples -> lists)
    ckpt = _prepare_run_dir(cfg, record)
    run = cfg.out

    with torch.random.fork_rng(devices=[]):  # seeded init without touching the caller's RNG
        torch.manual_seed(cfg.seed)
        model = LatentModel(model_cfg)
    opt = torch.optim.AdamW(
        model.parameters(), lr=cfg.lr, betas=cfg.betas, weight_decay=cfg.weight_decay
    )
    gen = torch.Generator().manual_seed(cfg.seed)  # the only randomness after the init
    metrics: list[dict[str, Any]] = []
    done = 0
    if ckpt is not None:
        try:
            model.load_state_dict(ckpt["model"])
            opt.load_state_dict(ckpt["optimizer"])
            gen.set_state(ckpt["generator"])
        except (KeyError, RuntimeError, ValueError) as e:
            raise UserError(
                f"{run / CHECKPOINT_FILE} does not fit this model ({e}); start "
                "over with --overwrite"
            ) from e
        metrics, done = list(ckpt["metrics"]), int(ckpt["epoch"])
    write_atomic(run / CONFIG_FILE, lambda f: f.write(json.dumps(record, indent=2)), False)
    _write_metrics(run / METRICS_FILE, metrics)  # drops rows logged after the checkpoint

    x, u = WindowDataset(data.split("train"), cfg.horizon, norm).tensors()  # (W,H+1,C,S,S)
    val = data.split("val")
    xv, uv = WindowDataset(val, cfg.horizon, norm).tensors() if val.n else (None, None)
    if val.n == 0:
        progress.note(f"{cfg.data} has no validation trajectories: val/* metrics stay empty")
    sindy = model_cfg.kind == "sindy"
    prune = sindy and cfg.threshold_every > 0

    last_ckpt = done or None
    model.train()
    progress.start(cfg.epochs, done)
    try:
        for epoch in range(done + 1, cfg.epochs + 1):
            t0 = time.perf_counter()
            row: dict[str, Any] = dict.fromkeys(METRIC_COLUMNS)
            row["epoch"] = epoch
            train_terms = _train_epoch(model, opt, x, u, cfg, gen, epoch, last_ckpt)
            row.update({f"train/{k}": v for k, v in train_terms.items()})
            if prune and epoch % cfg.threshold_every == 0:
                row["sindy/pruned"] = _prune(model, opt, cfg.threshold)
            if xv is not None:
                val_terms = evaluate(model, xv, uv, cfg.weights, cfg.batch_size)
                if not math.isfinite(val_terms["total"]):
                    raise _diverged(cfg, epoch, "the validation loss", last_ckpt)
                row.update({f"val/{k}": v for k, v in val_terms.items()})
            if sindy:
                row["sindy/active"] = model.dynamics.n_active()
                row["sindy/sparsity"] = model.dynamics.sparsity()
            row["time_s"] = time.perf_counter() - t0
            metrics.append(row)
            _append_metrics(run / METRICS_FILE, row)
            if epoch % cfg.checkpoint_every == 0 or epoch == cfg.epochs:
                _save_torch(_checkpoint(model, opt, gen, epoch, metrics), run / CHECKPOINT_FILE)
                last_ckpt = epoch
            progress.update(epoch, row)
    except TrainingDiverged:
        with contextlib.suppress(Exception):  # the plot is a convenience; the error matters
            plot_losses(metrics, run / PLOT_FILE)
        raise
    finally:
        progress.close()
    _save_torch(_model_file(model, norm, cfg.epochs), run / MODEL_FILE)
    plot_losses(metrics, run / PLOT_FILE)
    return run


# ----------------------------------------------------------------------------- loading
def load_run(run_dir: str | os.PathLike, checkpoint: bool = False) -> Run:
    """Rebuild (model, normalizer, config) of a run folder, the model in eval mode.

    ``checkpoint=True`` loads the weights of ``checkpoint.pt`` instead of ``model.pt`` (the
    state of an interrupted or diverged run).
    """
    run = Path(run_dir)
    record = _read_config_json(run)
    try:
        config = TrainConfig.from_dict(record["train"])
        model_cfg = ModelConfig.from_dict(record["model"])
        norm = Normalizer.from_dict(record["normalizer"])
        env_config = PushEnvConfig.from_dict(record["env"])
    except (KeyError, TypeError, ValueError) as e:
        raise UserError(
            f"{run / CONFIG_FILE} is damaged ({type(e).__name__}: {e}); retrain the run"
        ) from e
    path = run / (CHECKPOINT_FILE if checkpoint else MODEL_FILE)
    if not path.is_file():
        hint = (
            ""
            if checkpoint or not (run / CHECKPOINT_FILE).exists()
            else f" (its training did not finish: resume it with --resume --out {run}, or load "
            "its checkpoint)"
        )
        raise UserError(f"{run} has no {path.name}{hint}")
    payload = _load_torch(path)
    model = LatentModel(model_cfg)
    try:
        model.load_state_dict(payload["model"])
    except (KeyError, RuntimeError) as e:
        raise UserError(
            f"{path} does not match the model of {run / CONFIG_FILE} "
            f"({type(e).__name__}); retrain the run"
        ) from e
    return Run(model.eval(), norm, config, env_config)
