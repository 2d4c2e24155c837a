"""Observations of frames stacked as channels, as the frame readers take them."""

from __future__ import annotations

import torch

from latent_sindy.errors import UserError

__all__ = ["newest_and_before"]


def newest_and_before(obs: torch.Tensor, frames: int, where: str
                      ) -> tuple[torch.Tensor, torch.Tensor]:
    """Observations (B, C, H, W) of ``frames`` stacked frames -> their newest frames and the
    frames before those (the newest again where one frame is stacked), each
    (B, C / frames, H, W); ``where`` names the caller in the error."""
    if obs.ndim != 4 or obs.shape[1] % frames:
        raise UserError(f"{where}: expected observations (B, C, H, W) of {frames} stacked "
                        f"frames (C a multiple of {frames}), got {tuple(obs.shape)}")
    per = obs.shape[1] // frames
    newest = obs[:, -per:]
    return newest, (obs[:, -2 * per:-per] if frames > 1 else newest)
