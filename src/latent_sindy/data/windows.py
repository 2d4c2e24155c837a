"""Training windows cut from trajectories, what a model observes, and the normalisation.

A model observes either the camera images (normalised) or the block's true pose encoded so
that poses the camera cannot tell apart are equal (a state-space reference model);
:data:`OBSERVATIONS` maps the model's encoder kind to the one class that prepares both whole
data sets (training) and single frames (control).

A window of H pushes is (x_t..x_{t+H}, u_t..u_{t+H-1}) from one trajectory; every start
t = 0..T-H of every trajectory of a split gives one. Images are normalised with one scalar
mean and std computed on the training split only (as the course did), so validation and
test data never inform the normalisation.

    data = read_sequences("data/push.h5")
    norm = Normalizer.from_trajectories(data)
    train = WindowDataset(data.split("train"), window=4, normalizer=norm)
    x, u = train[0]  # (5, C, 32, 32) float32, (4, 3) float32
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch.utils.data import Dataset

from latent_sindy.data import SequenceData
from latent_sindy.errors import UserError


@dataclass(frozen=True)
class Normalizer:
    """x_norm = (x - mean) / std with scalar statistics of the training pixels."""

    mean: float
    std: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.mean) and np.isfinite(self.std) and self.std > 0):
            raise UserError(f"invalid image statistics mean={self.mean}, std={self.std}: "
                            "the training images are constant or corrupt")

    @classmethod
    def from_trajectories(cls, data: SequenceData) -> Normalizer:
        return cls(*data.pixel_stats())

    def normalize(self, images: np.ndarray | torch.Tensor) -> torch.Tensor:
        """uint8 images (..., C, S, S) -> float32 tensor of the same shape."""
        x = torch.as_tensor(images).to(torch.float32)
        return (x - self.mean) / self.std

    def denormalize(self, x: torch.Tensor) -> torch.Tensor:
        """Back to pixel values (float, not clipped)."""
        return x * self.std + self.mean

    def to_dict(self) -> dict:
        return {"mean": self.mean, "std": self.std}

    @classmethod
    def from_dict(cls, d: dict) -> Normalizer:
        return cls(float(d["mean"]), float(d["std"]))


def state_features(states: np.ndarray, periods: Sequence[float | None]) -> torch.Tensor:
    """States (..., ns) -> features float32: each state as it is, each angle state of period
    P as (cos(2πθ/P), sin(2πθ/P)), so that states the camera cannot tell apart are equal."""
    p = torch.as_tensor(np.asarray(states), dtype=torch.float64)
    columns = []
    for i, period in enumerate(periods):
        if period is None:
            columns.append(p[..., i])
        else:
            a = p[..., i] * (2 * np.pi / period)
            columns += [torch.cos(a), torch.sin(a)]
    return torch.stack(columns, -1).float()


def pose_features(poses: np.ndarray, period: float) -> torch.Tensor:
    """(x, y, θ) (..., 3) -> (x, y, cos(2πθ/P), sin(2πθ/P)) (..., 4) float32."""
    return state_features(poses, (None, None, period))


def data_features(data: SequenceData) -> torch.Tensor | None:
    """The data's state features (N, T+1, nf), or None for data without states."""
    if data.states is None:
        return None
    return state_features(data.states, data.state_periods)


class ImageObservations:
    """The camera images, normalised by the training split's scalar pixel statistics."""

    kind = "image"

    @staticmethod
    def normalizer(data: SequenceData) -> Normalizer:
        return Normalizer.from_trajectories(data)

    @staticmethod
    def batch(data: SequenceData, normalizer: Normalizer) -> torch.Tensor:
        """(N, T+1, C, S, S)"""
        return normalizer.normalize(data.images)

    @staticmethod
    def one(image: np.ndarray, pose: np.ndarray, normalizer: Normalizer,
            period: float) -> torch.Tensor:
        """(C, S, S)"""
        return normalizer.normalize(image)


class StateObservations:
    """The block's true pose, as :func:`pose_features` (no normalisation)."""

    kind = "state"

    @staticmethod
    def normalizer(data: SequenceData) -> Normalizer:
        return Normalizer(0.0, 1.0)

    @staticmethod
    def batch(data: SequenceData, normalizer: Normalizer) -> torch.Tensor:
        """(N, T+1, 4)"""
        if data.states is None:
            raise UserError(f"{data.source} has no states: a state model needs them")
        return data_features(data)

    @staticmethod
    def one(image: np.ndarray, pose: np.ndarray, normalizer: Normalizer,
            period: float) -> torch.Tensor:
        """(4,)"""
        return pose_features(pose, period)


#: Encoder kind -> what the model observes.
OBSERVATIONS = {c.kind: c for c in (ImageObservations, StateObservations)}


class WindowDataset(Dataset):
    """All windows of H pushes of a set of trajectories, as observed by an encoder ``kind``
    (normalised images by default), as torch tensors; :meth:`pose_tensors` gives the true
    poses of the same windows (for a privileged pose head), :meth:`reward_tensors` their
    rewards (for a reward head)."""

    def __init__(self, data: SequenceData, window: int, normalizer: Normalizer,
                 kind: str = "image") -> None:
        if not 1 <= window <= data.steps:
            raise UserError(f"window {window} is impossible for trajectories of {data.steps} "
                            f"steps: use 1..{data.steps}")
        self.window = window
        self.images = OBSERVATIONS[kind].batch(data, normalizer)  # (N, T+1, *observation)
        self.actions = torch.as_tensor(data.actions, dtype=torch.float32)  # (N, T, 3)
        self.poses = data_features(data)  # (N, T+1, nf) state features, or None
        self.rewards = (None if data.rewards is None  # (N, T), or None
                        else torch.as_tensor(data.rewards, dtype=torch.float32))
        starts = np.arange(data.steps - window + 1)
        traj = np.repeat(np.arange(data.n), len(starts))
        self._index = np.stack([traj, np.tile(starts, data.n)], axis=1)  # (W, 2)

    def __len__(self) -> int:
        return len(self._index)

    def __getitem__(self, k: int) -> tuple[torch.Tensor, torch.Tensor]:
        i, t = self._index[k]
        h = self.window
        return self.images[i, t:t + h + 1], self.actions[i, t:t + h]

    def trajectories(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The whole trajectories the windows are cut from: x (N, T+1, *observation),
        u (N, T, nu) (``LatentModel.loss(x, u, window=H)`` computes the loss of all their
        windows)."""
        return self.images, self.actions

    def tensors(self) -> tuple[torch.Tensor, torch.Tensor]:
        """All windows at once: x (W, H+1, *observation), u (W, H, nu) — for small data sets."""
        i = torch.as_tensor(self._index[:, 0])
        t = torch.as_tensor(self._index[:, 1])
        steps = torch.arange(self.window + 1)
        x = self.images[i[:, None], t[:, None] + steps]
        u = self.actions[i[:, None], t[:, None] + steps[:-1]]
        return x, u

    def reward_tensors(self) -> torch.Tensor:
        """The rewards of every window, in :meth:`tensors`' order: (W, H)."""
        if self.rewards is None:
            raise UserError("this data has no rewards: a reward head needs them")
        i = torch.as_tensor(self._index[:, 0])
        t = torch.as_tensor(self._index[:, 1])
        return self.rewards[i[:, None], t[:, None] + torch.arange(self.window)]

    def pose_tensors(self) -> torch.Tensor:
        """The state features of every window, in :meth:`tensors`' order: (W, H+1, nf)."""
        if self.poses is None:
            raise UserError("this data has no states: a pose head needs them")
        i = torch.as_tensor(self._index[:, 0])
        t = torch.as_tensor(self._index[:, 1])
        return self.poses[i[:, None], t[:, None] + torch.arange(self.window + 1)]
