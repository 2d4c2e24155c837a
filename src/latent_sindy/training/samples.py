"""What the trainer trains on: sequences for a discrete-time model, a frame and its time
derivatives for a continuous-time one.

Both sample types index alike (``pick``, over the first axis of their ``n`` samples, on
their ``device``) and hand the model's loss what it takes (``loss``), so that the training
loop never asks which it has:

    Sequences(x, u, s)                 x (N, T+1, ...) sequences or (W, H+1, ...) windows,
                                       u their actions (N, T, nu), s their true states or None
    DerivativeSamples(frames, actions) frames (N, 1+k, C, h, w): a frame and its k time
                                       derivatives; actions (N, nu): the action at each frame;
                                       with ``stencil`` h > 0, frames (N, 5, C, h, w) are five
                                       frames h apart around each instead, whose latents the
                                       model differentiates (derivatives="latent")
    CoordinateSamples(coords, actions, left)   the same on a model's principal-component
                                       front: coordinates (N, 1+k or 5, K) and the squared norm
                                       of what the front leaves out of each (N, 1+k or 5)

    batch = samples.pick(idx)
    terms = batch.loss(model, weights, window)
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from latent_sindy.models.latent_model import LatentModel, LossWeights
from latent_sindy.models.reward_head import Targets

__all__ = ["CoordinateSamples", "DerivativeSamples", "Samples", "Sequences"]


class Sequences(NamedTuple):
    """Sequences x (N, T+1, ...) or windows (W, H+1, ...), their actions u (N, T, nu), and
    their true state features s (privileged data of a pose head; :class:`Targets` with the
    rewards for a reward head) or None."""

    x: torch.Tensor
    u: torch.Tensor
    s: torch.Tensor | Targets | None = None

    @property
    def n(self) -> int:
        return len(self.x)

    @property
    def device(self) -> torch.device:
        return self.x.device

    def pick(self, idx: torch.Tensor | slice) -> Sequences:
        return Sequences(self.x[idx], self.u[idx], None if self.s is None else self.s[idx])

    def loss(self, model: LatentModel, weights: LossWeights, window: int | None
             ) -> dict[str, torch.Tensor]:
        """The model's loss terms on windows of ``window`` actions cut from the sequences."""
        return model.loss(self.x, self.u, weights, self.s, window=window)


class DerivativeSamples(NamedTuple):
    """A continuous-time model's samples: frames (N, 1+k, C, h, w), each a frame with its k
    time derivatives (x, ẋ[, ẍ]), normalised, and the action acting at each, actions (N, nu)."""

    frames: torch.Tensor
    actions: torch.Tensor
    stencil: float = 0.0
    """0: frames with their derivatives; h > 0: five frames h apart around each."""

    @property
    def n(self) -> int:
        return len(self.frames)

    @property
    def device(self) -> torch.device:
        return self.frames.device

    def pick(self, idx: torch.Tensor | slice) -> DerivativeSamples:
        return DerivativeSamples(self.frames[idx], self.actions[idx], self.stencil)

    def to(self, device: torch.device | str) -> DerivativeSamples:
        return DerivativeSamples(self.frames.to(device), self.actions.to(device), self.stencil)

    def loss(self, model: LatentModel, weights: LossWeights, window: int | None
             ) -> dict[str, torch.Tensor]:
        """The model's loss terms on the samples: single frames, so no window is cut (the
        trainer's ``window`` is a sequence's and does not apply), and no true states."""
        return model.loss(self.frames, self.actions, weights, stencil=self.stencil)


class CoordinateSamples(NamedTuple):
    """:class:`DerivativeSamples` on a continuous-time model's fixed principal-component
    front (:meth:`~latent_sindy.models.continuous_model.ContinuousLatentModel.coordinates`):
    coords (N, 1+k, K), actions (N, nu) and ``left`` (N, 1+k), the squared norm of what the
    front leaves out of each frame and derivative. The loss is the frames' up to rounding,
    without a pass over the pixels."""

    coords: torch.Tensor
    actions: torch.Tensor
    left: torch.Tensor
    stencil: float = 0.0

    @classmethod
    def of(cls, samples: DerivativeSamples, model: LatentModel) -> CoordinateSamples:
        """``samples`` on ``model``'s front (fitted: after its statistics)."""
        coords, left = model.coordinates(samples.frames, frames=bool(samples.stencil))
        return cls(coords, samples.actions, left, samples.stencil)

    @property
    def n(self) -> int:
        return len(self.coords)

    @property
    def device(self) -> torch.device:
        return self.coords.device

    def pick(self, idx: torch.Tensor | slice) -> CoordinateSamples:
        return CoordinateSamples(self.coords[idx], self.actions[idx], self.left[idx],
                                 self.stencil)

    def to(self, device: torch.device | str) -> CoordinateSamples:
        return CoordinateSamples(self.coords.to(device), self.actions.to(device),
                                 self.left.to(device), self.stencil)

    def loss(self, model: LatentModel, weights: LossWeights, window: int | None
             ) -> dict[str, torch.Tensor]:
        """The model's loss terms on the samples' coordinates (no window, no true states)."""
        return model.coordinate_loss(self.coords, self.actions, self.left, weights,
                                     stencil=self.stencil)


#: Any of the trainer's sample types.
Samples = Sequences | DerivativeSamples | CoordinateSamples
