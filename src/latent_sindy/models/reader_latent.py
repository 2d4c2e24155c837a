"""The latent a frame reader hands to :class:`~latent_sindy.read_latent.ReadLatent`, shared by
the geodesic and keypoint readers: a frame's coordinates, their change per second since the
frame before it, and the action held between the two; or, where two coordinates turn about
a centre, the angle's (cos φ, sin φ) and its turn per second in their place.

    >>> z = reader_latent(now, before, actions, dt=0.05)                # (B, 2·d + nu)
    >>> z = reader_latent(now, before, actions, dt=0.05, centre=c)      # (B, 3 + nu)
"""

from __future__ import annotations

import torch

__all__ = ["on_circle", "reader_latent"]


def on_circle(coords: torch.Tensor, centre: torch.Tensor) -> torch.Tensor:
    """Coordinates (B, 2) -> (cos φ, sin φ) of their angle φ about ``centre`` (2,)."""
    a = coords - centre
    return a / a.norm(dim=1, keepdim=True).clamp_min(1e-12)


def reader_latent(now: torch.Tensor, before: torch.Tensor, previous: torch.Tensor,
                  dt: float, centre: torch.Tensor | None = None) -> torch.Tensor:
    """Latents (B, 2·d + nu) of frames' coordinates ``now`` (B, d), those of the frames
    before them and the actions held since (B, nu); with ``centre``, (B, 3 + nu): the two
    coordinates' angle about it and its turn per second (the shorter way round)."""
    held = torch.as_tensor(previous).double().reshape(len(now), -1)
    if centre is None:
        return torch.cat([now, (now - before) / dt, held], -1)
    a, b = on_circle(now, centre), on_circle(before, centre)
    turn = torch.atan2(b[:, 0] * a[:, 1] - b[:, 1] * a[:, 0],
                       b[:, 0] * a[:, 0] + b[:, 1] * a[:, 1])
    return torch.cat([a, (turn / dt)[:, None], held], -1)
