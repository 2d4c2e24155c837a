"""State costs for MPPI: plain batched callables ``cost(z (..., nz)) -> (...)``.

MPPI calls a cost once per command on all predicted states, z (H, K, nz) -> (H, K), so a
cost must accept any leading batch dimensions. A cost whose ``takes_actions`` is true is
called instead on the states the actions are taken in and the actions,
``cost(z_0..z_{H-1} (H, K, nz), u (H, K, nu)) -> (H, K)``: ``RewardCost``, minus a model's
predicted reward, so that MPPI maximises the reward summed over its horizon (no goal).

``LatentCost`` is the paper's quadratic cost in latent space, ``ImageCost`` its image-space
variant (decode each predicted latent and compare with the goal image), ``PoseCost`` a
quadratic cost on a readout of each predicted latent (a model's pose head: the block's pose
features) against the goal's.

    >>> cost = LatentCost(z_goal=torch.zeros(16), Q=1.0)
    >>> cost(torch.ones(5, 16))  # (5,): tensor([16., 16., 16., 16., 16.])
    >>> icost = ImageCost(autoencoder.decode, goal_image)  # goal_image (1, 32, 32)
    >>> pcost = PoseCost(model.pose_head, model.pose_head(z_goal), pose_cost_weights(P))
    >>> rcost = RewardCost(model.reward_head)   # rcost(z (H, K, nz), u (H, K, nu)) -> (H, K)
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from torch import Tensor

from latent_sindy.errors import UserError

__all__ = ["ImageCost", "LatentCost", "PoseCost", "RewardCost", "StateCost"]

#: ``cost(z (..., nz)) -> (...)``, batched over any leading dimensions
StateCost = Callable[[Tensor], Tensor]


class LatentCost:
    """Quadratic latent cost ``(z - z_goal)ᵀ Q (z - z_goal)``.

    Args:
        z_goal: (nz,) goal latent, e.g. the encoded goal image.
        Q: scalar (Q·I), the diagonal (nz,), or a full symmetric (nz, nz) matrix.
    """

    def __init__(self, z_goal: Tensor, Q: float | Sequence[float] | Tensor = 1.0) -> None:
        goal = torch.as_tensor(z_goal)
        if not goal.is_floating_point():
            goal = goal.float()
        self.z_goal = goal.reshape(-1)  # (nz,)
        nz = self.z_goal.numel()
        q = torch.as_tensor(Q, dtype=goal.dtype, device=goal.device)
        if not torch.isfinite(self.z_goal).all():
            raise UserError(f"LatentCost: z_goal has non-finite values: {self.z_goal.tolist()}")
        if q.shape not in ((), (nz,), (nz, nz)) or not torch.isfinite(q).all():
            raise UserError(
                f"LatentCost: Q must be a finite scalar, ({nz},) diagonal or ({nz}, {nz}) "
                f"matrix for a goal of size nz={nz}, got shape {tuple(q.shape)}"
            )
        if q.ndim < 2 and (q < 0).any():
            raise UserError(f"LatentCost: Q weights must be >= 0, got {q.tolist()}")
        self.Q = q
        # Resolved once: a full matrix needs d Q dᵀ, a diagonal only (d ⊙ d) q.
        self._weight = q.expand(nz).clone() if q.ndim < 2 else q  # (nz,) or (nz, nz)
        self._full = q.ndim == 2

    def __call__(self, z: Tensor) -> Tensor:
        d = z - self.z_goal  # (..., nz)
        if self._full:
            return ((d @ self._weight) * d).sum(-1)  # (...)
        if d.stride(-1) != 1:  # feature-major states (a fused rollout): no matmul copy
            return d.square_().mul_(self._weight).sum(-1)  # (...)
        return (d * d) @ self._weight  # (...)


class ImageCost:
    """Image-space cost ``weight · ‖decoder(z) - goal_image‖²`` per sample.

    Args:
        decoder: ``decoder(z (N, nz)) -> (N, ...)`` images (any shape with goal_image's size);
            states with more leading dimensions are flattened to N for it.
        goal_image: the goal picture, in the decoder's output space (normalised like it).
        weight: scale of the squared error (summed over pixels).
    """

    def __init__(self, decoder: Callable[[Tensor], Tensor], goal_image: Tensor,
                 weight: float = 1.0) -> None:
        goal = torch.as_tensor(goal_image)
        if not goal.is_floating_point():
            goal = goal.float()
        if not torch.isfinite(goal).all():
            raise UserError("ImageCost: goal_image has non-finite values")
        if not weight > 0:
            raise UserError(f"ImageCost: weight={weight!r} must be positive")
        self.decoder = decoder
        self.goal = goal.reshape(1, -1)  # (1, D)
        self.weight = float(weight)

    def __call__(self, z: Tensor) -> Tensor:
        x = self.decoder(z.reshape(-1, z.shape[-1]))  # (N, ...)
        if x[0].numel() != self.goal.shape[1]:
            raise UserError(
                f"ImageCost: decoder output {tuple(x.shape[1:])} does not match the goal image "
                f"size {self.goal.shape[1]}"
            )
        d = x.reshape(x.shape[0], -1) - self.goal  # (N, D)
        return (self.weight * (d * d).sum(-1)).reshape(z.shape[:-1])  # (...)


class PoseCost:
    """Quadratic cost on a readout of the state: ``(r(z) - s_goal)ᵀ Q (r(z) - s_goal)``.

    Args:
        readout: ``readout(z (..., nz)) -> (..., ns)``, e.g. a model's pose head.
        s_goal: (ns,) the goal's readout, e.g. ``readout(encoded goal image)``.
        Q: as :class:`LatentCost`'s, on the readout's ns coordinates.
    """

    def __init__(self, readout: Callable[[Tensor], Tensor], s_goal: Tensor,
                 Q: float | Sequence[float] | Tensor = 1.0) -> None:
        self.readout = readout
        self._cost = LatentCost(s_goal, Q)

    def __call__(self, z: Tensor) -> Tensor:
        return self._cost(self.readout(z))  # (...)


class RewardCost:
    """Minus a predicted reward, ``cost(z, u) = −r̂(z, u)``: MPPI with it maximises the
    reward summed over the horizon, Σ_{t=0..H-1} r̂(z_t, u_t) (z_0 the encoded image).

    With ``support`` (low, high), each (nz,), and ``weight`` w, the cost adds
    ``w · Σ_i (relu(z_i − high_i) + relu(low_i − z_i))``: how far a predicted latent lies
    outside the box where the model saw data (a model's predictions, and its reward head's,
    mean little beyond it; where a camera's reader loses sight of the object, plans that
    leave its view are plans from guesses).

    Args:
        reward: ``reward(z (..., nz), u (..., nu)) -> (...)``, e.g. a model's reward head.
        support: the (low, high) corners of the box, or None (no penalty).
        weight: reward per step given up for each unit a latent lies outside the box.
    """

    takes_actions = True

    def __init__(self, reward: Callable[[Tensor, Tensor], Tensor],
                 support: tuple[Tensor, Tensor] | None = None, weight: float = 0.0) -> None:
        if not callable(reward):
            raise UserError(f"RewardCost takes a callable reward(z, u), got {type(reward)}")
        if not (isinstance(weight, int | float) and weight >= 0 and weight < float("inf")):
            raise UserError(f"RewardCost weight={weight!r}: use a number >= 0")
        self.reward = reward
        self.weight = float(weight)
        self.low = self.high = None
        if support is not None:
            low, high = (torch.as_tensor(v, dtype=torch.float32) for v in support)
            if low.ndim != 1 or low.shape != high.shape or not bool((low <= high).all()):
                raise UserError("RewardCost support: give (low, high), two (nz,) tensors "
                                "with low <= high")
            self.low, self.high = low, high

    def __call__(self, z: Tensor, u: Tensor) -> Tensor:
        cost = -self.reward(z, u)  # (...)
        if self.low is not None and self.weight > 0:
            low, high = self.low.to(z), self.high.to(z)
            cost = cost + self.weight * (torch.relu(z - high) + torch.relu(low - z)).sum(-1)
        return cost
