"""The image-to-image latent model: autoencoder + one latent dynamics model, and its loss.

``LatentModel`` joins an :class:`~latent_sindy.models.autoencoder.Autoencoder` and any latent
dynamics model of :func:`~latent_sindy.models.dynamics.make_dynamics` (SINDy, linear, MLP).
Its :meth:`LatentModel.loss` is the paper's loss (DESIGN §3, eq. 1–4) on one batch of windows
x_0..x_H, u_0..u_{H-1}, every term a mean squared error per element of normalised pixels
(or latent coordinates), so values do not depend on the image size, batch or horizon:

    recon  = mean_{b,t=0..H} ‖x_t − dec(enc(x_t))‖² / (C·S·S)
    pred_x = mean_{b,t=1..H} ‖x_t − dec(ẑ_t)‖² / (C·S·S)      ẑ rolled out from ẑ_0 = enc(x_0)
    pred_z = mean_{b,t=1..H} ‖enc(x_t) − ẑ_t‖² / nz
    l1     = ‖M ⊙ Ψ‖₁ (SINDy; 0 for the other models)
    total  = recon + λ1 pred_x + λ2 pred_z + λ3 l1
    objective = total − λ3 l1   (what train/val/test losses report, comparable across models)

Dimensions: B batch, H horizon, C channels, S image side, nz latent size, nu action size.

    >>> model = LatentModel(ModelConfig(kind="sindy", order=2, channels=1, image_size=32))
    >>> terms = model.loss(torch.zeros(8, 2, 1, 32, 32), torch.zeros(8, 1, 3))
    >>> sorted(terms)
    ['l1', 'objective', 'pred_x', 'pred_z', 'recon', 'total']
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import torch
import tyro
from torch import nn

from latent_sindy.errors import UserError, reject_unknown_fields
from latent_sindy.models.autoencoder import Autoencoder, AutoencoderConfig
from latent_sindy.models.dynamics import DYNAMICS_KINDS, LatentDynamics, make_dynamics
from latent_sindy.sindy.library import VALID_ORDERS

__all__ = ["LOSS_TERMS", "LatentModel", "LossWeights", "ModelConfig"]

#: The names of the loss terms :meth:`LatentModel.loss` returns, in report order.
LOSS_TERMS = ("total", "recon", "pred_x", "pred_z", "l1", "objective")

DynamicsKind = Literal["sindy", "linear", "mlp"]


@dataclass(frozen=True)
class ModelConfig:
    """Everything that defines a latent model's architecture; it rebuilds the model alone.

    ``channels`` and ``image_size`` left as None are taken from the training data (see
    :meth:`resolve`); a model can only be built from a resolved config.
    """

    kind: Annotated[DynamicsKind, tyro.conf.arg(aliases=("--model",))] = "sindy"
    """Latent dynamics: "sindy" (sparse library), "linear" (E2C-like baseline) or "mlp"."""
    order: int = 2
    """SINDy: polynomial order of the candidate library (1-4)."""
    include_sine: bool = True
    """SINDy: add sin(z_i) candidates."""
    latent_dim: int = 16
    """Latent size nz (the paper: 16)."""
    action_dim: int = 3
    """Action size nu (push: [p, phi, ell])."""
    channels: int | None = None
    """Image channels; None: from the data file."""
    image_size: int | None = None
    """Image side in pixels; None: from the data file."""
    conv_channels: tuple[int, int] = (4, 4)
    """Encoder: feature maps of the two 5x5 conv + max-pool stages."""
    encoder_hidden: int = 100
    """Encoder: width of the fully connected layer before the latent."""
    decoder: Literal["fc", "conv"] = "fc"
    """Decoder: "fc" fully connected (the course's), "conv" upsampling convolutions (better on
    held-out images; see latent_sindy.models.autoencoder)."""
    decoder_hidden: tuple[int, ...] = (500, 500)
    """fc decoder: widths of the fully connected hidden layers."""
    decoder_channels: int = 16
    """conv decoder: feature maps of its convolutions."""
    mlp_hidden: int = 128
    """MLP dynamics: hidden width."""
    mlp_layers: int = 2
    """MLP dynamics: number of hidden layers."""
    init_scale: float = 1e-3
    """SINDy / linear: standard deviation of the initial coefficients (Ψ; A − I and B)."""

    def __post_init__(self) -> None:
        if self.kind not in DYNAMICS_KINDS:
            raise UserError(
                f"model kind {self.kind!r} is unknown: use one of {', '.join(DYNAMICS_KINDS)}"
            )
        if self.kind == "sindy" and self.order not in VALID_ORDERS:
            raise UserError(f"SINDy order {self.order} is not supported: use 1, 2, 3 or 4")
        for name in ("latent_dim", "encoder_hidden", "mlp_hidden", "mlp_layers"):
            if getattr(self, name) < 1:
                raise UserError(f"model {name} {getattr(self, name)} must be at least 1")
        if self.action_dim < 0 or self.init_scale < 0:
            raise UserError(
                f"model action_dim {self.action_dim} and init_scale {self.init_scale} "
                "must not be negative"
            )

    @property
    def resolved(self) -> bool:
        return self.channels is not None and self.image_size is not None

    def resolve(self, channels: int, image_size: int, source: str = "the data") -> ModelConfig:
        """This config with the data's image shape filled in; UserError if it contradicts it."""
        for name, value in (("channels", channels), ("image_size", image_size)):
            mine = getattr(self, name)
            if mine is not None and mine != value:
                raise UserError(
                    f"model {name} is {mine} but {source} has {name} {value}: "
                    f"leave model {name} unset to use the data's"
                )
        return dataclasses.replace(self, channels=channels, image_size=image_size)

    def autoencoder_config(self) -> AutoencoderConfig:
        if not self.resolved:
            raise ValueError("ModelConfig needs channels and image_size: call resolve() first")
        try:
            return AutoencoderConfig(
                channels=self.channels,
                image_size=self.image_size,
                latent_dim=self.latent_dim,
                conv_channels=self.conv_channels,
                encoder_hidden=self.encoder_hidden,
                decoder=self.decoder,
                decoder_hidden=self.decoder_hidden,
                decoder_channels=self.decoder_channels,
            )
        except ValueError as e:
            raise UserError(f"model architecture: {e}") from e

    def dynamics_kwargs(self) -> dict[str, Any]:
        """Constructor arguments of the chosen dynamics model (besides nz, nu)."""
        if self.kind == "sindy":
            return {
                "order": self.order,
                "include_sine": self.include_sine,
                "init_scale": self.init_scale,
            }
        if self.kind == "linear":
            return {"init_scale": self.init_scale}
        return {"hidden": self.mlp_hidden, "layers": self.mlp_layers}

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> ModelConfig:
        """Inverse of :meth:`to_dict` (JSON lists back to tuples); unknown keys are an error."""
        reject_unknown_fields(cls, d, "model")
        d = dict(d)
        d.setdefault("decoder", "fc")  # runs saved before the conv decoder existed
        for key in ("conv_channels", "decoder_hidden"):
            if key in d:
                d[key] = tuple(d[key])
        return cls(**d)


@dataclass(frozen=True)
class LossWeights:
    """λ1, λ2, λ3 of the loss (see the module docstring)."""

    pred_x: float = 1.0
    pred_z: float = 1.0
    l1: float = 1e-3


_DEFAULT_WEIGHTS = LossWeights()


class LatentModel(nn.Module):
    """Autoencoder + latent dynamics; ``step(z, u)`` is the dynamics model's step.

    Args:
        config: a resolved :class:`ModelConfig`. The parameters are initialised from the
            global torch generator (seed it for reproducible runs).
    """

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        self.autoencoder = Autoencoder(config.autoencoder_config())
        self.dynamics: LatentDynamics = make_dynamics(
            config.kind, config.latent_dim, config.action_dim, **config.dynamics_kwargs()
        )
        self._has_l1 = hasattr(self.dynamics, "l1_penalty")

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """x (..., C, S, S) normalised images -> z (..., nz)."""
        return self.autoencoder.encode(x)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """z (..., nz) -> x̂ (..., C, S, S) normalised images."""
        return self.autoencoder.decode(z)

    def step(self, z: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """One latent step: z (K, nz), u (K, nu) -> (K, nz)."""
        return self.dynamics.step(z, u)

    def rollout_latent(self, z0: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """Open loop: z0 (B, nz), u (B, H, nu) -> ẑ (B, H+1, nz), ẑ_0 = z0."""
        return self.dynamics.rollout(z0, u)

    def predict(self, x0: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """Predicted images: x0 (B, C, S, S), u (B, H, nu) -> x̂ (B, H+1, C, S, S)."""
        return self.decode(self.rollout_latent(self.encode(x0), u))

    def l1_penalty(self) -> torch.Tensor:
        """‖M ⊙ Ψ‖₁ for SINDy, a zero scalar for the other models."""
        if self._has_l1:
            return self.dynamics.l1_penalty()
        return next(self.parameters()).new_zeros(())

    def loss(
        self, x: torch.Tensor, u: torch.Tensor, weights: LossWeights | None = None
    ) -> dict[str, torch.Tensor]:
        """The loss terms of :data:`LOSS_TERMS` on x (B, H+1, C, S, S), u (B, H, nu), H >= 1.

        ``weights`` None uses the defaults of :class:`LossWeights`.
        """
        weights = weights or _DEFAULT_WEIGHTS
        if x.ndim != 5 or u.ndim != 3 or u.shape[:2] != (x.shape[0], x.shape[1] - 1):
            raise ValueError(
                f"loss expects x (B, H+1, C, S, S) and u (B, H, nu), got {tuple(x.shape)} and "
                f"{tuple(u.shape)}"
            )
        h = u.shape[1]
        z = self.encode(x)  # (B, H+1, nz)
        z_hat = self.rollout_latent(z[:, 0], u)[:, 1:]  # (B, H, nz)
        # One decoder pass for the reconstructions and the predictions.
        x_dec = self.decode(torch.cat([z, z_hat], dim=1))  # (B, 2H+1, C, S, S)
        recon = (x_dec[:, : h + 1] - x).square().mean()
        pred_x = (x_dec[:, h + 1 :] - x[:, 1:]).square().mean()
        pred_z = (z_hat - z[:, 1:]).square().mean()
        l1 = self.l1_penalty()
        objective = recon + weights.pred_x * pred_x + weights.pred_z * pred_z
        return {
            "total": objective + weights.l1 * l1,
            "recon": recon,
            "pred_x": pred_x,
            "pred_z": pred_z,
            "l1": l1,
            "objective": objective,
        }
