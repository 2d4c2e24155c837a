"""Training windows cut from trajectories, and the image normalisation they use.

A window of H pushes is (x_t..x_{t+H}, u_t..u_{t+H-1}) from one trajectory; every start
t = 0..T-H of every trajectory of a split gives one. Images are normalised with one scalar
mean and std computed on the training split only (as the course did), so validation and
test data never inform the normalisation.

    data = read_trajectories("data/push.h5")
    norm = Normalizer.from_trajectories(data)
    train = WindowDataset(data.split("train"), window=4, normalizer=norm)
    x, u = train[0]  # (5, C, 32, 32) float32, (4, 3) float32
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch.utils.data import Dataset

from latent_sindy.data.store import Trajectories
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
    def from_trajectories(cls, data: Trajectories) -> Normalizer:
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


class WindowDataset(Dataset):
    """All windows of H pushes of a set of trajectories, normalised, as torch tensors."""

    def __init__(self, data: Trajectories, window: int, normalizer: Normalizer) -> None:
        if not 1 <= window <= data.steps:
            raise UserError(f"window {window} is impossible for trajectories of {data.steps} "
                            f"steps: use 1..{data.steps}")
        self.window = window
        self.images = normalizer.normalize(data.images)  # (N, T+1, C, S, S)
        self.actions = torch.as_tensor(data.actions, dtype=torch.float32)  # (N, T, 3)
        starts = np.arange(data.steps - window + 1)
        traj = np.repeat(np.arange(data.n), len(starts))
        self._index = np.stack([traj, np.tile(starts, data.n)], axis=1)  # (W, 2)

    def __len__(self) -> int:
        return len(self._index)

    def __getitem__(self, k: int) -> tuple[torch.Tensor, torch.Tensor]:
        i, t = self._index[k]
        h = self.window
        return self.images[i, t:t + h + 1], self.actions[i, t:t + h]

    def tensors(self) -> tuple[torch.Tensor, torch.Tensor]:
        """All windows at once: x (W, H+1, C, S, S), u (W, H, 3) — for small data sets."""
        i = torch.as_tensor(self._index[:, 0])
        t = torch.as_tensor(self._index[:, 1])
        steps = torch.arange(self.window + 1)
        x = self.images[i[:, None], t[:, None] + steps]
        u = self.actions[i[:, None], t[:, None] + steps[:-1]]
        return x, u
