"""A reward head: a small MLP r̂(z, u) that predicts the reward an action earns from the
latent state it is taken in, and the training targets that travel beside images and actions.

A model with a head (``ModelConfig(reward_head=WIDTH)``) learns it in its loss's ``reward``
term (weight ``LossWeights.lambda_reward``) on the data's rewards, predicted along the latent
rollout as PlaNet's multi-step prediction does: within a window from x_s the reward of step
s + k comes from (ẑ_{s+k}, u_{s+k}), ẑ_s = enc(x_s) and the later ẑ rolled out by the
dynamics. MPPI then plans against it (:class:`~latent_sindy.control.costs.RewardCost`).

    >>> head = RewardHead(nz=4, nu=1, width=32)
    >>> head(torch.zeros(10, 7, 4), torch.zeros(10, 7, 1)).shape   # (..., nz), (..., nu) -> (...)
    torch.Size([10, 7])
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

__all__ = ["RewardHead", "Targets", "reward_error"]


class RewardHead(nn.Module):
    """r̂(z, u) = MLP([z, u]): two hidden layers of ``width`` (ELU), one output."""

    def __init__(self, nz: int, nu: int, width: int) -> None:
        super().__init__()
        self.net = nn.Sequential(nn.Linear(nz + nu, width), nn.ELU(), nn.Linear(width, width),
                                 nn.ELU(), nn.Linear(width, 1))

    def forward(self, z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """z (..., nz), u (..., nu) -> r̂ (...)."""
        return self.net(torch.cat([z, u], -1)).squeeze(-1)


@dataclass(frozen=True)
class Targets:
    """Per-sequence training targets beside the images and actions, indexed together as the
    trainer cuts its batches: the true state features (N, T+1, nf) for a pose head and the
    rewards (N, T) for a reward head (each None where the model has no use for it)."""

    poses: torch.Tensor | None = None
    rewards: torch.Tensor | None = None

    def __getitem__(self, index: object) -> Targets:
        return Targets(*(None if t is None else t[index] for t in (self.poses, self.rewards)))

    def __len__(self) -> int:
        return len(self.rewards if self.poses is None else self.poses)

    def to(self, device: torch.device | str) -> Targets:
        return Targets(*(None if t is None else t.to(device) for t in (self.poses, self.rewards)))


def reward_error(head: RewardHead, z: torch.Tensor, z_hat: torch.Tensor, u_win: torch.Tensor,
                 rewards: torch.Tensor) -> torch.Tensor:
    """The mean squared error of the rewards predicted along every window's rollout.

    z (B, T+1, nz) the encoded frames; ẑ (B, W H, nz) the rolled-out latents of the W windows
    of H steps (ẑ_{s+1..s+H} of window s); u_win (B, W, H, nu) their actions; rewards (B, T).
    Step k of window s is predicted from (ẑ_{s+k}, u_{s+k}), ẑ_s = z_s."""
    b, w, h = u_win.shape[:3]
    rolled = z_hat.reshape(b, w, h, -1)[:, :, :-1]  # ẑ_{s+1..s+H-1}: (B, W, H-1, nz)
    states = torch.cat([z[:, :w, None], rolled], 2)  # (B, W, H, nz)
    target = rewards.unfold(1, h, 1)  # (B, W, H): target[:, s, k] = r[:, s + k]
    return (head(states, u_win) - target).square().mean()
