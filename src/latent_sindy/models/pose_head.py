"""A privileged pose head: a linear readout of the pose features from the latent.

Image autoencoders can keep an object's position in their latent but drop its orientation
(on the pushing world a linear probe read cos 4θ, sin 4θ with R² ≈ 0; issue 11). A pose head
is an auxiliary linear map P: z (nz) -> s (4), s = (x, y, cos(2πθ/P), sin(2πθ/P)) the
encoding of :func:`~latent_sindy.data.windows.pose_features`, trained with the data's true
poses during training only (the loss term ``pose`` of
:class:`~latent_sindy.models.latent_model.LatentModel`, weighted by ``--lambda-pose``). It
pulls the orientation into the latent (which the dynamics then carry) and gives MPPI a cost in
pose units (``--space pose``): the goal's pose is read from the goal image through the encoder
and the head, so control needs nothing privileged.

Two kinds (:data:`POSE_HEADS`, ``--pose-head linear|coordinates``):

* ``linear``: a learned linear map P: z -> s, beside whatever else the latent holds;
* ``coordinates``: the first four latent coordinates *are* the pose features, in their own
  units (P = [I 0], nothing learned). With ``--latent-dim 4`` the latent is the pose read from
  the image, so the dynamics can be written on it as on the true state (e.g. the face
  library, ``--library face``), and the decoder renders the object from it.

The head works on standardised features: its linear layer predicts (s - mean) / std with the
training split's statistics, held as buffers (saved with the model), so positions (spread
about 0.1 m) and angle features (about 0.7) weigh alike in the loss.

    latent-sindy train sindy --order 2 --library push --pose-head linear --lambda-pose 10 \\
        --data data/push.h5 --out runs/sindy2_pose
    latent-sindy control runs/sindy2_pose --task random --episodes 20 --space pose
"""

from __future__ import annotations

import torch
from torch import nn

from latent_sindy.models.state import STATE_DIM

__all__ = ["POSE_HEADS", "CoordinatePoseHead", "LinearPoseHead", "PoseHead"]


class PoseHead(nn.Module):
    """z (..., nz) -> pose features (..., 4) in their own units; see the module docstring.

    Subclasses define :meth:`standardized`; the training split's statistics are buffers."""

    kind: str

    def __init__(self, latent_dim: int) -> None:
        super().__init__()
        self.register_buffer("mean", torch.zeros(STATE_DIM))
        self.register_buffer("std", torch.ones(STATE_DIM))

    @torch.no_grad()
    def fit_statistics(self, poses: torch.Tensor) -> None:
        """Set the standardisation from the training split's pose features (..., 4)."""
        flat = poses.reshape(-1, STATE_DIM).to(self.mean)
        self.mean.copy_(flat.mean(0))
        self.std.copy_(flat.std(0).clamp_min(1e-6))

    def standardize(self, poses: torch.Tensor) -> torch.Tensor:
        """Pose features (..., 4) -> the standardised units the head is trained in."""
        return (poses - self.mean) / self.std

    def standardized(self, z: torch.Tensor) -> torch.Tensor:
        """z (..., nz) -> standardised pose features (..., 4) (what the loss compares)."""
        raise NotImplementedError

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        """z (..., nz) -> pose features (..., 4): (x, y, cos(2πθ/P), sin(2πθ/P))."""
        return self.standardized(z) * self.std + self.mean


class LinearPoseHead(PoseHead):
    """A learned linear readout of the pose features from the whole latent."""

    kind = "linear"

    def __init__(self, latent_dim: int) -> None:
        super().__init__(latent_dim)
        self.linear = nn.Linear(latent_dim, STATE_DIM)

    def standardized(self, z: torch.Tensor) -> torch.Tensor:
        return self.linear(z)


class CoordinatePoseHead(PoseHead):
    """The first four latent coordinates are the pose features themselves (no parameters)."""

    kind = "coordinates"

    def __init__(self, latent_dim: int) -> None:
        if latent_dim < STATE_DIM:
            raise ValueError(f"a coordinates pose head needs latent_dim >= {STATE_DIM}, "
                             f"got {latent_dim}")
        super().__init__(latent_dim)

    def standardized(self, z: torch.Tensor) -> torch.Tensor:
        return self.standardize(z[..., :STATE_DIM])

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return z[..., :STATE_DIM]


#: The pose head kinds of ``--pose-head``.
POSE_HEADS: dict[str, type[PoseHead]] = {c.kind: c for c in (LinearPoseHead,
                                                              CoordinatePoseHead)}
