"""Checks of what a user gives as data: pixels of a model's type, action names the equations
can print, a time step. Each refuses with one UserError naming the argument and the fix."""

from __future__ import annotations

import math
import numbers
import re
from collections.abc import Sequence
from typing import Any

import numpy as np

from latent_sindy.errors import UserError

__all__ = ["check_action_names", "check_dt", "check_pixels"]


def check_pixels(images: np.ndarray, pixel_dtype: str, name: str = "images") -> None:
    """UserError unless ``images`` are of the pixel type a model was trained on
    (``pixel_dtype``, a data description's): uint8 pixels (0..255) and floating-point ones
    (0..1) differ by a factor 255, so one passed for the other would give another latent."""
    arr = np.asarray(images)
    dtype = arr.dtype
    if pixel_dtype == "uint8":
        if not np.issubdtype(dtype, np.integer):
            if arr.size and np.issubdtype(dtype, np.floating) and np.nanmax(arr) > 1:
                # 0..255 already, as predict and simulate give a uint8 model's frames
                raise UserError(f"{name} are {dtype} pixels (0..255, as predict and simulate "
                                "return them) but this model takes uint8 pixels: pass "
                                f"np.round({name}).clip(0, 255).astype(np.uint8)")
            raise UserError(f"{name} are {dtype} but this model was trained on uint8 pixels "
                            f"(0..255): pass np.round({name} * 255).astype(np.uint8) for "
                            "pixels in [0, 1]")
    elif not np.issubdtype(dtype, np.floating):
        raise UserError(f"{name} are {dtype} but this model was trained on {pixel_dtype} "
                        f"pixels in [0, 1]: pass {name}.astype(np.float32) / 255 for uint8 "
                        "pixels")


#: Names an action may not have: the latents' and the actions' own variables (z0, u1: an
#: action named u1 at another place would read as that one), and the library's functions.
#: A bare z or u is free: the equations name only single variables (z0, u1), never a group.
_RESERVED = re.compile(r"^(z\d+|sin|cos)$")


def check_action_names(names: Any, n: int, where: str) -> None:
    """UserError (``where``: what the names are, e.g. "action_names") unless ``names`` is a
    list of ``n`` distinct identifiers, none a latent's (z0, ...), another action's variable
    (u1 at place 0) or a library function's (sin, cos): each is written into the equations."""
    if isinstance(names, str | bytes) or not isinstance(names, Sequence | np.ndarray):
        raise UserError(f"{where} {names!r}: give a list of {n} name(s), one per action "
                        f"(e.g. {['vx', 'vy', 'omega'][:max(n, 1)]})")
    names = list(names)
    if len(names) != n:
        raise UserError(f"{where} {names}: give a list of {n} name(s), one per action")
    for i, name in enumerate(names):
        if not (isinstance(name, str) and name.isidentifier()):
            raise UserError(f"{where}: {name!r} is not a name: use an identifier (letters, "
                            "digits and _, not starting with a digit), e.g. vx")
        own = re.fullmatch(r"u(\d+)", name)
        if _RESERVED.match(name) or (own and int(own[1]) != i):
            raise UserError(f"{where}: {name!r} is a name the equations already use (the "
                            "latents z0, z1, ..., the actions' u0, u1, ... by place, sin, "
                            "cos): choose another")
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:
        raise UserError(f"{where}: {twice[0]!r} names more than one action: give each action "
                        "its own name")


def check_dt(dt: Any, where: str) -> float | None:
    """The time between frames ``dt`` as a float (None: not known); UserError where it is no
    positive finite number (a string or a bool included)."""
    if dt is None:
        return None
    if isinstance(dt, bool | np.bool_) or not isinstance(dt, numbers.Real):
        raise UserError(f"{where}: dt={dt!r}: give the time between frames as a positive "
                        "number (e.g. dt=0.1), or None where it is not known")
    if not (math.isfinite(dt) and dt > 0):
        raise UserError(f"{where}: dt must be a positive number, got {dt}")
    return float(dt)
