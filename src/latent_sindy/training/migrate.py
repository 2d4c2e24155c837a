"""Run records of earlier versions, read as the current one: format version 1 (a flat model
config) and runs trained before data were generic (an "env" record: the pushing world's)."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from latent_sindy.configs import one_name_each
from latent_sindy.errors import UserError
from latent_sindy.plugins import legacy_world
from latent_sindy.training.record import RUN_FORMAT_VERSION

__all__ = ["migrate_v1", "run_description"]


def run_description(record: Mapping[str, Any], where: Path) -> tuple[dict, dict]:
    """The data description and world record of a run; runs recorded before data were
    generic (an "env" record) get theirs from the world that wrote them
    (:func:`~latent_sindy.plugins.legacy_world`)."""
    if "description" in record:
        world = record.get("world") or {}
        return dict(record["description"]), dict(world.get("record") or {})
    world_record = {"env_config": record["env"]}
    world = legacy_world()
    env = world.config_from_record(world_record, str(where))
    description = {"frame_shape": [env.channels, env.image_size, env.image_size],
                   "pixel_dtype": "uint8", "action_low": list(env.action_low),
                   "action_high": list(env.action_high),
                   "action_names": list(env.action_names), "state_names": ["x", "y", "θ"],
                   "state_periods": [None, None, env.angle_period], "dt": None,
                   "world": world.name}
    return description, world_record



#: Version 1's loss weights, at the top of the training settings.
_LOSS_V1 = ("lambda_pred_x", "lambda_pred_z", "lambda_l1")

_AUTOENCODER_V1 = ("channels", "image_size", "latent_dim", "conv_channels", "encoder_hidden",
                   "decoder", "decoder_hidden", "decoder_channels")


def _model_v1(m: Mapping[str, Any], resolved: bool) -> dict[str, Any]:
    """A version-1 flat model config as the nested version-2 one (version 1 always had
    three actions; an unresolved config now leaves the action size to the data)."""
    m = dict(m)
    kind = m.get("kind", "sindy")
    dynamics: dict[str, Any] = {"kind": kind}
    if kind == "sindy":
        dynamics.update(order=m.get("order", 2), include_sine=m.get("include_sine", True),
                        init_scale=m.get("init_scale", 1e-3))
    elif kind == "linear":
        dynamics.update(init_scale=m.get("init_scale", 1e-3))
    elif kind == "mlp":
        dynamics.update(hidden=m.get("mlp_hidden", 128), layers=m.get("mlp_layers", 2))
    auto = {"kind": "image", **{k: m[k] for k in _AUTOENCODER_V1 if k in m}}
    auto.setdefault("decoder", "fc")  # runs saved before the conv decoder existed
    action_dim = m.get("action_dim", 3) if resolved else None
    return {"dynamics": dynamics, "encoder": auto, "action_dim": action_dim}


def migrate_v1(record: Mapping[str, Any], where: str = "config.json") -> dict[str, Any]:
    """A version-1 record (flat model config, ``horizon``, loss weights at the top of the
    training settings) in the current layout; the values are kept as they were. A setting
    under its version-1 name and its current one together is refused (UserError)."""
    record = json.loads(json.dumps(record))
    train = record["train"]
    if isinstance(train, dict):
        one_name_each({"horizon": "window"}, train, f"{where}: train")
        weights = [k for k in _LOSS_V1 if k in train]
        if weights and "loss" in train:
            raise UserError(f"{where}: train holds {weights[0]} and loss, the same setting "
                            "(version 1 kept the loss weights at the top): keep loss only")
    train["window"] = train.pop("horizon", 1)
    train["loss"] = {k: train.pop(k) for k in _LOSS_V1 if k in train}
    train["model"] = _model_v1(train["model"], resolved=False)
    record["model"] = _model_v1(record["model"], resolved=True)
    record["format_version"] = RUN_FORMAT_VERSION
    return record
