"""The neural reference latent model: z[t+1] = z + MLP([z, u]), and its config.

    >>> model = MlpConfig(hidden=64).build(nz=4, nu=2)
    >>> model.step(torch.zeros(8, 4), torch.zeros(8, 2)).shape  # (8, 4)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import torch
from torch import nn

from latent_sindy.errors import UserError
from latent_sindy.models.dynamics.base import LatentDynamics

__all__ = ["MlpConfig", "MlpDynamics"]


class MlpDynamics(LatentDynamics):
    """Neural latent model ``z_{t+1} = z_t + MLP([z_t, u_t])``.

    ``layers`` hidden layers of width ``hidden`` with SiLU; the output layer starts at a tenth
    of PyTorch's default scale so the untrained model is close to the identity. With
    ``harmonics`` = n > 0 the action ``u[angle]`` (an angle) also enters as cos(k u), sin(k u)
    for k = 1..n: a network of this size learns functions of an angle that turn n times per
    revolution (the pose features of an object with n-fold symmetry) only from such features.
    ``circle``: see :class:`LatentDynamics`.
    """

    kind = "mlp"

    def __init__(self, nz: int, nu: int, hidden: int = 128, layers: int = 2,
                 harmonics: int = 0, angle: int = 1, circle: Sequence[int] | None = None,
                 turn: bool = False) -> None:
        super().__init__(nz, nu, circle, turn)
        if layers < 1 or hidden < 1:
            raise ValueError(
                f"MlpDynamics needs layers >= 1 and hidden >= 1, got layers={layers}, "
                f"hidden={hidden}"
            )
        if harmonics < 0 or (harmonics and not 0 <= angle < nu):
            raise ValueError(f"MlpDynamics harmonics {harmonics} of action {angle}: need "
                             f"harmonics >= 0 and 0 <= angle < {nu}")
        self.register_buffer("_k", torch.arange(1, harmonics + 1, dtype=torch.float32),
                             persistent=False)
        self._angle = angle
        mods: list[nn.Module] = []
        width = nz + nu + 2 * harmonics
        for _ in range(layers):
            mods += [nn.Linear(width, hidden), nn.SiLU()]
            width = hidden
        out = nn.Linear(width, nz)
        with torch.no_grad():
            out.weight.mul_(0.1)
            out.bias.zero_()
        self.net = nn.Sequential(*mods, out)
        self._init = {"hidden": hidden, "layers": layers}
        if harmonics:
            self._init |= {"harmonics": harmonics, "angle": angle}

    def hparams(self) -> dict[str, Any]:
        return {**super().hparams(), **self._init}

    def _step(self, z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        parts = [z, u]
        if len(self._k):
            a = u[..., self._angle, None] * self._k.to(u.dtype)
            parts += [torch.cos(a), torch.sin(a)]
        return z + self.net(torch.cat(parts, dim=-1))  # (K, nz)

    def summary(self) -> list[str]:
        n = self._init.get("harmonics", 0)
        extra = f", u{self._init['angle']} as cos/sin of 1..{n} times it" if n else ""
        return [f"MLP latent dynamics z[t+1] = z + MLP([z, u]) ({self._init['layers']} hidden "
                f"layers of {self._init['hidden']}{extra}): a neural network has no readable "
                "equations", *self._circle_note()]


@dataclass(frozen=True)
class MlpConfig:
    """Neural reference: z[t+1] = z + MLP([z, u])."""

    kind: ClassVar[str] = "mlp"
    model_class: ClassVar[type[LatentDynamics]] = MlpDynamics
    hidden: int = 128
    """Width of the hidden layers."""
    layers: int = 2
    """Number of hidden layers."""
    harmonics: int = 0
    """Also feed the action u1, an angle, as cos(k u1), sin(k u1), k = 1..harmonics (0: u as
    it is): the number of times per revolution what the angle acts on looks alike (4 for a
    square object, as the pushing world's state reference rows use)."""

    def __post_init__(self) -> None:
        if self.hidden < 1 or self.layers < 1:
            raise UserError(f"MLP hidden {self.hidden} and layers {self.layers}: use 1 or more")
        if not 0 <= self.harmonics <= 64:
            raise UserError(f"--harmonics {self.harmonics}: use 0 to 64")

    def build(self, nz: int, nu: int, circle: Sequence[int] | None = None,
              turn: bool = False) -> MlpDynamics:
        if self.harmonics and nu < 2:
            raise UserError(f"--harmonics needs an angle as the action u1, but actions have "
                            f"{nu} components")
        return MlpDynamics(nz, nu, hidden=self.hidden, layers=self.layers,
                           harmonics=self.harmonics, angle=1, circle=circle, turn=turn)

