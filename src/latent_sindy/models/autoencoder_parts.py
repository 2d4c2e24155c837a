"""The settings of each encoder and decoder kind: one small frozen dataclass per kind, its
``kind`` tag naming it, with what that part is built from beyond the image shape (C, H, W)
and the latent size nz.

The parts (:mod:`.encoders`, :mod:`.decoders`) are built from these;
:class:`~latent_sindy.models.autoencoder.AutoencoderConfig` holds one of each (``encoder``,
``decoder``) and passes in what the two share (the mlp's ``pca_components``, the sprite's
moment order), so the parts never import the autoencoder's config. Each kind checks its own
settings; what involves the image or the other part the autoencoder's config checks. Each
kind's ``flat`` names the setting of the flat form each of its fields is
(:class:`~latent_sindy.models.autoencoder_flags.AutoencoderFlags`, where what it means is
documented; the defaults are the same).

    >>> MomentEncoderConfig(order=4).kind
    'moments'
    >>> conv_shape((32, 32))  # the conv encoder's feature maps after both stages
    (5, 5)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from latent_sindy.errors import UserError

__all__ = ["ACTIVATION_NAMES", "DECODER_PARTS", "ENCODER_PARTS", "KERNEL", "ConvDecoderConfig",
           "ConvEncoderConfig", "DecoderPart", "EncoderPart", "FcDecoderConfig", "ImageShape",
           "KeypointEncoderConfig", "MaskMomentEncoderConfig", "MlpDecoderConfig",
           "MlpEncoderConfig", "MomentEncoderConfig", "SpriteDecoderConfig", "conv_shape",
           "sprite_side"]

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


def sprite_side(hw: tuple[int, int]) -> int:
    """The sprite's template side P for an H × W image: 2 ⌊5.5 S / 32⌋ + 1, S the shorter
    side (11 at 32 pixels, 23 at 64)."""
    return 2 * math.floor(5.5 * min(hw) / 32) + 1


#: The activations of the mlp encoder and decoder (:func:`latent_sindy.models.encoders.mlp`).
ACTIVATION_NAMES = ("sigmoid", "relu", "elu", "tanh")

_MLP_FLAT = {"widths": "mlp_widths", "activation": "mlp_activation"}


def _check_mlp(widths: tuple[int, ...], activation: str) -> None:
    if not widths or min(widths) < 1 or activation not in ACTIVATION_NAMES:
        raise UserError(f"--mlp-widths {widths} and --mlp-activation {activation!r}: use one "
                        f"or more positive widths and one of {', '.join(ACTIVATION_NAMES)}")


# ---------------------------------------------------------------------------- encoders
@dataclass(frozen=True)
class ConvEncoderConfig:
    """The course's encoder: two 5×5 conv + pool stages, then fully connected."""

    kind: ClassVar[str] = "conv"
    flat: ClassVar[dict[str, str]] = {"channels": "conv_channels", "hidden": "encoder_hidden"}
    channels: tuple[int, int] = (4, 4)
    hidden: int = 100

    def __post_init__(self) -> None:
        if len(self.channels) != 2 or min(self.channels) < 1:
            raise UserError(f"conv_channels must be two positive ints, got {self.channels}")
        if self.hidden < 1:
            raise UserError(f"hidden sizes must be positive, got encoder_hidden={self.hidden}")


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

    def __post_init__(self) -> None:
        if self.channels < 1 or self.layers < 1:
            raise UserError(f"--mask-channels {self.channels} and --mask-layers "
                            f"{self.layers}: use 1 or more of each")
        if self.weight not in ("background", "image", "mask"):
            raise UserError(f"--mask-weight {self.weight!r}: use background, image or mask")
        if self.refine < 0 or (self.refine and self.window <= 0):
            raise UserError(f"--mask-refine {self.refine} with --mask-window {self.window}: "
                            "use 0 or more steps, and a window > 0 with steps (or "
                            "--mask-refine 0)")
        if not (math.isfinite(self.window) and self.window >= 0):
            raise UserError(f"--mask-window {self.window}: use a window of 0 (none) or more "
                            "pixels")


@dataclass(frozen=True)
class MlpEncoderConfig:
    """Fully connected through ``widths`` (behind the autoencoder's ``pca_components``
    principal components, 0: none)."""

    kind: ClassVar[str] = "mlp"
    flat: ClassVar[dict[str, str]] = _MLP_FLAT
    widths: tuple[int, ...] = (128, 64, 32)
    activation: str = "sigmoid"

    def __post_init__(self) -> None:
        _check_mlp(self.widths, self.activation)


# ---------------------------------------------------------------------------- decoders
@dataclass(frozen=True)
class FcDecoderConfig:
    """The course's decoder: fully connected through ``hidden``."""

    kind: ClassVar[str] = "fc"
    flat: ClassVar[dict[str, str]] = {"hidden": "decoder_hidden"}
    hidden: tuple[int, ...] = (500, 500)

    def __post_init__(self) -> None:
        if not self.hidden or min(self.hidden) < 1:
            raise UserError(f"hidden sizes must be positive (and the decoder needs at least "
                            f"one layer), got decoder_hidden={self.hidden}")


@dataclass(frozen=True)
class ConvDecoderConfig:
    """Upsampling transposed convolutions of ``channels`` feature maps."""

    kind: ClassVar[str] = "conv"
    flat: ClassVar[dict[str, str]] = {"channels": "decoder_channels"}
    channels: int = 16

    def __post_init__(self) -> None:
        if self.channels < 1:
            raise UserError(f"decoder_channels {self.channels}: use 1 or more")


@dataclass(frozen=True)
class SpriteDecoderConfig:
    """A learned template of side ``size`` (odd; None: :func:`sprite_side` of the image)
    drawn at the moments latent's pose (whose angle is the encoder's moment's)."""

    kind: ClassVar[str] = "sprite"
    flat: ClassVar[dict[str, str]] = {"size": "sprite_size", "supersample": "sprite_supersample"}
    size: int | None = None
    supersample: int = 2

    def __post_init__(self) -> None:
        if self.size is not None and (self.size < 1 or self.size % 2 == 0):
            raise UserError(f"sprite_size {self.size}: use an odd number of pixels (the "
                            "template's centre is a pixel), at most the image's shorter side")
        if self.supersample < 1:
            raise UserError(f"sprite_supersample {self.supersample}: use 1 or more")


@dataclass(frozen=True)
class MlpDecoderConfig:
    """The mlp encoder's mirror: the reversed ``widths``, then the autoencoder's
    ``pca_components`` principal components back to the pixels (0: none)."""

    kind: ClassVar[str] = "mlp"
    flat: ClassVar[dict[str, str]] = _MLP_FLAT
    widths: tuple[int, ...] = (128, 64, 32)
    activation: str = "sigmoid"

    def __post_init__(self) -> None:
        _check_mlp(self.widths, self.activation)


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
