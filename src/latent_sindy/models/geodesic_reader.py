"""A latent learned from the frames alone: the geodesic coordinates of what moves in them.

Frames of a system lie on a low-dimensional surface in pixel space, one point per state of
what is seen (a pendulum's frames on a circle, a cart-pole's on a cylinder). The reader
learns that surface's coordinates from training frames (:mod:`latent_sindy.models.manifold`:
principal components, then Isomap on landmarks) and reads any frame by interpolating its
nearest landmarks' coordinates. Nothing in it knows what is filmed: its one structural
setting is ``dim``, the number of coordinates (the motions' count, a turning one counted
twice: a circle needs two).

Observations are frames stacked as channels (``frames`` of them, oldest first). The latent
of one is the newest frame's coordinates, their change per second since the frame before it,
and the action held between the two (their change depends on it), so a first-order model
of the latent sees positions, velocities and what pushed them.

A closed curve (two coordinates that wind once around their centre: a thing that turns
all the way round) is read as the angle φ about that centre instead: the latent is cos φ,
sin φ, the turn per second and the action, and the pair is the ``circle`` that the dynamics
keep on the unit circle at every step. Whether the curve is closed is the data's: every
twelfth of the turn holds training frames, and none lies near the centre
(:func:`winds_round`). φ is the curve's own angle, a smooth monotone function of the
thing's (Isomap's coordinates bend a little where the frames are sparse). It serves
:class:`~latent_sindy.read_latent.ReadLatent` like a world's hand-made reader, which fits
dynamics and a reward head on it and plans.

    >>> reader = GeodesicReader(frames=2, dim=2).fit_episodes(images)   # (E, T+1, C, H, W)
    >>> z, seen = reader.episode(images[0], actions[0], dt=0.05)        # (T+1, nz)
"""

from __future__ import annotations

import math

import torch

from latent_sindy.errors import UserError
from latent_sindy.models.manifold import (
    LANDMARKS,
    NEIGHBOURS,
    Manifold,
    geodesic_coordinates,
    principal_front,
)
from latent_sindy.models.reader_latent import on_circle, reader_latent
from latent_sindy.models.stacked_frames import newest_and_before

__all__ = ["GeodesicReader", "winds_round"]

#: Principal components the frames are projected on before their geodesic coordinates.
COMPONENTS = 32
#: Training frames the coordinates are learned from at most (an even subsample beyond).
MAX_FRAMES = 20_000


class GeodesicReader:
    """Geodesic coordinates of each frame, learned from training frames; see the module
    docstring.

    Args:
        frames: frames stacked as channels in one observation (their colours split evenly;
            with one frame the rates are 0: nothing shows them).
        dim: coordinates of a frame (a circle's motion needs 2).
        components: principal components of the frames the coordinates are learned on.
        landmarks, neighbours: Isomap's landmarks and each one's graph neighbours.
        seed: the landmarks' first point and the principal components' random start.
        angle: read two coordinates as an angle about their centre (True; needs dim 2),
            never (False), or where they wind round it (None: :func:`winds_round`).
    """

    def __init__(self, frames: int = 2, dim: int = 2, components: int = COMPONENTS,
                 landmarks: int = LANDMARKS, neighbours: int = NEIGHBOURS, seed: int = 0,
                 angle: bool | None = None) -> None:
        for name, value, low in (("frames", frames, 1), ("dim", dim, 1),
                                 ("components", components, 1), ("landmarks", landmarks, 3),
                                 ("neighbours", neighbours, 1)):
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise UserError(f"GeodesicReader {name}={value!r}: use an integer >= {low}")
        if dim >= landmarks:
            raise UserError(f"GeodesicReader dim={dim}: use fewer coordinates than the "
                            f"{landmarks} landmarks")
        if angle not in (None, True, False) or (angle and dim != 2):
            raise UserError(f"GeodesicReader angle={angle!r}: use None (from the data), "
                            "False, or True with dim=2")
        self.frames = frames
        self.dim = dim
        self.components = components
        self.landmarks = landmarks
        self.neighbours = neighbours
        self.seed = seed
        self.angle = angle
        self.names = tuple(f"g{i}" for i in range(dim)) + tuple(
            f"g{i}'" for i in range(dim))
        self.circle: tuple[int, int] | None = None  # set by fit_episodes

    # ------------------------------------------------------------------ fitting
    @staticmethod
    def _pixels(frames: torch.Tensor) -> torch.Tensor:
        """Frames (B, ...) -> (B, pixels) float64, in [0, 1] where they are uint8."""
        x = frames.reshape(len(frames), -1).double()
        return x / 255.0 if frames.dtype == torch.uint8 else x

    def _split(self, obs: torch.Tensor, where: str) -> tuple[torch.Tensor, torch.Tensor]:
        """Observations (B, C, H, W) -> their newest frames and the frames before those."""
        return newest_and_before(obs, self.frames, f"GeodesicReader.{where}")

    def fit_episodes(self, images: torch.Tensor) -> GeodesicReader:
        """Learn the coordinates from training episodes' observations (E, T+1, C, H, W)."""
        images = torch.as_tensor(images)
        if images.ndim != 5:
            raise UserError(f"GeodesicReader.fit_episodes: expected episodes (E, T+1, C, H, "
                            f"W), got {tuple(images.shape)}")
        x = self._pixels(self._split(images.flatten(0, 1), "fit_episodes")[0])
        if len(x) > MAX_FRAMES:
            x = x[torch.linspace(0, len(x) - 1, MAX_FRAMES).round().long()]
        if len(x) <= self.dim + 1:
            raise UserError(f"GeodesicReader.fit_episodes: {len(x)} frames are too few for "
                            f"{self.dim} coordinates; collect more episodes")
        self.shape_ = tuple(images.shape[2:])
        self.mean_, self.axes_ = principal_front(x, self.components, self.seed)
        self.manifold_: Manifold = geodesic_coordinates(
            (x - self.mean_) @ self.axes_, self.dim, self.landmarks, self.neighbours, self.seed)
        coords = self.manifold_.coords
        self.centre_ = coords.mean(0)
        closed = self.dim == 2 and winds_round(coords - self.centre_)
        self.turns_ = bool(closed if self.angle is None else self.angle)
        self.circle = (0, 1) if self.turns_ else None
        self.names = (("cos φ", "sin φ", "φ'") if self.turns_ else
                      tuple(f"g{i}" for i in range(self.dim))
                      + tuple(f"g{i}'" for i in range(self.dim)))
        return self

    # ------------------------------------------------------------------ reading
    def record(self) -> dict:
        """What the fit found, JSON-ready: the coordinates and whether they are read as an
        angle; ``summary``, the same in a line."""
        if not hasattr(self, "manifold_"):
            raise UserError("GeodesicReader.record before fit_episodes: fit it first")
        return {"reader": "geodesic", "dim": self.dim, "angle": self.turns_,
                "summary": f"{self.dim} geodesic coordinate(s)"
                           + (", read as an angle" if self.turns_ else "")}

    def read(self, frames: torch.Tensor) -> torch.Tensor:
        """Coordinates (B, dim) float64 of single frames (B, C / frames, H, W)."""
        if not hasattr(self, "manifold_"):
            raise UserError("GeodesicReader.read before fit_episodes: fit it on training "
                            "episodes first")
        frames = torch.as_tensor(frames)
        x = self._pixels(frames)
        if x.shape[1] != len(self.mean_):
            raise UserError(f"GeodesicReader.read: frames of {tuple(frames.shape[1:])} for a "
                            f"reader fitted on observations {self.shape_} of {self.frames} "
                            "frames")
        return self.manifold_.transform((x - self.mean_) @ self.axes_)

    def position(self, frames: torch.Tensor) -> torch.Tensor:
        """What the latent holds of single frames (B, C / frames, H, W): the angle's
        (cos φ, sin φ) (B, 2) where the coordinates wind round, else the coordinates
        (B, dim)."""
        g = self.read(frames)
        return on_circle(g, self.centre_) if self.turns_ else g

    def _latent(self, now: torch.Tensor, before: torch.Tensor, previous: torch.Tensor,
                dt: float) -> torch.Tensor:
        return reader_latent(now, before, previous, dt, self.centre_ if self.turns_ else None)

    def latent(self, obs: torch.Tensor, previous: torch.Tensor, dt: float
               ) -> tuple[torch.Tensor, torch.Tensor]:
        """Latents (B, 2·dim + nu; a closed curve's 3 + nu) of observations (B, C, H, W)
        and the actions held since the frame before the newest (B, nu); and (B,) True
        (every frame is read)."""
        newest, earlier = self._split(torch.as_tensor(obs), "latent")
        now = self.read(newest)
        before = self.read(earlier) if self.frames > 1 else now
        return (self._latent(now, before, previous, dt),
                torch.ones(len(obs), dtype=torch.bool))

    def episode(self, images: torch.Tensor, actions: torch.Tensor, dt: float
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """One episode's latents (T+1, 2·dim + nu; a closed curve's 3 + nu) from its
        observations (T+1, C, H, W) and actions (T, nu), each newest frame read once (a
        frame's earlier one is the last step's; the first step's is its own
        observation's, with no action before it)."""
        images, actions = torch.as_tensor(images), torch.as_tensor(actions)
        if images.ndim != 4 or actions.ndim != 2 or len(actions) != len(images) - 1:
            raise UserError(f"GeodesicReader.episode: expected observations (T+1, C, H, W) "
                            f"and actions (T, nu), got {tuple(images.shape)} and "
                            f"{tuple(actions.shape)}")
        newest, earlier = self._split(images, "episode")
        now = self.read(newest)
        first = self.read(earlier[:1]) if self.frames > 1 else now[:1]
        previous = torch.cat([torch.zeros_like(actions[:1]), actions]).double()
        return (self._latent(now, torch.cat([first, now[:-1]]), previous, dt),
                torch.ones(len(images), dtype=torch.bool))


def winds_round(coords: torch.Tensor, sectors: int = 12, inner: float = 0.3) -> bool:
    """Whether points (N, 2) about their centre (0, 0) trace a closed curve: each of
    ``sectors`` equal turns about the centre holds some, and none lies within ``inner`` of
    the median distance from it."""
    radius = coords.norm(dim=1)
    if len(coords) < sectors or float(radius.min()) < inner * float(radius.median()):
        return False
    phase = torch.atan2(coords[:, 1], coords[:, 0])
    held = ((phase + math.pi) / (2 * math.pi) * sectors).long().clamp(0, sectors - 1)
    return len(torch.unique(held)) == sectors
