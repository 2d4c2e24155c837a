"""The run folder: the one place that names its files and reads and writes them.

A run folder describes itself; every later command needs only it::

    RUN/config.json         the record: TrainConfig, the batching it resolved to, resolved
                            ModelConfig, normaliser, the data's identity, the environment,
                            versions; at the end "kept": the epoch whose weights model.pt
                            holds and why
    RUN/model.pt            kept weights (best validation or last epoch; SINDy mask
                            included) + model config + normaliser
    RUN/checkpoint.pt       model, optimiser, epoch, shuffle-generator state, metrics so far,
                            best-validation weights so far
    RUN/metrics.csv         one row per epoch: train/*, val/*, sindy/*, time_s
    RUN/loss.png            train and validation objective per epoch
    RUN/evaluation.json     the study's measurements of this run (cached)
    RUN/coefficients.csv/.json   the equations' coefficients (``latent-sindy equations``)
    RUN/control-TASK-SPACE/ closed-loop results (``latent-sindy control``, the study)

Files are written atomically (temporary file + rename); ``.pt`` files are read with
``torch.load(weights_only=True)`` only; config.json is checked (format, version, every key)
when read. A run folder of another format version is refused with one line: retrain the run.

    run = RunDir("runs/sindy2")
    model, normalizer, config, description, world_record = run.load()
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import os
import pickle
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, NamedTuple

import torch

from latent_sindy.atomic import write_atomic
from latent_sindy.configs import from_json, to_json
from latent_sindy.data.windows import Normalizer
from latent_sindy.errors import UserError
from latent_sindy.locks import holder
from latent_sindy.models.latent_model import LatentModel, ModelConfig
from latent_sindy.plugins import get_world
from latent_sindy.training.config import BATCHINGS, RESUMABLE, TrainConfig
from latent_sindy.training.metrics import METRIC_COLUMNS
from latent_sindy.training.record import (
    RECORD_KEYS,
    RUN_FORMAT,
    RUN_FORMAT_VERSION,
    check_action_box,
    check_description,
)

__all__ = ["METRIC_COLUMNS", "RUN_FORMAT", "RUN_FORMAT_VERSION", "Run", "RunDir", "load_run",
           "read_metrics"]

#: Columns of metrics.csv (empty cells: no validation split / not a SINDy model).

Task = Literal["paper", "random"]
Space = Literal["latent", "image", "pose"]


#: Model settings that training derives from the data where left unset, as (part, key):
#: runs are compared on what their model was built with (the record's resolved "model").
DERIVED: tuple[tuple[str, str], ...] = (
    ("observation", "decoder.size"),
)


class Run(NamedTuple):
    """What :meth:`RunDir.load` rebuilds from a run folder: the model, its normaliser, its
    training settings, and what it knows of its data (``description``: frame shape, pixel
    type, action box and names, state names and periods, dt, world; ``world_record``: the
    world's own record, read by that world's plug-in)."""

    model: LatentModel
    normalizer: Normalizer
    config: TrainConfig
    description: dict[str, Any]
    world_record: dict[str, Any]

    @property
    def world(self) -> str | None:
        return self.description.get("world")

    @property
    def world_config(self) -> Any:
        """The settings of the world the model's data came from (its plug-in reads them)."""
        if self.world is None:
            raise UserError("this run was trained on data of no world: it has no world "
                            "settings (plan with the estimator's planner instead)")
        return get_world(self.world).config_from_record(self.world_record, "the run's record")


class RunDir:
    """A run folder and its files. Construct it for any path; nothing is touched until asked."""

    CONFIG = "config.json"
    MODEL = "model.pt"
    CHECKPOINT = "checkpoint.pt"
    METRICS = "metrics.csv"
    PLOT = "loss.png"
    EVALUATION = "evaluation.json"
    COEFFICIENTS_CSV = "coefficients.csv"
    COEFFICIENTS_JSON = "coefficients.json"
    #: Everything a run owns besides its control folders; ``clear()`` removes exactly these.
    FILES = (CONFIG, MODEL, CHECKPOINT, METRICS, PLOT, EVALUATION, COEFFICIENTS_CSV,
             COEFFICIENTS_JSON)

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"RunDir({str(self.path)!r})"

    def __truediv__(self, name: str) -> Path:
        return self.path / name

    # ---------------------------------------------------------------- state
    @property
    def finished(self) -> bool:
        """It holds a final model."""
        return (self.path / self.MODEL).is_file()

    @property
    def interrupted(self) -> bool:
        """It holds a checkpoint but no final model."""
        return not self.finished and (self.path / self.CHECKPOINT).is_file()

    def control_dir(self, task: Task, space: Space) -> Path:
        """Where closed-loop results of (task, planning space) live: ``control-TASK-SPACE``."""
        return self.path / f"control-{task}-{space}"

    def control_dirs(self) -> list[Path]:
        return sorted(p for p in self.path.glob("control-*") if p.is_dir())

    def check_folder(self) -> None:
        """UserError unless the path is a run folder with a config.json."""
        if not self.path.exists() and self.path.is_symlink():  # (exists() follows the link)
            raise UserError(f"{self.path} is a symbolic link that leads to no folder (a loop, "
                            "or its target is gone): point it at a run folder")
        if not self.path.exists():
            raise UserError(f"run folder {self.path} does not exist: train one with "
                            f"`latent-sindy train --out {self.path}`")
        if not self.path.is_dir():
            raise UserError(f"{self.path} is a file, not a run folder: give the --out folder "
                            "of `latent-sindy train`")
        if not (self.path / self.CONFIG).is_file():
            raise UserError(f"{self.path} is not a run folder (no {self.CONFIG}); give the "
                            "--out folder of `latent-sindy train`")

    def clear(self) -> None:
        """Remove every file of the run and its control folders (``--overwrite``)."""
        for name in self.FILES:
            (self.path / name).unlink(missing_ok=True)
        for folder in self.control_dirs():
            shutil.rmtree(folder)

    # ---------------------------------------------------------------- config.json
    def read_record(self) -> dict[str, Any]:
        """config.json, checked: its format, its version (the current one) and every key."""
        self.check_folder()
        path = self.path / self.CONFIG
        try:
            record = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
            raise UserError(f"{path} is damaged ({e}); retrain the run") from e
        if not isinstance(record, dict) or record.get("format") != RUN_FORMAT:
            raise UserError(f"{path} is not a latent-sindy run config")
        check_version(record, path)
        unknown = sorted(set(record) - RECORD_KEYS)
        if unknown:
            raise UserError(f"{path}: unknown key {unknown[0]!r} at the top (the file was "
                            "edited): remove it, or retrain the run")
        return record

    def write_record(self, record: Mapping[str, Any]) -> None:
        write_atomic(self.path / self.CONFIG, lambda f: f.write(json.dumps(record, indent=2)),
                     binary=False)

    def train_config(self, record: Mapping[str, Any] | None = None) -> TrainConfig:
        record = self.read_record() if record is None else record
        return from_json(TrainConfig, record["train"], f"{self.path / self.CONFIG}: train")

    def batching(self, record: Mapping[str, Any] | None = None) -> str:
        """How the run batched its training: "trajectories" or "windows" (its --batching,
        "auto" resolved as recorded)."""
        record = self.read_record() if record is None else record
        recorded = record.get("batching")
        if recorded not in BATCHINGS or recorded == "auto":
            raise UserError(f"{self.path / self.CONFIG}: batching {recorded!r} is not "
                            "trajectories or windows: the file was edited; retrain the run")
        return recorded

    # ---------------------------------------------------------------- .pt files
    def save_torch(self, name: str, payload: dict[str, Any]) -> None:
        write_atomic(self.path / name, lambda f: torch.save(
            {"format": RUN_FORMAT, "format_version": RUN_FORMAT_VERSION, **payload}, f))

    def load_torch(self, name: str) -> dict[str, Any]:
        path = self.path / name
        if not path.is_file():
            raise UserError(f"{path} does not exist")
        try:
            obj = torch.load(path, map_location="cpu", weights_only=True)
        except (RuntimeError, OSError, EOFError, ValueError, pickle.UnpicklingError) as e:
            raise UserError(f"{path} is damaged or not a latent-sindy file "
                            f"({type(e).__name__}); retrain the run") from e
        if not isinstance(obj, dict) or obj.get("format") != RUN_FORMAT:
            raise UserError(f"{path} is not a latent-sindy run file; retrain the run")
        check_version(obj, path)
        return obj

    # ---------------------------------------------------------------- metrics.csv
    def read_metrics(self) -> list[dict[str, float | None]]:
        """metrics.csv as rows of numbers (None for empty cells); UserError naming the file
        and the line where a cell is not a number or a row has the wrong number of cells."""
        path = self.path / self.METRICS
        if not path.is_file():
            raise UserError(f"{path} does not exist: {self.path} is not a (started) run "
                            "folder, or the file was deleted (a study restores a finished "
                            f"run's from its {self.CHECKPOINT}; else retrain with --overwrite)")
        rows = []
        try:
            with path.open(newline="", encoding="utf-8") as f:
                reader = csv.DictReader(f)
                for row in reader:
                    rows.append(_metric_row(row, path, reader.line_num, self.CHECKPOINT))
        except (UnicodeDecodeError, csv.Error) as e:
            raise UserError(f"{path} is damaged ({e}): a study restores a finished run's "
                            f"from its {self.CHECKPOINT}; else retrain with --overwrite") from e
        return rows

    def write_metrics(self, rows: list[dict[str, Any]]) -> None:
        def write(f: io.TextIOBase) -> None:
            w = csv.DictWriter(f, fieldnames=METRIC_COLUMNS)
            w.writeheader()
            w.writerows(rows)

        write_atomic(self.path / self.METRICS, write, binary=False)

    def append_metrics(self, row: dict[str, Any]) -> None:
        with (self.path / self.METRICS).open("a", newline="") as f:
            csv.DictWriter(f, fieldnames=METRIC_COLUMNS).writerow(row)

    # ---------------------------------------------------------------- the whole run
    def load(self, checkpoint: bool = False) -> Run:
        """Rebuild (model, normalizer, config, env config), the model in eval mode.

        ``checkpoint=True`` loads the weights of checkpoint.pt instead of model.pt (the state
        of an interrupted or diverged run).
        """
        record = self.read_record()
        where = self.path / self.CONFIG
        try:
            config = self.train_config(record)
            model_cfg = from_json(ModelConfig, record["model"], f"{where}: model")
            norm = Normalizer.from_dict(record["normalizer"])
            description = dict(record["description"])
            world_record = dict((record.get("world") or {}).get("record") or {})
        except (KeyError, TypeError, ValueError) as e:
            raise UserError(f"{where} is damaged ({type(e).__name__}: {e}); retrain the "
                            "run") from e
        if not model_cfg.resolved:
            raise UserError(f"{where}: the model's image shape or action size is missing; "
                            "retrain the run")
        check_description(description, where)
        enc = model_cfg.observation
        c, h, w = description["frame_shape"]
        size = getattr(enc, "image_size", h)
        seen = (getattr(enc, "channels", c), *(size if isinstance(size, list | tuple)
                                               else (size, size)), model_cfg.action_dim)
        given = (c, h, w, len(description["action_low"]))
        if tuple(seen) != given:
            raise UserError(f"{where}: the model takes {seen[0]}x{seen[1]}x{seen[2]} images "
                            f"and {seen[3]} actions but its data gave {given[0]}x{given[1]}x"
                            f"{given[2]} and {given[3]}: the file was edited; retrain the run")
        name = self.CHECKPOINT if checkpoint else self.MODEL
        if not (self.path / name).is_file():
            training = holder(self.path)
            hint = (f" ({training} is training it now: wait for it to finish)" if training
                    else "" if checkpoint or not self.interrupted else
                    f" (its training did not finish: resume it with --resume --out "
                    f"{self.path}, or load its checkpoint)")
            raise UserError(f"{self.path} has no {name}{hint}")
        payload = self.load_torch(name)
        check_action_box(description, payload, where, name)
        model = LatentModel(model_cfg)
        try:
            model.load_state_dict(payload["model"])
        except (KeyError, RuntimeError) as e:
            raise UserError(f"{self.path / name} does not match the model of {where} "
                            f"({type(e).__name__}); retrain the run") from e
        return Run(model.eval(), norm, config, description, world_record)

    def differences(self, record: Mapping[str, Any], ignore: frozenset[str] = RESUMABLE
                    ) -> list[str]:
        """Settings (train, normaliser, data identity) that differ between this run's record
        and ``record``, as "name (run X, now Y)"; keys in ``ignore`` (train settings) and the
        data path are left out."""
        old = self.read_record()

        def flat(r: Mapping[str, Any]) -> dict[str, Any]:
            data = {k: v for k, v in r["data"].items() if k != "path"}
            # through the dataclass, so both sides are written alike; "auto" batching as
            # what it batched
            tc = dataclasses.replace(self.train_config(r), batching=self.batching(r))
            train = json.loads(json.dumps(to_json(tc)))
            out = _flatten({"train": train, "normalizer": r["normalizer"], "data": data})
            # settings derived at training when left unset: what the model was built with
            for part, key in DERIVED:
                if (name := f"train.model.{part}.{key}") in out:
                    out[name] = _flatten(r["model"][part]).get(key)
            return out

        was, now = flat(old), flat(record)
        return [f"{k.removeprefix('train.')} (run {was.get(k)!r}, now {now.get(k)!r})"
                for k in sorted(set(was) | set(now))
                if k.removeprefix("train.") not in ignore and was.get(k) != now.get(k)]


def check_version(record: Mapping[str, Any], path: Path) -> None:
    """UserError, one line naming ``path``, where a run file (config.json, a .pt file) was
    written in another format version than this latent-sindy's."""
    version = record.get("format_version")
    if version != RUN_FORMAT_VERSION:
        raise UserError(f"{path} was written by another version of latent-sindy (run format "
                        f"version {version}; this one reads version {RUN_FORMAT_VERSION}): "
                        "retrain the run")


def load_run(run_dir: str | os.PathLike, checkpoint: bool = False) -> Run:
    """:meth:`RunDir.load` of ``run_dir``."""
    return RunDir(run_dir).load(checkpoint)


def read_metrics(run_dir: str | os.PathLike) -> list[dict[str, float | None]]:
    """:meth:`RunDir.read_metrics` of ``run_dir``."""
    return RunDir(run_dir).read_metrics()


def _metric_row(row: dict[Any, Any], path: Path, line: int, checkpoint: str
                ) -> dict[str, float | None]:
    """One row of metrics.csv as numbers; UserError naming ``path`` and ``line`` if damaged."""
    def damaged(what: str) -> UserError:
        return UserError(f"{path} line {line}: {what}; the file is damaged (a study restores "
                         f"a finished run's from its {checkpoint}; else retrain with "
                         "--overwrite)")

    if None in row:  # more cells than the header names
        raise damaged(f"{len(row) - 1 + len(row[None])} cells for {len(row) - 1} columns")
    out: dict[str, float | None] = {}
    for k, v in row.items():
        if v is None:  # fewer cells than the header names
            raise damaged(f"no value for {k}")
        try:
            out[k] = float(v) if v != "" else None
        except ValueError:
            raise damaged(f"{k} {v!r} is not a number") from None
    return out


def _flatten(d: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, Mapping):
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out
