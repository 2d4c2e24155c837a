"""Latent models of the pendulum on a fixed image latent: each frame's centroid.

The latent of an observation (C, S, S) is, per channel (frame), the centroid (x, y) of the
pixels' absolute difference from that frame's median (the background where the object
covers under half the pixels), in the image coordinates of
:func:`~latent_sindy.models.encoders.image_coordinates` (x right, y down). Nothing is
learned and only the image is read. On the pendulum's two stacked frames the four latents
are the rod's midpoint a step ago and now: the angle is their direction, the rate their
turn (linear probes of (cos θ, sin θ) reach R² 1.000, a quadratic probe of θ̇ 0.999; see
docs/pendulum_swing_up.md).

On these latents the dynamics are fitted by regression on the encoded transitions:

* :class:`CentroidSindy`: sparse regression on monomials of (z, u) up to ``order`` (the
  rotation of the rod's midpoint needs the cubic terms; order 2 diverged within 8 steps).
  On these latents the library's terms are dependent (each frame's centroid stays on a
  circle about the pivot), so the default sparsifier is backward elimination by the fit a
  term costs, most complex terms first (:class:`~latent_sindy.sindy.StepwiseSR`); STLSQ,
  which judges terms by their coefficients, keeps about half of the library there;
* ``CentroidSindy(order=1, min_share=0, sparsifier="stlsq")``: least squares on (1, z, u),
  the linear model z' = A z + B u + c;
* :class:`CentroidMlp`: z' = z + MLP([z, u]), trained by Adam on one-step errors.

A latent learned from the frames instead (:class:`GeodesicLatent`, each frame's angle as
(cos φ, sin φ)) lies on unit circles by construction; its ``circles`` name those pairs, and
every model on it scales them back onto the unit circle after each step (and the SINDy's
setting is chosen on rollouts that do the same), so its equations need only say how far the
angle turns, not hold the pair's length.

    >>> z = frame_centroids(images)              # (..., 2, S, S) uint8 -> (..., 4)
    >>> model = CentroidSindy().fit(data)        # data: PendulumWorld(...).collect(...)
    >>> model.step(z, u)                          # (K, 4), (K, 1) -> (K, 4)
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from torch import nn

import latent_sindy.worlds.pendulum.physics as physics
from latent_sindy.data import SequenceData
from latent_sindy.errors import UserError
from latent_sindy.models.dynamics.base import project_circle
from latent_sindy.models.encoders import image_coordinates
from latent_sindy.models.geodesic_reader import GeodesicReader
from latent_sindy.sindy import Polynomial, SindyLibrary, StepwiseSR, select_on_rollouts
from latent_sindy.sindy.fit import fit_state_data
from latent_sindy.sindy.optimizers import STLSQ
from latent_sindy.sindy.selection import TOLERANCES
from latent_sindy.worlds.pendulum.state_sindy import sindy_step

__all__ = ["SPARSIFIERS", "CentroidMlp", "CentroidSindy", "Encode", "GeodesicLatent",
           "frame_centroids", "geodesic_latent", "on_circles", "transitions"]

SPARSIFIERS = ("stepwise", "stlsq")
"""The sparse regressions of :class:`CentroidSindy`: :class:`~latent_sindy.sindy.StepwiseSR`
(``min_share``: its tolerance) or :class:`~latent_sindy.sindy.optimizers.STLSQ`."""

STLSQ_SHARES = (0.003, 0.01, 0.02, 0.03, 0.05, 0.1, 0.2, 0.3)
"""STLSQ shares tried when the share is chosen on rollouts."""


@torch.no_grad()
def frame_centroids(images: np.ndarray | torch.Tensor) -> torch.Tensor:
    """Images (..., C, H, W) -> (..., 2C) float32: per channel, the centroid (x, y) of the
    absolute difference from that channel's median pixel (a blank channel reads (0, 0))."""
    x = torch.as_tensor(np.asarray(images), dtype=torch.float32)
    *lead, c, h, w = x.shape
    flat = x.reshape(-1, c, h * w)
    d = (flat - flat.median(-1, keepdim=True).values).abs().reshape(-1, c, h, w)
    mass = d.sum((2, 3)).clamp_min(torch.finfo(torch.float32).tiny)  # (B, C)
    xs, ys = image_coordinates(h, w)
    cx = (d.sum(2) * xs).sum(-1) / mass  # columns: x
    cy = (d.sum(3) * ys).sum(-1) / mass  # rows: y
    return torch.stack([cx, cy], -1).reshape(*lead, 2 * c)


Encode = Callable[[Any], torch.Tensor]
"""A fixed latent of images (..., C, H, W) -> (..., nz): :func:`frame_centroids` by default,
or a latent learned from the frames beforehand (:func:`geodesic_latent`). One with a
``circles`` attribute (pairs of latent coordinates on the unit circle, as
:class:`GeodesicLatent`'s) has its models keep those pairs there (:func:`on_circles`)."""


class GeodesicLatent:
    """Images (..., C, H, W) -> (..., 2C) float32: per channel (frame), the angle
    (cos φ, sin φ) of its geodesic coordinates about their centre, read by a fitted
    :class:`~latent_sindy.models.geodesic_reader.GeodesicReader` whose coordinates wind
    round. ``circles``: the latent's pairs (2i, 2i + 1), one a frame, each on the unit
    circle."""

    def __init__(self, reader: GeodesicReader, channels: int) -> None:
        self.reader = reader
        self.circles = tuple((2 * i, 2 * i + 1) for i in range(channels))

    @torch.no_grad()
    def __call__(self, images: Any) -> torch.Tensor:
        y = torch.as_tensor(np.asarray(images))
        *lead, ch, h, w = y.shape
        flat = y.reshape(-1, ch, h, w)
        z = torch.cat([self.reader.position(flat[:, i:i + 1]) for i in range(ch)], -1)
        return z.float().reshape(*lead, 2 * ch)


def geodesic_latent(images: np.ndarray, seed: int = 0) -> GeodesicLatent:
    """The latent learned from training images (N, T+1, C, H, W) alone, per channel (frame):
    the angle (cos φ, sin φ) of its geodesic coordinates about their centre
    (:class:`~latent_sindy.models.geodesic_reader.GeodesicReader`, no world knowledge), in
    the place of each frame's centroid. UserError where the coordinates do not wind round
    (no angle to read)."""
    x = torch.as_tensor(np.asarray(images))
    reader = GeodesicReader(frames=x.shape[2], dim=2, seed=seed).fit_episodes(x)
    if not reader.turns_:
        raise UserError("the frames' geodesic coordinates do not wind round their centre: "
                        "no angle to read; plan on the centroid latent instead")
    return GeodesicLatent(reader, x.shape[2])


def on_circles(z: torch.Tensor, circles: tuple[tuple[int, int], ...]) -> torch.Tensor:
    """z (..., nz) with each pair of ``circles`` scaled back onto the unit circle (out of
    place; no pairs: z itself)."""
    for pair in circles:
        z = project_circle(z, torch.tensor(pair, device=z.device))
    return z


def transitions(data: SequenceData, encode: Encode = frame_centroids
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The training split's encoded transitions (z, u, z_next), float64, leaving out steps
    where the rate hit its clip (a different law there)."""
    train = data.split("train")
    z = encode(train.images).double()  # (N, T+1, nz)
    nz = z.shape[-1]
    keep = torch.as_tensor(np.abs(train.states[:, 1:, 1]).reshape(-1) < physics.MAX_SPEED) \
        if train.states is not None else torch.ones(z[:, 1:].numel() // nz, dtype=torch.bool)
    u = torch.as_tensor(train.actions.reshape(-1, train.actions.shape[-1]), dtype=torch.float64)
    return z[:, :-1].reshape(-1, nz)[keep], u[keep], z[:, 1:].reshape(-1, nz)[keep]


class CentroidSindy:
    """Sparse regression of the centroid latents' steps on a polynomial library of (z, u).

    Args:
        order: highest degree of the monomials of (z, u).
        min_share: the sparsifier's setting: StepwiseSR's tolerance (the share of a step's
            mean square a dropped term may cost) or STLSQ's ``min_share``. None: chosen on the
            validation sequences' rollouts (:func:`~latent_sindy.sindy.select_on_rollouts`,
            the sparsest fit within three times the best rollout error; the training
            sequences stand in when the data has no validation split).
        sparsifier: one of :data:`SPARSIFIERS`.
        encode: the fixed latent (:data:`Encode`); its ``circles``, if any, are kept on the
            unit circle after every step, in the rollouts the setting is chosen on too.

    Attributes (after :meth:`fit`): ``coef_``, ``mask_``, ``setting_`` (the setting used)
    and ``selection_`` (the path it was chosen from, or None when it was given).
    """

    def __init__(self, order: int = 4, min_share: float | None = None,
                 sparsifier: str = "stepwise", encode: Encode = frame_centroids) -> None:
        if sparsifier not in SPARSIFIERS:
            raise UserError(f"centroid SINDy sparsifier {sparsifier!r}: choose from "
                            f"{', '.join(SPARSIFIERS)}")
        self.order = order
        self.min_share = min_share
        self.sparsifier = sparsifier
        self.encode = encode
        self.circles: tuple[tuple[int, int], ...] = tuple(getattr(encode, "circles", ()))
        self.library: SindyLibrary | None = None

    def fit(self, data: SequenceData) -> CentroidSindy:
        z, u, z_next = transitions(data, self.encode)
        self.library = SindyLibrary(Polynomial("z,u", self.order), n_state=z.shape[1],
                                    n_control=u.shape[1])

        def make(setting: float):
            return (StepwiseSR(setting, complexity=self.library.degrees)
                    if self.sparsifier == "stepwise" else STLSQ(min_share=setting))

        self.selection_ = None
        if self.min_share is None:
            held = data.split("val") if data.split_counts()["val"] else data.split("train")
            self.selection_ = select_on_rollouts(
                self.library, z, u, z_next, self.encode(held.images).double(),
                torch.as_tensor(held.actions, dtype=torch.float64),
                TOLERANCES if self.sparsifier == "stepwise" else STLSQ_SHARES, make,
                project=lambda x: on_circles(x, self.circles))
            fit = self.selection_.model
            self.setting_ = self.selection_.setting
        else:
            fit = fit_state_data(self.library, z, u, z_next, make(self.min_share))
            self.setting_ = self.min_share
        self.mask_ = np.asarray(fit.mask_, bool)
        self.coef_ = torch.as_tensor(fit.coef_, dtype=torch.float64) * torch.as_tensor(
            self.mask_)  # (p, nz), pruned entries 0
        return self

    def sparsity(self) -> float:
        """Fraction of the library's coefficients pruned."""
        return float(1 - self.mask_.mean())

    def equations(self, precision: int = 3) -> list[str]:
        names = [n.replace("u0", "torque") for n in self.library.names]
        lines = []
        for i in range(self.coef_.shape[1]):
            terms = [f"{float(self.coef_[j, i]):+.{precision}g}"
                     + ("" if names[j] == "1" else f" {names[j]}")
                     for j in np.flatnonzero(self.mask_[:, i])]
            lines.append(f"z{i}[t+1] = z{i} " + (" ".join(terms) if terms else ""))
        return lines

    def step(self, z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """z (K, nz), u (K, 1) -> (K, nz) (torque clipped into the box; the latent's
        circles kept)."""
        return on_circles(sindy_step(self.library, self.coef_, z, u), self.circles)


class CentroidMlp:
    """z' = z + MLP([z, u]) on the centroid latents (two hidden layers of ``width``, tanh),
    trained by Adam on the one-step error of the latent scaled to unit spread. It steps as
    it was trained, without the projection onto the latent's ``circles`` that the sparse
    and linear models make: it learns the circle from the data, and the projection of
    steps it was never trained on lowered its swing-ups (docs/pendulum_swing_up.md)."""

    def __init__(self, width: int = 128, epochs: int = 1000, seed: int = 0,
                 encode: Encode = frame_centroids) -> None:
        self.width, self.epochs, self.seed = width, epochs, seed
        self.encode = encode

    def fit(self, data: SequenceData) -> CentroidMlp:
        z, u, z_next = (a.float() for a in transitions(data, self.encode))
        gen = torch.Generator().manual_seed(self.seed)
        torch.manual_seed(self.seed)
        nz, nu = z.shape[1], u.shape[1]
        self.net = nn.Sequential(nn.Linear(nz + nu, self.width), nn.Tanh(),
                                 nn.Linear(self.width, self.width), nn.Tanh(),
                                 nn.Linear(self.width, nz))
        self.scale = (z_next - z).std(0).clamp_min(1e-6)  # (nz,) the step's spread
        opt = torch.optim.Adam(self.net.parameters(), lr=3e-3)
        for _ in range(self.epochs):
            for idx in torch.randperm(len(z), generator=gen).split(256):
                pred = self.net(torch.cat([z[idx], u[idx] / physics.MAX_TORQUE], 1))
                loss = (pred - (z_next[idx] - z[idx]) / self.scale).square().mean()
                opt.zero_grad()
                loss.backward()
                opt.step()
        return self

    @torch.no_grad()
    def step(self, z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        uc = u.clamp(-physics.MAX_TORQUE, physics.MAX_TORQUE) / physics.MAX_TORQUE
        zf = z.float()
        z_next = zf + self.net(torch.cat([zf, uc.float()], 1)) * self.scale
        return z_next.to(z.dtype)
