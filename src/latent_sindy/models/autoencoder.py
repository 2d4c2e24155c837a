"""The image autoencoder: its config and the module joining an encoder and a decoder.

The kinds live in :mod:`.encoders` ("conv", the course's; "keypoints"; "moments";
"mask_moments"; "mlp") and :mod:`.decoders` ("fc", the course's; "conv"; "sprite"; "mlp");
:data:`ENCODERS` and :data:`DECODERS` name them, and each is built from its own settings,
the config's ``encoder`` and ``decoder`` (:mod:`.autoencoder_parts`, tagged by ``kind``; the
flat settings, ``encoder_kind="moments"``, ``moment_order=2``, still read and build them:
:mod:`.autoencoder_flags`). Both work on normalised images (see
:class:`latent_sindy.data.windows.Normalizer`) of any shape (C, H, W), so the decoder's output
is unbounded. Dimensions: B batch, C channels, H × W image, nz latent size.

    >>> ae = Autoencoder(AutoencoderConfig(channels=3, image_size=(20, 28), latent_dim=16))
    >>> AutoencoderConfig().resolve(channels=1, image_size=32)  # the shape taken from data
    >>> AutoencoderConfig(encoder_kind="moments", latent_dim=4, moment_order=2).encoder
    MomentEncoderConfig(order=2)
    >>> z = ae.encode(torch.zeros(8, 3, 20, 28))  # (8, 16)
    >>> ae.decode(z).shape
    torch.Size([8, 3, 20, 28])
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import torch
from torch import nn

from latent_sindy.errors import UserError
from latent_sindy.models.autoencoder_flags import ImageSize, flat_settings
from latent_sindy.models.autoencoder_parts import (
    ConvEncoderConfig,
    DecoderPart,
    EncoderPart,
    FcDecoderConfig,
    SpriteDecoderConfig,
    conv_shape,
    sprite_side,
)
from latent_sindy.models.costs import cost_weights
from latent_sindy.models.decoders import Decoder, MlpDecoder, SpriteDecoder
from latent_sindy.models.encoders import (
    Encoder,
    KeypointEncoder,
    MaskMomentEncoder,
    MlpEncoder,
    MomentEncoder,
)

__all__ = ["DECODERS", "ENCODERS", "Autoencoder", "AutoencoderConfig", "ImageSize"]


def image_hw(size: ImageSize) -> tuple[int, int]:
    """(H, W) of an image size (S: square)."""
    return (size, size) if isinstance(size, int) else (int(size[0]), int(size[1]))


def _size_text(hw: tuple[int, int]) -> str:
    """S for a square, HxW otherwise (as errors name sizes)."""
    return str(hw[0]) if hw[0] == hw[1] else f"{hw[0]}x{hw[1]}"


@flat_settings
@dataclass(frozen=True)
class AutoencoderConfig:
    """Sizes of the encoder and decoder; equal resolved configs build identical architectures.

    ``channels`` and ``image_size`` left as None are taken from the training data
    (:meth:`resolve`); an autoencoder is built only from a resolved config. A square image
    size is the side S, any other (H, W) (a square (S, S) is stored as S).
    """

    kind: ClassVar[str] = "image"
    channels: int | None = None
    """Image channels C (1 grayscale, 3 RGB); None: from the data file."""
    image_size: ImageSize | None = None
    """Image size in pixels: S, or (H, W); None: from the data file."""
    latent_dim: int = 16
    """Latent size nz (the paper: 16)."""
    encoder: EncoderPart = field(default_factory=ConvEncoderConfig)
    """The encoder's kind and its own settings (:mod:`.autoencoder_parts`)."""
    decoder: DecoderPart = field(default_factory=FcDecoderConfig)
    """The decoder's kind and its own settings."""
    pca_components: int = 0
    """mlp encoder and decoder: the principal components both work on (0: none;
    :class:`~.autoencoder_flags.AutoencoderFlags`)."""

    def __post_init__(self) -> None:
        if isinstance(self.image_size, tuple | list):
            h, w = image_hw(self.image_size)
            # one form per shape: a square is its side, so equal shapes are equal configs
            object.__setattr__(self, "image_size", h if h == w else (h, w))
        if self.latent_dim < 1 or (self.channels is not None and self.channels < 1):
            raise UserError(f"latent_dim {self.latent_dim} and channels {self.channels}: use 1 "
                            "or more")
        enc, dec = self.encoder_kind, self.decoder_kind
        if self.image_size is not None and enc != "mlp" and min(self.conv_shape()) < 1:
            raise UserError(
                f"image size {self._size_text()} is too small for two 5x5 conv + 2x2 pool "
                "stages: use at least 16 pixels a side"
            )
        if self.pca_components < 0 or (self.pca_components and not (
                enc == "mlp" and dec == "mlp")):
            raise UserError(f"pca_components {self.pca_components}: use 0 (none) or more, with "
                            f"the mlp encoder and decoder (got {enc!r}, {dec!r})")
        if self.pca_components and self.resolved and self.pca_components > (
                self.channels * self.height * self.width):
            raise UserError(f"pca_components {self.pca_components} is more than the "
                            f"{self.channels * self.height * self.width} values of a frame: use "
                            "at most that many")
        if enc == "moments" and (self.latent_dim != 4 or self.moment_order < 1):
            raise UserError(f"the moments encoder's latent is (x, y, cos nφ, sin nφ): use "
                            f"--latent-dim 4 (got {self.latent_dim}) and --moment-order >= 1 "
                            f"(got {self.moment_order})")
        if enc == "mask_moments" and (self.latent_dim != 4 or self.moment_order < 0):
            raise UserError(f"the mask_moments encoder's latent is (x, y, cos nφ, sin nφ): use "
                            f"--latent-dim 4 (got {self.latent_dim}) and --moment-order >= 1, "
                            f"or 0 to choose it from the data (got {self.moment_order})")
        if enc == "keypoints" and (self.latent_dim % 2 or self.keypoint_channels < 1):
            raise UserError(f"the keypoints encoder gives two coordinates per keypoint: use an "
                            f"even latent_dim (got {self.latent_dim}) and keypoint_channels "
                            f">= 1 (got {self.keypoint_channels})")
        if dec == "sprite" and not self.pose_latent:
            raise UserError(f"the sprite decoder draws the object at the moments encoder's "
                            f"pose: use it with --encoder moments or mask_moments (got "
                            f"{enc!r}), or --decoder conv")
        if self.sprite_size is not None and self.image_size is not None and (
                self.sprite_size > min(self.hw)):
            raise UserError(f"sprite_size {self.sprite_size}: use an odd number of pixels "
                            f"(the template's centre is a pixel), at most the image's shorter "
                            f"side")
        if dec == "conv" and self.image_size is not None and (self.hw[0] % 4 or self.hw[1] % 4):
            raise UserError(
                f"the conv decoder needs image sides divisible by 4 (got {self._size_text()}): "
                "use --decoder fc or another image size"
            )

    # ------------------------------------------------------------------ the image's shape
    @property
    def resolved(self) -> bool:
        return (self.channels is not None and self.image_size is not None
                and not self.order_from_data)

    @property
    def order_from_data(self) -> bool:
        """Whether the angular moment's order is still to be chosen from the data
        (``moment_order`` 0: training chooses it)."""
        return self.encoder_kind == "mask_moments" and self.moment_order == 0

    @property
    def hw(self) -> tuple[int, int]:
        """(H, W) of a config that has its image size."""
        if self.image_size is None:
            raise ValueError("the image size comes from the data: resolve() first")
        return image_hw(self.image_size)

    @property
    def height(self) -> int:
        return self.hw[0]

    @property
    def width(self) -> int:
        return self.hw[1]

    @property
    def image_shape(self) -> tuple[int, int, int]:
        """(C, H, W) of a resolved config."""
        if self.channels is None:
            raise ValueError("the channels come from the data: resolve() first")
        return (self.channels, *self.hw)

    def _size_text(self) -> str:
        return _size_text(self.hw)

    def conv_shape(self) -> tuple[int, int]:
        """(H', W') of the feature maps after both conv + pool stages (5 x 5 for 32 x 32)."""
        return conv_shape(self.hw)

    @property
    def sprite_side(self) -> int:
        """The sprite decoder's template side P: ``sprite_size``, or the one for the image's
        shorter side (a resolved config states it)."""
        return self.sprite_size if self.sprite_size is not None else sprite_side(self.hw)

    # ------------------------------------------------------------------ what the latent is
    @property
    def pose_latent(self) -> bool:
        """Whether the latent is a pose (x, y, cos nφ, sin nφ), as a library written on a pose
        latent needs."""
        return self.encoder_kind in ("moments", "mask_moments")

    @property
    def fixed_encoder(self) -> bool:
        """Whether the encoder learns nothing (the moments'), so its latents are data."""
        return self.encoder_kind == "moments"

    def resolve(self, channels: int, image_size: ImageSize, source: str = "the data"
                ) -> AutoencoderConfig:
        """This config with the data's image shape filled in (``image_size``: S, or (H, W));
        UserError if it contradicts it."""
        size = image_hw(image_size)
        mine = {"channels": self.channels,
                "image_size": None if self.image_size is None else self.hw}
        for name, value, text in (("channels", channels, str(channels)),
                                  ("image_size", size, _size_text(size))):
            if mine[name] is not None and mine[name] != value:
                have = self.channels if name == "channels" else self._size_text()
                raise UserError(
                    f"model {name} is {have} but {source} has {name} {text}: "
                    f"leave model {name} unset to use the data's"
                )
        resolved = dataclasses.replace(self, channels=channels, image_size=size)
        if not isinstance(self.decoder, SpriteDecoderConfig):
            return resolved
        return dataclasses.replace(resolved, decoder=dataclasses.replace(
            self.decoder, size=resolved.sprite_side))

    def encoder_part(self) -> EncoderPart:
        """The encoder's own settings (``encoder``)."""
        return self.encoder

    def decoder_part(self) -> DecoderPart:
        """The decoder's own settings (``decoder``; the sprite's size: a resolved config's)."""
        return self.decoder

    def shared(self, part: EncoderPart | DecoderPart) -> dict[str, Any]:
        """What a part is built with beyond its own settings: the mlp's principal
        components, the sprite's moment order (the encoder's)."""
        if part.kind == "mlp":
            return {"pca_components": self.pca_components}
        return {"order": self.moment_order} if part.kind == "sprite" else {}

    def build(self) -> Autoencoder:
        return Autoencoder(self)


class Autoencoder(nn.Module):
    """Encoder and decoder of one :class:`AutoencoderConfig`."""

    def __init__(self, cfg: AutoencoderConfig) -> None:
        super().__init__()
        if not cfg.resolved:
            raise ValueError("AutoencoderConfig needs channels and image_size: resolve() first")
        self.config = cfg
        self.image_shape = shape = cfg.image_shape  # (C, H, W)
        enc, dec = cfg.encoder, cfg.decoder
        self.encoder = ENCODERS[enc.kind](enc, shape, cfg.latent_dim, **cfg.shared(enc))
        self.decoder = DECODERS[dec.kind](dec, shape, cfg.latent_dim, **cfg.shared(dec))

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """x (..., C, H, W) -> z (..., nz); any leading dimensions."""
        if x.shape[-3:] != self.image_shape:
            c, h, w = self.image_shape
            raise UserError(f"the autoencoder takes images of shape (C, H, W) = ({c}, {h}, {w}), "
                            f"got {tuple(x.shape[-3:])}: build the model for the data's images "
                            f"(leave channels and image_size unset to take them from the data)")
        lead = x.shape[:-3]
        return self.encoder(x.reshape(-1, *x.shape[-3:])).view(*lead, -1)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """z (..., nz) -> x̂ (..., C, H, W); any leading dimensions."""
        return self.decoder(z)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.decode(self.encode(x))

    @torch.no_grad()
    def fit_statistics(self, frames: torch.Tensor) -> None:
        """Let an encoder or a decoder that needs them (the moments encoders' and the sprite
        decoder's background, the principal components of ``pca_components``) take their
        statistics from normalised training images (N, C, H, W); the learned ones need none."""
        for part in (self.encoder, self.decoder):
            if isinstance(part, MomentEncoder | MaskMomentEncoder | SpriteDecoder):
                part.fit_statistics(frames)
        if k := self.config.pca_components:
            from latent_sindy.models.pca_front import principal_components

            mean, basis, spread = principal_components(frames.flatten(1), k)
            # coordinates of unit spread (the pixels' variance, concentrated on k
            # directions, would reach the network k-to-pixels times wider)
            self.encoder.net[0].set(basis.T / spread, -(mean @ basis) / spread)
            self.decoder.net[-1].set(basis * spread, mean)

    def cost_weights(self, period: float) -> torch.Tensor:
        """Q (nz,) of MPPI's latent cost, :func:`~latent_sindy.models.costs.cost_weights`: on
        the moments latent one pixel of position error costs 1, and so does 10° of
        orientation (modulo its symmetry 2π / n; ``period`` unused); on any other latent every
        coordinate alike."""
        if isinstance(self.encoder, MomentEncoder | MaskMomentEncoder):
            return cost_weights(4, positions=(0, 1), position_scale=self.encoder.pixel,
                                circle=(2, 3), period=2 * math.pi / self.encoder.order,
                                angle_scale=math.radians(10.0))
        return torch.ones(self.config.latent_dim)


#: The encoder kinds of ``AutoencoderConfig.encoder_kind``.
ENCODERS: dict[str, type[nn.Module]] = {"conv": Encoder, "keypoints": KeypointEncoder,
                                        "moments": MomentEncoder,
                                        "mask_moments": MaskMomentEncoder, "mlp": MlpEncoder}

#: The decoder kinds of ``AutoencoderConfig.decoder_kind``.
DECODERS: dict[str, type[nn.Module]] = {"fc": Decoder, "conv": Decoder,
                                        "sprite": SpriteDecoder, "mlp": MlpDecoder}
