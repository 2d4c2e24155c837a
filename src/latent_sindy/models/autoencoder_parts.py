"""The settings of each encoder and decoder kind: one small frozen dataclass per kind, its
``kind`` tag naming it, with what that part is built from beyond the image shape (C, H, W)
and the latent size nz.

The parts (:mod:`.encoders`, :mod:`.decoders`) are built from these, and
:class:`~latent_sindy.models.autoencoder.AutoencoderConfig` gives each part its own
(``encoder_part()``, ``decoder_part()``), so the parts never import the autoencoder's config.
Each kind's ``flat`` names the ``AutoencoderConfig`` setting each of its fields comes from
(where what it means is documented; the defaults are the same).

    >>> MomentEncoderConfig(order=4).kind
    'moments'
    >>> conv_shape((32, 32))  # the conv encoder's feature maps after both stages
    (5, 5)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

__all__ = ["DECODER_PARTS", "ENCODER_PARTS", "KERNEL", "ConvDecoderConfig", "ConvEncoderConfig",
           "DecoderPart", "EncoderPart", "FcDecoderConfig", "ImageShape",
           "KeypointEncoderConfig", "MaskMomentEncoderConfig", "MlpDecoderConfig",
           "MlpEncoderConfig", "MomentEncoderConfig", "SpriteDecoderConfig", "conv_shape"]

#: The side of every learned encoder's convolution kernels.
KERNEL = 5

#: (C, H, W) of the images a part is built for.
ImageShape = tuple[int, int, int]


def conv_shape(hw: tuple[int, int]) -> tuple[int, int]:
    """(H', W') of the conv encoder's feature maps after both 5×5 conv + 2×2 pool stages of
    an H × W image (5 × 5 for 32 × 32; below 1 where the image is too small)."""
    out = []
    for s in hw:
        for _ in range(2):
            s = (s - KERNEL + 1) // 2
        out.append(s)
    return out[0], out[1]


_MLP_FLAT = {"widths": "mlp_widths", "activation": "mlp_activation",
             "pca_components": "pca_components"}


# ---------------------------------------------------------------------------- encoders
@dataclass(frozen=True)
class ConvEncoderConfig:
    """The course's encoder: two 5×5 conv + pool stages, then fully connected."""

    kind: ClassVar[str] = "conv"
    flat: ClassVar[dict[str, str]] = {"channels": "conv_channels", "hidden": "encoder_hidden"}
    channels: tuple[int, int] = (4, 4)
    hidden: int = 100


@dataclass(frozen=True)
class KeypointEncoderConfig:
    """A spatial softmax over learned feature maps: nz / 2 keypoints."""

    kind: ClassVar[str] = "keypoints"
    flat: ClassVar[dict[str, str]] = {"channels": "keypoint_channels"}
    channels: int = 16


@dataclass(frozen=True)
class MomentEncoderConfig:
    """Nothing learned: the pose of what differs from the background; ``order`` n."""

    kind: ClassVar[str] = "moments"
    flat: ClassVar[dict[str, str]] = {"order": "moment_order"}
    order: int = 4


@dataclass(frozen=True)
class MaskMomentEncoderConfig:
    """The moments of a per-pixel weight that small convolutions learn."""

    kind: ClassVar[str] = "mask_moments"
    flat: ClassVar[dict[str, str]] = {"order": "moment_order", **{
        k: f"mask_{k}" for k in ("channels", "layers", "normalise", "weight", "window", "refine")}}
    order: int = 4
    channels: int = 16
    layers: int = 3
    normalise: bool = True
    weight: str = "background"
    window: float = 3.0
    refine: int = 3


@dataclass(frozen=True)
class MlpEncoderConfig:
    """Fully connected through ``widths``, behind ``pca_components`` principal components
    (0: none)."""

    kind: ClassVar[str] = "mlp"
    flat: ClassVar[dict[str, str]] = _MLP_FLAT
    widths: tuple[int, ...] = (128, 64, 32)
    activation: str = "sigmoid"
    pca_components: int = 0


# ---------------------------------------------------------------------------- decoders
@dataclass(frozen=True)
class FcDecoderConfig:
    """The course's decoder: fully connected through ``hidden``."""

    kind: ClassVar[str] = "fc"
    flat: ClassVar[dict[str, str]] = {"hidden": "decoder_hidden"}
    hidden: tuple[int, ...] = (500, 500)


@dataclass(frozen=True)
class ConvDecoderConfig:
    """Upsampling transposed convolutions of ``channels`` feature maps."""

    kind: ClassVar[str] = "conv"
    flat: ClassVar[dict[str, str]] = {"channels": "decoder_channels"}
    channels: int = 16


@dataclass(frozen=True)
class SpriteDecoderConfig:
    """A learned template of side ``size`` (odd) drawn at the moments latent's pose, whose
    angle is the encoder's order-``order`` moment's."""

    kind: ClassVar[str] = "sprite"
    flat: ClassVar[dict[str, str]] = {"size": "sprite_side", "supersample": "sprite_supersample",
                                      "order": "moment_order"}
    size: int = 11
    supersample: int = 2
    order: int = 4


@dataclass(frozen=True)
class MlpDecoderConfig:
    """The mlp encoder's mirror: the reversed ``widths``, then ``pca_components`` principal
    components back to the pixels (0: none)."""

    kind: ClassVar[str] = "mlp"
    flat: ClassVar[dict[str, str]] = _MLP_FLAT
    widths: tuple[int, ...] = (128, 64, 32)
    activation: str = "sigmoid"
    pca_components: int = 0


EncoderPart = (ConvEncoderConfig | KeypointEncoderConfig | MomentEncoderConfig
               | MaskMomentEncoderConfig | MlpEncoderConfig)
DecoderPart = FcDecoderConfig | ConvDecoderConfig | SpriteDecoderConfig | MlpDecoderConfig

#: Every encoder kind's settings, by kind.
ENCODER_PARTS: dict[str, type] = {c.kind: c for c in (
    ConvEncoderConfig, KeypointEncoderConfig, MomentEncoderConfig, MaskMomentEncoderConfig,
    MlpEncoderConfig)}

#: Every decoder kind's settings, by kind.
DECODER_PARTS: dict[str, type] = {c.kind: c for c in (
    FcDecoderConfig, ConvDecoderConfig, SpriteDecoderConfig, MlpDecoderConfig)}
