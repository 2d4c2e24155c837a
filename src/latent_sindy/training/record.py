"""What a run folder's config.json records: the settings, the model resolved against the data,
the normaliser, the data's identity and description, and the world it came from.

    record = run_record(TrainConfig(data=Path("data/push.h5")), read_sequences("data/push.h5"))
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from latent_sindy.configs import to_json
from latent_sindy.data import SequenceData
from latent_sindy.data.windows import OBSERVATIONS
from latent_sindy.errors import UserError
from latent_sindy.models.dynamics.continuous import time_unit_for
from latent_sindy.models.latent_model import ModelConfig
from latent_sindy.plugins import get_world, hook
from latent_sindy.training.config import TrainConfig, resolve_batching

__all__ = ["PIXEL_DTYPES", "RECORD_KEYS", "RUN_FORMAT", "RUN_FORMAT_VERSION",
           "action_box", "check_action_box", "check_derivatives", "check_description",
           "data_identity", "data_time", "resolve_model", "run_record"]

RUN_FORMAT = "latent-sindy-run"
RUN_FORMAT_VERSION = 3


#: The keys config.json may hold at its top ("kept": a finished run's).
RECORD_KEYS = frozenset({"format", "format_version", "package_version", "created", "train",
                         "batching", "model", "normalizer", "data", "description", "world",
                         "kept"})


def data_identity(data: SequenceData, path: Path | None) -> dict[str, Any]:
    """Which data a run was trained on (compared when it is resumed or reused): the arrays'
    fingerprint, and what a model also depends on (time step, action box, exact derivatives,
    executed actions)."""
    return {
        "path": None if path is None else str(path.resolve()),
        "fingerprint": data.fingerprint(),
        "dt": data.dt,
        "action_low": list(data.action_low),
        "action_high": list(data.action_high),
        "extras_fingerprint": data.extras_fingerprint(),
        "seed": data.seed,
        "trajectories": data.n,
        "steps": data.steps,
        "splits": data.split_counts(),
    }


def resolve_model(model: ModelConfig, data: SequenceData, where: str,
                  derivatives: tuple[str, int] = ("auto", 9)) -> ModelConfig:
    """``model`` with its shapes taken from ``data``, a continuous-time unit chosen from
    them (their derivatives as ``derivatives``, the training's method and window, give
    them), and the settings the data's world derives (its ``prepare_model``); UserError
    where they contradict the data."""
    if model.reward_head and data.rewards is None:
        raise UserError(f"{where} has no rewards: a reward head (reward_head={model.reward_head}"
                        ") learns them; give data with rewards (SequenceData(rewards=...), "
                        "a world that returns them), or drop the head")
    c, h, w = data.frame_shape
    cfg = model.resolve(c, h if h == w else (h, w), data.nu, source=where)
    dyn = cfg.dynamics
    if dyn.kind == "continuous" and dyn.dt is None and data.dt is not None:
        cfg = dataclasses.replace(cfg, dynamics=dataclasses.replace(dyn, dt=data.dt))
    if dyn.kind == "continuous" and dyn.time_unit is None:
        unit = time_unit_for(data_time(data, dyn.derivative_order, where, *derivatives))
        cfg = dataclasses.replace(cfg, dynamics=dataclasses.replace(cfg.dynamics,
                                                                    time_unit=unit))
    world = get_world(data.world) if data.world is not None else None
    prepare = hook(world, "prepare_model")
    if prepare is not None:
        return prepare(cfg, data, where)
    return cfg


#: Training sequences :func:`data_time` reads at most (it estimates their derivatives).
TIME_SEQUENCES = 64


def data_time(data: SequenceData, order: int, where: str, derivatives: str = "auto",
              window: int = 9) -> float:
    """The time the motion in ``data``'s training frames takes
    (:func:`~latent_sindy.models.derivatives.motion_time`, the centroid of what moves, on at
    most :data:`TIME_SEQUENCES` sequences), whatever the derivatives given
    or how they are taken (``order``, ``derivatives`` and ``window`` are kept for callers).
    Sequences of under three frames read it as before, from the pixels' ``order``-th
    derivatives (:func:`~latent_sindy.models.derivatives.characteristic_time` over
    :data:`PIXEL_TIME_RATIO` of the motion's)."""
    from latent_sindy.models.derivatives import (
        characteristic_time,
        estimate_derivatives,
        motion_time,
    )

    part = data.split("train")
    if part.n == 0:
        raise UserError(f"{where} has no training sequences to choose a time unit from")
    keep = slice(0, TIME_SEQUENCES)
    frames = np.asarray(part.images[keep])
    if frames.shape[1] >= 3 and data.dt:
        return motion_time(frames, data.dt)
    given = [part.images_dot, part.images_ddot][:order] if derivatives == "auto" else []
    if len(given) == order and all(g is not None for g in given):
        rate = np.asarray(given[-1][keep])
    else:
        method = "central" if derivatives in ("auto", "latent") else derivatives
        exact = np.asarray(given[0][keep]) if given and given[0] is not None and order == 2 \
            else None
        rate = estimate_derivatives(frames, data.dt or 1.0, order, method, window,
                                    dx=exact)[order - 1]
    return PIXEL_TIME_RATIO * characteristic_time(frames.reshape(-1, *frames.shape[2:]),
                                                  rate.reshape(-1, *rate.shape[2:]), order)


#: The motion time over the pixels' characteristic time on the pendulum video (1.013 / 0.141).
PIXEL_TIME_RATIO = 1.013 / 0.141


def check_derivatives(cfg: TrainConfig, data: SequenceData) -> None:
    """UserError where a continuous-time model would need to estimate the data's derivatives
    and cannot: no time step, or too few frames."""
    if cfg.model.dynamics.kind != "continuous":
        return
    order = cfg.model.dynamics.derivative_order
    given = [data.images_dot, data.images_ddot][:order]
    if cfg.derivatives == "auto" and all(g is not None for g in given):
        return
    if data.dt is None:
        raise UserError(f"{data.source}: continuous-time dynamics need the frames' time "
                        "derivatives: give the data's time step (SequenceData(dt=...)) to "
                        "estimate them from the frames, or the exact ones (images_dot"
                        + (", images_ddot)" if order == 2 else ")"))
    need = 5 if cfg.derivatives in ("smooth", "latent") else 4
    if data.steps + 1 < max(need, cfg.derivative_window if cfg.derivatives == "smooth" else 0):
        raise UserError(f"{data.source}: sequences of {data.steps + 1} frames are too short "
                        f"to estimate derivatives ({cfg.derivatives}): use longer sequences "
                        "or give the exact derivatives")


def run_record(cfg: TrainConfig, data: SequenceData) -> dict[str, Any]:
    """What RUN/config.json holds for training ``cfg`` on ``data`` (JSON values); the data's
    identity names its file (``data.source``), or none for data held in memory.

    Resolves the model's shapes from the data; raises UserError where they contradict it.
    """
    from latent_sindy.version import __version__

    path = None if data.source.startswith("<") else Path(data.source)  # (held in memory)
    check_derivatives(cfg, data)
    model_cfg = resolve_model(cfg.model, data, data.source,
                              (cfg.derivatives, cfg.derivative_window))
    record = {
        "format": RUN_FORMAT,
        "format_version": RUN_FORMAT_VERSION,
        "package_version": __version__,
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        "train": to_json(cfg),
        "batching": resolve_batching(cfg),  # what train.batching ("auto") batched
        "model": to_json(model_cfg),
        "normalizer": OBSERVATIONS[model_cfg.observation.kind].normalizer(data).to_dict(),
        "data": data_identity(data, path),
        "description": data.describe(),  # what the model needs to know of its data
        # the world the images came from, its own record (for control)
        "world": {"name": data.world,
                  "record": {k: v for k, v in data.record.items() if k != "collection"}},
    }
    return json.loads(json.dumps(record))  # as config.json will hold it


def action_box(description: Mapping[str, Any]) -> list[list[float]]:
    """The action box of a run's description, [action_low, action_high]: saved in its .pt
    files beside the weights, so an edited config.json is seen (:func:`check_action_box`)."""
    return [[float(v) for v in description["action_low"]],
            [float(v) for v in description["action_high"]]]


def check_action_box(description: Mapping[str, Any], payload: Mapping[str, Any], where: Path,
                     name: str) -> None:
    """UserError where the action box of a run's description (config.json, ``where``)
    differs from the one the model was trained with, kept in its .pt file ``name``
    (``payload``)."""
    trained = payload.get("action_box")
    if not (isinstance(trained, list | tuple) and len(trained) == 2):
        raise UserError(f"{where.parent / name} keeps no action box (the file was edited): "
                        "retrain the run")
    if action_box(description) != [[float(v) for v in side] for side in trained]:
        low, high = trained
        raise UserError(f"{where}: the action box (action_low {description['action_low']}, "
                        f"action_high {description['action_high']}) is not the one the model "
                        f"was trained with (action_low {list(low)}, action_high {list(high)}, "
                        f"kept in {name}): the file was edited; put that box back, or retrain "
                        "the run on data with the box you want")


#: The pixel types a model can have been trained on (SequenceData's images).
PIXEL_DTYPES = ("uint8", "float16", "float32", "float64")


def check_description(d: Mapping[str, Any], where: Path) -> None:
    """UserError where a run's description of its data contradicts itself (an edited file):
    a pixel type images cannot have, names of the wrong count, a malformed action box."""
    def edited(what: str) -> UserError:
        return UserError(f"{where}: description {what}: the file was edited; retrain the run")

    low, high = d.get("action_low"), d.get("action_high")
    if not (isinstance(low, list) and isinstance(high, list) and len(low) == len(high)
            and all(isinstance(v, int | float) for v in low + high)):
        raise edited(f"action_low {low!r} and action_high {high!r} are not an action box")
    if not all(math.isfinite(lo) and math.isfinite(hi) and lo < hi
               for lo, hi in zip(low, high, strict=True)):
        raise edited(f"action_low {low} and action_high {high} are not a finite box with "
                     "action_low < action_high")
    if d.get("pixel_dtype", "uint8") not in PIXEL_DTYPES:
        raise edited(f"pixel_dtype {d.get('pixel_dtype')!r} is not one of "
                     f"{', '.join(PIXEL_DTYPES)}")
    counts = [("action_names", len(low), "actions")]
    if isinstance(d.get("state_periods"), list):
        counts.append(("state_names", len(d["state_periods"]), "states"))
    for names, count, of in counts:
        given = d.get(names)
        if given is None:
            continue
        if not (isinstance(given, list) and all(isinstance(n, str) for n in given)):
            raise edited(f"{names} {given!r} is not a list of names")
        if len(given) != count:
            raise edited(f"{names} has {len(given)} name(s) for {count} {of}")
