"""Settings of one training run (the paper's recipe is the default but for the epochs).

With the data file they determine the final model, bit for bit on a CPU. The model's own
settings are nested (:class:`~latent_sindy.models.latent_model.ModelConfig`), as are the loss
weights; on the command line every field is a flag named like the field.

    latent-sindy train sindy --order 2 --data data/push.h5 --out runs/sindy2 --epochs 300
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import torch
import tyro

from latent_sindy.configs import check_field_types, checked_value
from latent_sindy.errors import MAX_SEED, UserError
from latent_sindy.models.latent_model import LossWeights, ModelConfig

__all__ = ["BATCHINGS", "DEVICES", "PARALLELS", "PRUNINGS", "RESUMABLE", "TrainConfig",
           "auto_batch_size", "check_fit_settings", "default_threads", "resolve_batching",
           "resolve_device", "resolve_parallel", "resolve_prune", "unknown_choice"]

#: Settings that may change when resuming; everything else must match the run's record. The
#: data file may move: its identity (fingerprint, sizes, splits) is checked instead.
RESUMABLE = frozenset({"epochs", "resume", "overwrite", "checkpoint_every", "eval_every",
                       "keep_best", "device", "parallel", "out", "data"})

#: Values of :attr:`TrainConfig.batching`.
BATCHINGS = ("auto", "trajectories", "windows")

#: Values of :attr:`TrainConfig.parallel`.
PARALLELS = ("auto", "ops", "batch")

#: Values of :attr:`TrainConfig.prune`.
PRUNINGS = ("auto", "relative", "absolute")

#: Mini-batch updates an epoch aims at where the batch size is chosen from the data.
UPDATES_PER_EPOCH = 16
#: The batch sizes (windows) that choice stays within.
AUTO_BATCH = (16, 500)

#: Values of :attr:`TrainConfig.device`.
DEVICES = ("auto", "cpu", "cuda")


def unknown_choice(name: str, value: Any) -> str | None:
    """The message refusing ``value`` for the TrainConfig field ``name`` of a few fixed choices
    (a Literal) where it is a string outside them, in the words of the command line (the flag
    and the value, for Python callers too); None where it is one of them, is no string (the
    type check's), or ``name`` has no fixed choices."""
    if not isinstance(value, str):
        return None
    choices = {
        "prune": (PRUNINGS, f"--prune {value!r} is unknown: use one of {', '.join(PRUNINGS)}"),
        "sindy_init": (("auto", "random", "regression"),
                       f"--sindy-init {value!r}: use auto, random or regression"),
        "sindy_fit": (("joint", "after"), f"--sindy-fit {value!r}: use joint or after"),
        "derivatives": (("auto", "latent", "central", "smooth"),
                        f"--derivatives {value!r}: use auto, latent, central or smooth"),
        "batching": (BATCHINGS,
                     f"--batching {value!r} is unknown: use one of {', '.join(BATCHINGS)}"),
        "parallel": (PARALLELS,
                     f"--parallel {value!r} is unknown: use one of {', '.join(PARALLELS)}"),
        "device": (DEVICES, f"--device {value!r} is unknown: use one of {', '.join(DEVICES)}"),
    }
    if name not in choices or value in choices[name][0]:
        return None
    return choices[name][1]


@dataclass(frozen=True)
class TrainConfig:
    """Settings of one training run; with the data file they determine the final model."""

    data: Path = Path("data/train.h5")
    """Trajectory file (.h5) from `latent-sindy collect` (the command line's default: the
    default world's, data/WORLD.h5)."""
    out: Path = Path("runs/sindy")
    """Run folder to create (config, weights, checkpoint, metrics, loss plot)."""
    model: tyro.conf.OmitArgPrefixes[ModelConfig] = field(default_factory=ModelConfig)
    """Architecture of the latent model."""
    loss: tyro.conf.OmitArgPrefixes[LossWeights] = field(default_factory=LossWeights)
    """Weights of the loss terms."""
    window: int = 1
    """Actions per training window H (1: the paper's single-step model)."""
    epochs: int = 300
    """Passes over the training windows (the paper: 3000; 300 trains in minutes on a CPU)."""
    batch_size: int | None = None
    """Windows per mini-batch (the paper: 500); trajectory batches hold batch_size // (T-H+1)
    whole trajectories (at least one), T the actions per trajectory. None: a sixteenth of the
    training windows, 16 to 500, so that every epoch makes about 16 updates however small the
    data (a batch of 500 gives a set of 50 trajectories one update an epoch, too few to learn
    anything in 300 epochs)."""
    batching: Literal["auto", "trajectories", "windows"] = "auto"
    """Mini-batches of "windows" (drawn from all trajectories; each window encodes and decodes
    its own frames) or of whole "trajectories" (each frame encoded and reconstructed once:
    the same prediction terms, a reconstruction term that weighs every frame once instead of
    once per window holding it; 1.5x faster epochs at H = 1, batch 500); "auto": trajectories for
    --window 1, windows otherwise. Validation always uses windows."""
    parallel: Literal["auto", "ops", "batch"] = "auto"
    """How training uses several CPU threads (--threads T): "ops", torch's own threads inside
    each layer; "batch", each mini-batch split into T parts whose gradients T threads compute
    at once (one torch thread each) and add (1.3x faster epochs than "ops" on 2 cores at the
    paper's sizes: these layers are too small to split well; BENCHMARKS.md); "auto": batch on
    the CPU with T > 1, else ops (always ops for continuous-time dynamics). The same settings
    give the same model; ops and batch differ in the last bits."""
    lr: float = 1e-3
    """AdamW learning rate (the paper: 1e-3)."""
    betas: tuple[float, float] = (0.9, 0.999)
    """AdamW betas (the paper: 0.9, 0.999)."""
    weight_decay: float = 0.01
    """AdamW decoupled weight decay (PyTorch's default, which the paper kept)."""
    starts: int = 4
    """Initialisations tried (seeds derived from --seed): each trains --start-epochs, and the
    one of lowest validation objective continues to --epochs (the paper kept the best of ten
    runs). 1: the seed's alone. Costs (starts - 1) x start-epochs more epochs."""
    start_epochs: int | None = None
    """Epochs each start trains before the choice (None: a fifth of --epochs)."""
    prune_below: float = 1e-3
    """SINDy: prune the coefficients below this, as --prune measures them (the paper: |Ψ|
    below 1e-3)."""
    prune: Literal["auto", "relative", "absolute"] = "auto"
    """SINDy: how --prune-below measures a coefficient. "relative": its term's share of its
    state's update, |Ψ_kj| rms(Θ_k) / rms(Θ Ψ_j) over the encoded training transitions, the
    same whatever the scales of the latent, the actions and the library's columns;
    "absolute": |Ψ_kj| (the paper), which prunes every term of a latent whose steps are
    small; "auto": relative for discrete-time SINDy, absolute for continuous time."""
    prune_every: int = 30
    """SINDy: prune every this many epochs, the last included; 0 never (the paper: 300 of 3000)."""
    refine_epochs: int = 0
    """SINDy: the last this many of the epochs refine the coefficients: no pruning (the mask
    stays as it is) and no L1 term (the SINDy autoencoder: 1001 after 5001, --epochs 6002)."""
    derivatives: Literal["auto", "latent", "central", "smooth"] = "auto"
    """Continuous-time models: where the time derivatives come from. "auto": the data's
    exact ones (images_dot, images_ddot) where it has them, else "latent": the encoder's
    latents of five frames around each differentiated (fourth-order differences, the
    frames' spacing chosen from the model's time unit), never the pixels; "central":
    central differences of the frames, dt apart; "smooth": a Savitzky-Golay differentiator
    of the frames over --derivative-window frames."""
    derivative_window: int = 9
    """--derivatives smooth: frames in the differentiator's window (odd, at least 5)."""
    sindy_init: Literal["auto", "random", "regression"] = "auto"
    """SINDy: where the coefficients start. "random" (the paper: small normal values, seeded);
    "regression": least squares of the training split's encoded transitions on the library,
    which needs an encoder that learns nothing (state, moments: its latents are fixed data);
    "auto": regression where the encoder learns nothing, else random. Training then goes on
    from there (the L1 term and the pruning make it sparser)."""
    sindy_init_share: float = 0.0
    """SINDy, regression start: the sequentially thresholded least squares' cut, the
    smallest share a term may contribute (on RMS-normalised library columns); the terms it
    drops start pruned. 0: plain least squares, every term."""
    sindy_fit: Literal["joint", "after"] = "joint"
    """SINDy: "joint" trains the coefficients with the autoencoder (the paper); "after" trains
    the autoencoder first (its loss terms as given; with the prediction weights at 0, on
    reconstruction alone) and then sets the coefficients to the sequentially thresholded
    least squares (at --sindy-init-share) of the trained encoder's training transitions,
    as for an encoder that learns nothing: for a learned latent that the prediction terms
    would bend (RESULTS.md, "A learned object mask for the moments")."""
    order_epochs: int = 10
    """A mask_moments encoder with --moment-order 0: epochs of the short fit (at order 2)
    whose encoder chooses the order from the training images."""
    checkpoint_every: int = 10
    """Write checkpoint.pt every this many epochs (and always at the end)."""
    # Validation is a forward pass over 500 windows, about a seventh of an epoch at the
    # paper's sizes (BENCHMARKS.md), and it never changes the model.
    eval_every: int = 1
    """Validation loss every this many epochs and at the last (others' val/* stay empty)."""
    # Selection never changes training; the checkpoint tracks the best weights either way.
    keep_best: bool = True
    """Save the weights of the validated epoch with the lowest validation objective since the
    last SINDy pruning that removed a term (so with the final mask), not the last epoch's."""
    device: Literal["auto", "cpu", "cuda"] = "cpu"
    """cpu (bit-identical per seed and threads), cuda (not bit-identical), auto: cuda if present."""
    seed: int = 0
    """Seeds the initial weights and the mini-batch order."""
    resume: bool = False
    """Continue the run in `out` from its checkpoint (settings must match; epochs may grow)."""
    overwrite: bool = False
    """Replace a finished or interrupted run in `out` (all of it) instead of refusing."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):  # a string outside the choices: the flag's words
            if (message := unknown_choice(f.name, getattr(self, f.name))) is not None:
                raise UserError(message)
        check_field_types(self, "TrainConfig ")  # (True, "2" or 1.5 for an integer, ...)

        def finite(v: float) -> bool:
            return math.isfinite(v)

        checks = (
            (self.epochs >= 1, f"--epochs {self.epochs}: train for at least 1 epoch"),
            (self.window >= 1, f"--window {self.window}: windows need at least 1 action"),
            (self.batch_size is None or self.batch_size >= 1,
             f"--batch-size {self.batch_size}: use 1 or more (or None: chosen from the data)"),
            (self.starts >= 1, f"--starts {self.starts}: use 1 or more"),
            (self.start_epochs is None or self.start_epochs >= 1,
             f"--start-epochs {self.start_epochs}: use 1 or more (or None: a fifth of "
             "--epochs)"),
            (self.lr > 0 and finite(self.lr), f"--lr {self.lr}: use a finite positive number"),
            (len(self.betas) == 2 and all(0 <= b < 1 for b in self.betas),
             f"--betas {self.betas}: use two numbers in [0, 1)"),
            (self.weight_decay >= 0 and finite(self.weight_decay),
             f"--weight-decay {self.weight_decay}: use a finite number >= 0"),
            (self.prune_below >= 0 and finite(self.prune_below),
             f"--prune-below {self.prune_below}: use a finite number >= 0"),
            (self.sindy_init_share >= 0 and finite(self.sindy_init_share),
             f"--sindy-init-share {self.sindy_init_share}: use a finite number >= 0"),
            (self.order_epochs >= 1, f"--order-epochs {self.order_epochs}: use 1 or more"),
            (self.prune_every >= 0,
             f"--prune-every {self.prune_every}: use 0 (never) or more"),
            (0 <= self.refine_epochs <= self.epochs,
             f"--refine-epochs {self.refine_epochs}: use 0 to --epochs ({self.epochs}); the "
             "refinement is the last of the epochs"),
            (self.derivative_window >= 5 and self.derivative_window % 2 == 1,
             f"--derivative-window {self.derivative_window}: use an odd number, at least 5"),
            (self.checkpoint_every >= 1,
             f"--checkpoint-every {self.checkpoint_every}: use 1 or more"),
            (self.eval_every >= 1, f"--eval-every {self.eval_every}: use 1 or more"),
            (0 <= self.seed <= MAX_SEED,
             f"--seed {self.seed}: seeds are integers from 0 to {MAX_SEED}"),
            (not (self.resume and self.overwrite),
             "--resume and --overwrite contradict each other: choose one"),
        )
        for ok, message in checks:
            if not ok:
                raise UserError(message)
        if not isinstance(self.model, ModelConfig):
            raise TypeError(f"TrainConfig.model must be a ModelConfig, got {type(self.model)}")
        kind = self.model.observation.kind
        if self.loss.foreground_weight > 0 and kind != "image":
            raise UserError(f"--foreground-weight {self.loss.foreground_weight} weights the "
                            f"object's pixels in the image terms; a {kind} model has no "
                            "images: leave it at 0 (image models only)")
        continuous = self.model.dynamics.kind == "continuous"
        if continuous and self.loss.foreground_weight > 0:
            raise UserError(f"--foreground-weight {self.loss.foreground_weight} is for "
                            "discrete-time models: leave it at 0 with continuous dynamics")
        if continuous and self.parallel == "batch":
            raise UserError("--parallel batch splits a batch over threads, which the "
                            "forward-mode derivatives of continuous-time dynamics cannot run "
                            "in: use --parallel auto or ops")
        if continuous and self.prune == "relative":
            raise UserError("--prune relative measures a term's share of a discrete step; "
                            "continuous-time dynamics prune |Ξ|: use --prune auto or absolute")
        if not continuous and self.derivatives != "auto":
            raise UserError(f"--derivatives {self.derivatives} is for continuous-time "
                            "dynamics (latent-sindy train continuous ...): drop it")
        if self.loss.lambda_pose > 0 and not self.model.has_pose_head:
            raise UserError(f"--lambda-pose {self.loss.lambda_pose} weights a pose head the "
                            "model does not have: add --pose-head linear or coordinates "
                            "(image models)")


def resolve_prune(cfg: TrainConfig) -> str:
    """What :attr:`TrainConfig.prune` measures for ``cfg``'s model: "relative" or
    "absolute"."""
    if cfg.prune == "auto":
        return "absolute" if cfg.model.dynamics.kind == "continuous" else "relative"
    return cfg.prune


def auto_batch_size(windows: int) -> int:
    """The batch size (windows) a fit on ``windows`` training windows takes when none is
    given: about :data:`UPDATES_PER_EPOCH` updates an epoch, within :data:`AUTO_BATCH`."""
    low, high = AUTO_BATCH
    return int(min(high, max(low, math.ceil(windows / UPDATES_PER_EPOCH))))


def resolve_batching(cfg: TrainConfig) -> str:
    """What :attr:`TrainConfig.batching` batches for ``cfg``: "trajectories" or "windows"."""
    if cfg.batching == "auto":
        return "trajectories" if cfg.window == 1 else "windows"
    return cfg.batching


def resolve_parallel(cfg: TrainConfig, device: str, threads: int) -> str:
    """What :attr:`TrainConfig.parallel` does on ``device`` with ``threads`` torch threads:
    "batch" or "ops" (always "ops" off the CPU, on one thread, or for continuous-time
    dynamics)."""
    if device != "cpu" or threads < 2 or cfg.model.dynamics.kind == "continuous":
        return "ops"  # (forward-mode derivatives cannot run in several threads at once)
    return "batch" if cfg.parallel == "auto" else cfg.parallel


def resolve_device(device: str) -> str:
    """The torch device a :attr:`TrainConfig.device` setting trains on ("cpu" or "cuda");
    UserError for "cuda" on a machine without a usable CUDA device."""
    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device == "cuda" and not torch.cuda.is_available():
        raise UserError(f"--device cuda: this torch ({torch.__version__}) sees no CUDA device; "
                        "use --device cpu or auto")
    return device


def default_threads() -> int:
    """torch CPU threads for training: one per core this process may run on, at most torch's
    own default (which honours OMP_NUM_THREADS)."""
    return max(1, min(torch.get_num_threads(), len(os.sched_getaffinity(0))))


#: TrainConfig fields that ``fit`` sets itself: the estimator's settings, or its ``out``.
FIT_OWN_SETTINGS = {"model": "LatentSINDy(model=...)", "loss": "LatentSINDy(loss=...)",
                 "seed": "LatentSINDy(seed=...)", "device": "LatentSINDy(device=...)",
                 "data": "fit(data)", "out": "fit(data, out=...)"}


def check_fit_settings(settings: dict[str, Any], out: Any) -> None:
    """UserError naming a keyword of ``fit`` that is no training setting, or one that the
    estimator or ``fit`` sets elsewhere."""
    fields = {f.name for f in dataclasses.fields(TrainConfig)}
    hints = typing.get_type_hints(TrainConfig, include_extras=True)
    for key in settings:
        if key in FIT_OWN_SETTINGS:
            raise UserError(f"fit(..., {key}=...): {key} is set by {FIT_OWN_SETTINGS[key]}, not "
                            "as a training setting")
        if key not in fields:
            close = difflib.get_close_matches(key, sorted(fields), n=1)
            raise UserError(f"fit(..., {key}=...): no such training setting"
                            + (f" (did you mean {close[0]}?)" if close else "")
                            + "; the settings are TrainConfig's fields")
        if key in ("resume", "overwrite") and out is None:
            raise UserError(f"fit(..., {key}=...) is for a run folder: add out=FOLDER")
        if (message := unknown_choice(key, settings[key])) is not None:
            raise UserError(message)  # (as TrainConfig words it)
        settings[key] = checked_value(hints[key], settings[key], f"fit: {key}")
