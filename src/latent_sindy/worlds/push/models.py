"""What the pushing world derives for a model trained on its data: the frame library's
orientation sense and offset (on the moments latent its camera's), and the checks that a
library or encoder fits the block's visible symmetry and the world's push style."""

from __future__ import annotations

import dataclasses
import math

from latent_sindy.data import SequenceData
from latent_sindy.errors import UserError
from latent_sindy.models.latent_model import ModelConfig
from latent_sindy.worlds.push.data import push_config

__all__ = ["prepare_model"]


def _check_symmetry(name: str, value: float, data: SequenceData, where: str,
                    sep: str = " ") -> None:
    """UserError unless ``value`` is the data's visible symmetry, 2π / its angle period
    (``name``, ``sep`` and the value as the user gives them)."""
    period = push_config(data, where).angle_period
    f = 2 * math.pi / period
    if abs(value - f) > 1e-9:
        raise UserError(f"{name}{sep}{value:g} does not match {where}: its block looks alike "
                        f"every {math.degrees(period):g}°, so use {name}{sep}{f:g}")


def _resolve_frame(model_cfg: ModelConfig, data: SequenceData, where: str) -> ModelConfig:
    """A model config whose frame library has its orientation sense and offset stated: on the
    moments latent the data's camera's (a value given must match), else 1 and 0 where unset
    (world angles); any other config as it is."""
    dyn = model_cfg.dynamics
    if getattr(dyn, "library", None) != "frame":
        return model_cfg
    options = dyn.options
    moments = getattr(model_cfg.observation, "encoder_kind", None) == "moments"
    if moments:
        from latent_sindy.worlds.push.camera import moment_frame  # (loads the simulator)

        sense, offset = moment_frame(push_config(data, where))
        off = options.offset is not None and abs(
            math.remainder(options.offset - offset, 2 * math.pi)) > 1e-4
        if options.sense not in (None, sense) or off:
            raise UserError(f"--library frame on the moments latent of {where}: its camera "
                            f"shows the world's angles with sense {sense} and offset "
                            f"{offset:.6f}: leave sense and offset out of --library-options "
                            f"to use them, or give --library-options sense={sense} "
                            f"offset={offset!r}")
    else:
        sense = 1 if options.sense is None else options.sense
        offset = 0.0 if options.offset is None else options.offset
    return dataclasses.replace(model_cfg, dynamics=dyn.with_options(sense=sense, offset=offset))


def prepare_model(model_cfg: ModelConfig, data: SequenceData, where: str) -> ModelConfig:
    """``model_cfg`` (its shapes resolved) checked against the pushing data ``data`` and with
    the settings this world derives stated."""
    if getattr(model_cfg.observation, "encoder_kind", None) == "moments":
        _check_symmetry("--moment-order", model_cfg.observation.moment_order, data, where)
    library = getattr(model_cfg.dynamics, "library", None)
    if library in ("face", "frame") and model_cfg.dynamics.options.frequency != 0:
        # (0: the learned encoder's order, chosen from the data, is not checked against the
        # world's symmetry: nothing is set by hand)
        _check_symmetry("--library-options frequency", model_cfg.dynamics.options.frequency,
                        data, where, sep="=")
    model_cfg = _resolve_frame(model_cfg, data, where)
    push = push_config(data, where).push
    if library in ("face", "frame") and push != "symmetric":
        raise UserError(f"--library {library} writes pushes given as world directions, but "
                        f"{where} was collected with push style '{push}' "
                        "(the angle relative to the block): use --library push")
    return model_cfg
