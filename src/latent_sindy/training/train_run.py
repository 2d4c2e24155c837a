"""Training into a run folder: the data file, resume, checkpoints and progress around
:func:`~latent_sindy.training.fit_loop.fit` (the one gradient loop).

The paper's recipe (docs/design.md): AdamW on the loss of
:meth:`~latent_sindy.models.latent_model.LatentModel.loss` over windows of ``window`` steps,
mini-batches (of windows, or of whole sequences whose frames are encoded once: ``batching``)
shuffled by a generator seeded from ``seed``, and every ``prune_every`` epochs SINDy
coefficients with ``|Ψ| < prune_below`` pruned for good. ``resume=True`` continues from the run's
checkpoint to the same final model, bit for bit on CPU (for the same torch thread count), as an
uninterrupted run with the same settings. On CUDA (``device``) the same code runs with the
data, model and optimiser on the GPU; the shuffling generator stays on the CPU, so both
devices see the same mini-batches.

    latent-sindy train sindy --order 2 --data data/push.h5 --out runs/sindy2
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Any

import torch

from latent_sindy.data import SequenceData, read_sequences
from latent_sindy.errors import UserError
from latent_sindy.locks import exclusive
from latent_sindy.models.latent_model import LatentModel
from latent_sindy.plots import loss_histories
from latent_sindy.progress import Progress, Silent
from latent_sindy.training.config import TrainConfig, resolve_device, resolve_parallel
from latent_sindy.training.fit_loop import (
    BestValidation,
    TrainingDiverged,
    keep_freed_memory,
    to_cpu,
)
from latent_sindy.training.metrics import METRIC_COLUMNS
from latent_sindy.training.prepare import settle_settings
from latent_sindy.training.record import action_box, run_record
from latent_sindy.training.runs import RunDir
from latent_sindy.training.session import prepare

__all__ = ["TrainingDiverged", "restore_finished", "run_record", "train"]


def _check_folder(run: RunDir, cfg: TrainConfig, record: dict[str, Any]) -> dict[str, Any] | None:
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


def _diverged(cfg: TrainConfig, e: TrainingDiverged, last_ckpt: int | None) -> TrainingDiverged:
    kept = (f"the last good checkpoint is {cfg.out / RunDir.CHECKPOINT} (epoch {last_ckpt})"
            if last_ckpt else "no checkpoint was written yet")
    return TrainingDiverged(e.epoch, e.what, f"training diverged at epoch {e.epoch}: {e.what} "
                            f"is not finite; {kept}. Lower --lr (now {cfg.lr}) and start over "
                            "with --overwrite")


def _resume(ckpt: dict[str, Any], run: RunDir, cfg: TrainConfig, model: LatentModel,
            opt: torch.optim.Optimizer, gen: torch.Generator, device: torch.device,
            now: tuple[str, int, str], progress: Progress) -> tuple[list, int, BestValidation]:
    """Model, optimiser and generator states from a checkpoint; (metrics, epoch, best)."""
    try:
        model.load_state_dict(ckpt["model"])
        opt.load_state_dict(ckpt["optimizer"])
        gen.set_state(ckpt["generator"])
        best = BestValidation.from_checkpoint(ckpt.get("best"), device, int(ckpt["epoch"]))
    except (KeyError, RuntimeError, ValueError, TypeError) as e:
        raise UserError(f"{run / run.CHECKPOINT} does not fit this model ({e}); start "
                        "over with --overwrite") from e
    metrics = list(ckpt["metrics"])
    done = int(ckpt["epoch"])
    if "best" not in ckpt and cfg.keep_best:
        progress.note(f"{run / run.CHECKPOINT} is from before model selection: the kept "
                      f"weights are chosen among epochs {done + 1} to {cfg.epochs}")
    was = (ckpt.get("device", "cpu"), ckpt.get("threads"), ckpt.get("parallel", "ops"))
    if was[1] is not None and was != now:  # older checkpoints did not record them
        progress.note(f"resuming on {now[0]} with {now[1]} thread(s) ({now[2]}) a run "
                      f"trained on {was[0]} with {was[1]} ({was[2]}): the result will "
                      "differ in the last bits from an uninterrupted run")
    return metrics, done, best


def train(cfg: TrainConfig, progress: Progress | None = None,
          data: SequenceData | None = None) -> Path:
    """Train the model `cfg` describes into the run folder ``cfg.out``; returns that folder.

    ``data`` (else read from ``cfg.data``) is what it trains on. Every setting, the data and
    the run folder are checked before a file is written or removed; ``overwrite`` then
    removes the old run whole. Raises :class:`UserError` for unusable settings, data or run
    folders and :class:`TrainingDiverged` (a UserError) when a loss becomes NaN/inf; the last
    checkpoint stays loadable then.
    """
    with exclusive(cfg.out, "run folder"):  # one process per run folder, refused at once
        return _train(cfg, progress, data)


def _train(cfg: TrainConfig, progress: Progress | None, data: SequenceData | None) -> Path:
    progress = progress or Silent()
    device = torch.device(resolve_device(cfg.device))
    if device.type == "cpu":
        keep_freed_memory()
    data = read_sequences(cfg.data) if data is None else data
    cfg = settle_settings(cfg, data)  # (refuses a window longer than the sequences)
    record = run_record(cfg, data)
    run = RunDir(cfg.out)
    ckpt = _check_folder(run, cfg, record)

    def ready() -> None:  # every setting checked: the folder changes now
        if cfg.overwrite:
            run.clear()
        run.path.mkdir(parents=True, exist_ok=True)
        run.write_record(record)

    if ckpt is not None:  # (the old model is loaded into the session before the folder changes)
        session = prepare(cfg, data, device, record=record, resumed=True,
                          earlier=run.read_record(), progress=progress)
    else:
        session = prepare(cfg, data, device, record=record, progress=progress, ready=ready)
    model = session.model
    opt = session.opt
    gen = session.gen
    threads = torch.get_num_threads()
    parallel = resolve_parallel(cfg, device.type, threads)
    if ckpt is not None:
        session.metrics, session.done, session.best = _resume(
            ckpt, run, cfg, model, opt, gen, device, (device.type, threads, parallel), progress)
        session.info = ckpt.get("start")  # the start was chosen before the checkpoint
        ready()
    metrics = session.metrics
    best = session.best
    done = session.done
    run.write_metrics(metrics)  # drops rows logged after the checkpoint (or a start's probe)
    if session.tensors.val is None:
        progress.note(f"{cfg.data} has no validation trajectories: val/* metrics stay empty")
    last_ckpt = done or None

    def checkpoint(epoch: int) -> None:
        nonlocal last_ckpt
        run.save_torch(run.CHECKPOINT, {
            "epoch": epoch, "model": to_cpu(model.state_dict()),
            "optimizer": to_cpu(opt.state_dict()), "generator": gen.get_state(),
            "metrics": metrics, "best": best.to_checkpoint(), "device": device.type,
            "threads": threads, "parallel": parallel, "start": session.info,
            "action_box": action_box(record["description"])})
        last_ckpt = epoch

    if ckpt is None and done:  # the chosen start resumes from here, not the probes
        checkpoint(done)

    def on_epoch(epoch: int, row: dict[str, Any]) -> None:
        run.append_metrics(row)
        if epoch % cfg.checkpoint_every == 0 or epoch == cfg.epochs:
            checkpoint(epoch)
        progress.update(epoch, row)

    progress.start(cfg.epochs, done)
    try:
        result = session.fit(on_epoch=on_epoch)
        kept = result.kept
        if kept["selection"] == "best validation":
            progress.note(f"kept the weights of epoch {kept['epoch']} of {cfg.epochs}: the "
                          f"lowest validation objective ({kept['val_objective']:.6g}) since "
                          f"epoch {kept['candidates_from']}")
    except TrainingDiverged as e:
        with contextlib.suppress(Exception):  # the plot is a convenience; the error matters
            loss_histories({"run": metrics}, {}, run / run.PLOT, dpi=100)
        raise _diverged(cfg, e, last_ckpt) from None
    finally:
        progress.close()
    session.finish(result)  # (the kept weights; --sindy-fit after fits them)
    from latent_sindy.version import __version__

    # both before model.pt, which marks the run finished: a finished run lacks neither
    run.write_record({**record, "kept": kept})
    loss_histories({"run": result.metrics}, {}, run / run.PLOT, dpi=100)
    run.save_torch(run.MODEL, {"epoch": kept["epoch"], "epochs": cfg.epochs,
                               "selection": kept["selection"], "model": to_cpu(result.state),
                               "model_config": record["model"],
                               "normalizer": record["normalizer"],
                               "action_box": action_box(record["description"]),
                               "package_version": __version__})
    return run.path


def restore_finished(run: RunDir) -> list[str]:
    """Give a finished run back the files it lost that it still holds elsewhere: metrics.csv
    (missing, damaged, or short of the run's epochs) from checkpoint.pt, whose last save has
    every epoch's row, and loss.png from the metrics. Returns the names restored; UserError
    naming the fix where metrics.csv is unreadable and the checkpoint cannot restore it."""
    epochs = run.train_config().epochs
    restored = []
    try:
        rows: list[dict[str, Any]] | None = run.read_metrics()
        problem = None if len(rows) == epochs else f"{run / run.METRICS} holds {len(rows)} rows"
    except UserError as e:
        rows = None
        problem = str(e)
    if problem is not None:
        saved = _checkpoint_metrics(run, epochs)
        if saved is not None:
            run.write_metrics(saved)
            rows = saved
            restored.append(run.METRICS)
        elif rows is None:
            raise UserError(f"{problem.rstrip('.')}; {run / run.CHECKPOINT} cannot restore it "
                            f"(missing, or not at the last epoch): delete {run.path} to retrain "
                            "the run")
    if rows is not None and not (run / run.PLOT).is_file():
        loss_histories({"run": rows}, {}, run / run.PLOT, dpi=100)
        restored.append(run.PLOT)
    return restored


def _checkpoint_metrics(run: RunDir, epochs: int) -> list[dict[str, Any]] | None:
    """The metrics rows of the run's checkpoint if it holds all ``epochs`` of them, else None."""
    if not (run / run.CHECKPOINT).is_file():
        return None
    try:
        ckpt = run.load_torch(run.CHECKPOINT)
    except UserError:
        return None
    rows = ckpt.get("metrics")
    ok = (ckpt.get("epoch") == epochs and isinstance(rows, list) and len(rows) == epochs
          and all(isinstance(r, dict) and set(r) <= set(METRIC_COLUMNS) for r in rows))
    return rows if ok else None
