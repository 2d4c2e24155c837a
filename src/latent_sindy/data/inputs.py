"""What a fitted model takes from its user: frames of its shape and pixel type, actions of its
size, each refused with one UserError naming the argument and what to give instead.

    x = check_frames(images, "images", (4,), frame_shape=(3, 20, 28), pixel_dtype="uint8")
    u = check_actions(actions, "actions", (len(x),), nu=2)
"""

from __future__ import annotations

import numbers
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from latent_sindy.configs import checked_value
from latent_sindy.data.checks import check_action_names, check_pixels
from latent_sindy.errors import UserError

__all__ = ["action_names", "check_action_names", "check_actions", "check_estimator_arguments",
           "check_folder", "check_frames", "check_pixels", "check_previous",
           "check_rollout_actions"]


def check_frames(images: Any, name: str, dims: Sequence[int], frame_shape: Sequence[int],
                 pixel_dtype: str) -> np.ndarray:
    """``images`` (argument ``name``) as an array of ``dims`` dimensions whose last three are
    a frame (C, H, W) = ``frame_shape`` in the pixel type ``pixel_dtype``."""
    x = np.asarray(images)
    shape = tuple(frame_shape)
    if x.ndim not in dims or x.shape[-3:] != shape:
        want = " or ".join({3: "(C, H, W)", 4: "(N, C, H, W)"}.get(d, f"{d}-D") for d in dims)
        raise UserError(f"{name} of shape {x.shape} do not fit this model: give {want} with "
                        f"frames (C, H, W) = {shape}")
    if x.size == 0:
        raise UserError(f"{name} of shape {x.shape} hold no frame: give at least one "
                        f"(N >= 1 in (N, C, H, W))")
    check_pixels(x, pixel_dtype, name)
    return x


def check_actions(actions: Any, name: str, lead: tuple[int, ...], nu: int) -> np.ndarray:
    """``actions`` (argument ``name``) as float32 of shape (*lead, nu), every value finite."""
    try:
        u = np.asarray(actions, dtype=np.float32)
    except (TypeError, ValueError):
        raise UserError(f"{name} must be numbers, of shape {(*lead, nu)}") from None
    if u.shape != (*lead, nu):
        raise UserError(f"{name} of shape {u.shape} do not fit: give {(*lead, nu)} (this model "
                        f"takes {nu} action(s) a step)")
    if not np.all(np.isfinite(u)):
        raise UserError(f"{name} hold NaN or infinite values")
    return u


#: The estimator's arguments that are numbers or flags: the type each takes, the least
#: value (None: any), and what they are.
_ARGUMENTS: dict[str, tuple[Any, int | None, str]] = {
    "latent_dim": (int, 1, "the latent state's size"),
    "order": (int | None, 1, "SINDy's polynomial order"),
    "include_sine": (bool, None, "whether the library holds sin(z)"),
    "seed": (int, 0, "the random seed"),
    "derivative_order": (int, 1, "continuous time: 1 or 2"),
    "pca_components": (int | None, 0, "principal components in front of the encoder"),
}


def check_estimator_arguments(*values: Any) -> None:
    """UserError naming the first of LatentSINDy's arguments (``values``: those of
    :data:`_ARGUMENTS`, then time_unit, in order) of the wrong type
    (a bool, a string or a fraction where an integer is meant) or below its least value."""
    given = dict(zip([*_ARGUMENTS, "time_unit"], values, strict=True))
    for name, (tp, least, what) in _ARGUMENTS.items():
        value = checked_value(tp, given[name], f"LatentSINDy: {name}")
        if least is not None and value is not None and value < least:
            raise UserError(f"LatentSINDy: {name}={value!r} ({what}): use {least} or more")
    unit = given["time_unit"]
    if not (unit is None or unit == "data" or (  # (a number's value: the model's check)
            isinstance(unit, numbers.Real) and not isinstance(unit, bool | np.bool_))):
        raise UserError(f"LatentSINDy: time_unit={unit!r}: give a positive number (the unit "
                        "of time the coefficients are fitted in, in the data's), \"data\" (chosen "
                        "from the data) or None")


def check_rollout_actions(actions: Any, single: bool, n: int, nu: int) -> Any:
    """simulate's ``actions``: (T, nu) for one image (``single``), else (N, T, nu) with N =
    ``n``; a number of steps T for a model without actions (as zeros of no column)."""
    if isinstance(actions, int | np.integer) and not isinstance(actions, bool):
        if nu:
            raise UserError(f"simulate: this model takes {nu} action(s) a step: give the "
                            f"actions (T, {nu}), not a number of steps")
        if actions < 0:
            raise UserError(f"simulate: {actions} steps: use 0 or more")
        actions = np.zeros((int(actions), 0) if single else (n, int(actions), 0))
    want = f"(T, {nu})" if single else f"(N, T, nu) with N = {n}, nu = {nu}"
    if np.ndim(actions) != (2 if single else 3) or (not single and len(actions) != n):
        raise UserError(f"actions of shape {np.shape(actions)}: give {want}, the actions "
                        "of each step")
    return actions


def check_previous(dynamics: Any, previous: Any, method: str) -> bool:
    """Whether ``dynamics`` are of second order (a step needs the latent's velocity, so the
    frames one dt before, ``previous``); a UserError saying what to pass where ``previous``
    is missing, or given to a model that does not take it."""
    if getattr(dynamics, "derivative_order", 1) == 1:
        if previous is not None:
            raise UserError(f"{method}(..., previous=...) is for second-order "
                            "continuous-time models (z'' = ...): this model steps from the "
                            "image alone; drop previous")
        return False
    if previous is None:
        raise UserError(f"a second-order continuous-time model steps from the latent and its "
                        f"velocity, which one frame does not give: pass the frames one time "
                        f"step (dt = {dynamics.dt:g}) before as well, {method}(images, "
                        f"actions, previous=frames_before), both (N, C, H, W) or (C, H, W) "
                        f"(e.g. images = video[:, t], previous = video[:, t - 1])")
    return True


def check_folder(path: Any, method: str) -> Path:
    """A folder argument of ``method`` as a Path ("." as the folder it names); UserError for
    an empty one or one that is no path."""
    if not isinstance(path, str | os.PathLike) or not os.fspath(path).strip():
        raise UserError(f"{method}({path!r}): give the folder to save the run into, e.g. "
                        f"{method}(\"runs/mine\")")
    return Path(path) if Path(path).name else Path(path).resolve()


def action_names(description: dict[str, Any], given: Any = None) -> list[str]:
    """The names a model's equations give its actions: ``given`` (checked against the
    ``description`` of its data), else the data's own."""
    if given is None:
        return list(description.get("action_names") or [])
    check_action_names(given, len(description["action_low"]), "action_names")
    return list(given)
