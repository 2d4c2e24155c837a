"""What a fitted model takes from its user: frames of its shape and pixel type, actions of its
size, each refused with one UserError naming the argument and what to give instead.

    x = check_frames(images, "images", (4,), frame_shape=(3, 20, 28), pixel_dtype="uint8")
    u = check_actions(actions, "actions", (len(x),), nu=2)
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from latent_sindy.data.sequence import check_pixels
from latent_sindy.errors import UserError

__all__ = ["check_actions", "check_frames", "check_pixels"]


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
