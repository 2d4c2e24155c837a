"""The image autoencoder: its config and the module joining an encoder and a decoder.

The kinds live in :mod:`.encoders` ("conv", the course's; "keypoints"; "moments";
"mask_moments"; "mlp") and :mod:`.decoders` ("fc", the course's; "conv"; "sprite"; "mlp");
:data:`ENCODERS` and :data:`DECODERS` name them, and each is built from its own settings
(:mod:`.autoencoder_parts`; ``encoder_part()`` and ``decoder_part()`` of the config). Both
work on normalised images (see :class:`latent_sindy.data.windows.Normalizer`) of any shape
(C, H, W), so the decoder's output is unbounded. Dimensions: B batch, C channels, H × W
image, nz latent size.

    >>> ae = Autoencoder(AutoencoderConfig(channels=3, image_size=(20, 28), latent_dim=16))
    >>> AutoencoderConfig().resolve(channels=1, image_size=32)  # the shape taken from data
    >>> z = ae.encode(torch.zeros(8, 3, 20, 28))  # (8, 16)
    >>> ae.decode(z).shape
    torch.Size([8, 3, 20, 28])
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Annotated, ClassVar, Literal

import torch
import tyro
from torch import nn

from latent_sindy.errors import UserError
from latent_sindy.models.autoencoder_parts import (
    DECODER_PARTS,
    ENCODER_PARTS,
    DecoderPart,
    EncoderPart,
    conv_shape,
)
from latent_sindy.models.costs import cost_weights
from latent_sindy.models.decoders import Decoder, MlpDecoder, SpriteDecoder
from latent_sindy.models.encoders import (
    ACTIVATIONS,
    Encoder,
    KeypointEncoder,
    MaskMomentEncoder,
    MlpEncoder,
    MomentEncoder,
)
from latent_sindy.models.renamed import renamed

__all__ = ["DECODERS", "ENCODERS", "Autoencoder", "AutoencoderConfig", "ImageSize"]

#: An image size: the side S of square images, or (H, W).
ImageSize = int | tuple[int, int]


def image_hw(size: ImageSize) -> tuple[int, int]:
    """(H, W) of an image size (S: square)."""
    return (size, size) if isinstance(size, int) else (int(size[0]), int(size[1]))


def _size_text(hw: tuple[int, int]) -> str:
    """S for a square, HxW otherwise (as errors name sizes)."""
    return str(hw[0]) if hw[0] == hw[1] else f"{hw[0]}x{hw[1]}"


@renamed(encoder="encoder_kind", decoder="decoder_kind")
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
    """Image size in pixels: the side S of square images, or height and width (H, W); None:
    from the data file."""
    latent_dim: int = 16
    """Latent size nz (the paper: 16)."""
    conv_channels: tuple[int, int] = (4, 4)
    """Feature maps of the two 5×5 convolution stages (the course used 4 and 4)."""
    encoder_hidden: int = 100
    """Width of the encoder's fully connected layer (the course: 100)."""
    decoder_kind: Annotated[Literal["fc", "conv", "sprite", "mlp"],
                            tyro.conf.arg(name="decoder")] = "fc"
    """Decoder kind: "fc" fully connected (the course's), "conv" upsampling convolutions,
    "sprite" (moments encoder only) a learned patch of the moving object drawn at the
    latent's pose on the encoder's background, "mlp" fully connected through the reversed
    --mlp-widths with --mlp-activation (the SINDy autoencoder's)."""
    decoder_hidden: tuple[int, ...] = (500, 500)
    """fc decoder: widths of the hidden layers (the course: 500, 500)."""
    decoder_channels: int = 16
    """conv decoder: feature maps of its convolutions."""
    encoder_kind: Annotated[Literal["conv", "keypoints", "moments", "mask_moments", "mlp"],
                            tyro.conf.arg(name="encoder")] = "conv"
    """Encoder kind: "conv" (the course's: conv + pool stages, then fully connected),
    "keypoints" (a spatial softmax: the latent is the expected image position of
    latent_dim / 2 learned feature maps, so it is a position by construction) or "moments"
    (nothing learned: the latent is the centroid and the orientation of what differs from the
    background, (x, y, cos nφ, sin nφ); latent_dim 4), "mask_moments" (the same latent, the
    moments of a per-pixel weight that small convolutions learn; latent_dim 4) or "mlp"
    (fully connected through --mlp-widths with --mlp-activation: the SINDy autoencoder's, any
    image size)."""
    keypoint_channels: int = 16
    """keypoints encoder: feature maps of its two hidden 5×5 convolutions."""
    sprite_size: int | None = None
    """sprite decoder: side P of its template in pixels (odd); None: from the image's shorter
    side S, 2 ⌊5.5 S / 32⌋ + 1 (11 at 32 pixels, 23 at 64)."""
    sprite_supersample: int = 2
    """sprite decoder: draw at this many times the image's resolution, then average-pool (1:
    draw at the image's resolution)."""
    moment_order: int = 4
    """moments and mask_moments encoders: n, the order of the angular moment that gives the
    orientation: the object's visible rotational symmetry (4 for a uniform square, which
    looks alike every quarter turn; 1 for an object with none). mask_moments: 0 chooses it
    from the data at training (a short fit at order 2, then the trained encoder's
    ``symmetry_order`` on the training images; the run's record states the order chosen)."""
    mask_channels: int = 16
    """mask_moments encoder: feature maps of its hidden 3×3 convolutions."""
    mask_layers: int = 3
    """mask_moments encoder: hidden 3×3 convolutions before the one that gives the weight."""
    mask_normalise: bool = True
    """mask_moments encoder: standardise each image on its own (its median subtracted, divided
    by its standard deviation) before the convolutions."""
    mask_weight: Literal["background", "image", "mask"] = "background"
    """mask_moments encoder: a pixel's weight is the learned mask (in (0, 1)) times its
    deviation from the "background" (the per-pixel median of the training images as the
    encoder sees them) or from its "image"'s median (the mask chooses which pixels count, the
    image keeps their shape), or the "mask" alone."""
    mask_window: float = 3.0
    """mask_moments encoder: σ in pixels of the Gaussian window about the centroid that the
    angular moment is taken in (0: none, the whole image's)."""
    mask_refine: int = 3
    """mask_moments encoder: mean-shift steps of the centre: from the masked weights' centroid
    it moves this many times to the centroid of the image's own deviation (``mask_weight``'s,
    without the mask) in the window about it, and the pose is read from that deviation about
    that centre, so the mask only says where the object is, not what shape it has. 0: the
    pose of the masked weights themselves (a trained mask can drift off the object's shape:
    RESULTS.md, "The learned row"). Needs a window."""
    mlp_widths: tuple[int, ...] = (128, 64, 32)
    """mlp encoder: widths of its hidden layers (the mlp decoder: the same, reversed); the
    SINDy autoencoder's pendulum: 128, 64, 32."""
    mlp_activation: Literal["sigmoid", "relu", "elu", "tanh"] = "sigmoid"
    """mlp encoder and decoder: the activation after every hidden layer (the SINDy
    autoencoder's pendulum: sigmoid)."""
    pca_components: int = 0
    """mlp encoder and decoder: the first this many principal components of the normalised
    training frames in front of the encoder's network and behind the decoder's, a fixed
    linear map (:mod:`~latent_sindy.models.front`; the frames' derivatives pass it exactly):
    the networks work on these coordinates, not on every pixel. 0: none."""

    def __post_init__(self) -> None:
        if isinstance(self.image_size, tuple | list):
            h, w = image_hw(self.image_size)
            # one form per shape: a square is its side, so equal shapes are equal configs
            object.__setattr__(self, "image_size", h if h == w else (h, w))
        if self.latent_dim < 1 or (self.channels is not None and self.channels < 1):
            raise UserError(f"latent_dim {self.latent_dim} and channels {self.channels}: use 1 "
                            "or more")
        if self.image_size is not None and self.encoder_kind != "mlp" and (
                min(self.conv_shape()) < 1):
            raise UserError(
                f"image size {self._size_text()} is too small for two 5x5 conv + 2x2 pool "
                "stages: use at least 16 pixels a side"
            )
        if len(self.conv_channels) != 2 or min(self.conv_channels) < 1:
            raise UserError(f"conv_channels must be two positive ints, got {self.conv_channels}")
        if self.encoder_hidden < 1 or not self.decoder_hidden or min(self.decoder_hidden) < 1:
            raise UserError(
                f"hidden sizes must be positive (and the decoder needs at least one layer), "
                f"got encoder_hidden={self.encoder_hidden}, decoder_hidden={self.decoder_hidden}"
            )
        if self.pca_components < 0 or (self.pca_components and not (
                self.encoder_kind == "mlp" and self.decoder_kind == "mlp")):
            raise UserError(f"pca_components {self.pca_components}: use 0 (none) or more, with "
                            f"the mlp encoder and decoder (got {self.encoder_kind!r}, "
                            f"{self.decoder_kind!r})")
        if self.pca_components and self.resolved and self.pca_components > (
                self.channels * self.height * self.width):
            raise UserError(f"pca_components {self.pca_components} is more than the "
                            f"{self.channels * self.height * self.width} values of a frame: use "
                            "at most that many")
        if self.decoder_kind not in DECODERS:
            raise UserError(f"decoder {self.decoder_kind!r} is unknown: use one of "
                            + ", ".join(DECODERS))
        if self.encoder_kind not in ENCODERS:
            raise UserError(f"encoder {self.encoder_kind!r} is unknown: use one of "
                            + ", ".join(ENCODERS))
        if self.encoder_kind == "moments" and (self.latent_dim != 4 or self.moment_order < 1):
            raise UserError(f"the moments encoder's latent is (x, y, cos nφ, sin nφ): use "
                            f"--latent-dim 4 (got {self.latent_dim}) and --moment-order >= 1 "
                            f"(got {self.moment_order})")
        if self.encoder_kind == "mask_moments" and (self.latent_dim != 4
                                                     or self.moment_order < 0):
            raise UserError(f"the mask_moments encoder's latent is (x, y, cos nφ, sin nφ): use "
                            f"--latent-dim 4 (got {self.latent_dim}) and --moment-order >= 1, "
                            f"or 0 to choose it from the data (got {self.moment_order})")
        if self.mask_channels < 1 or self.mask_layers < 1:
            raise UserError(f"--mask-channels {self.mask_channels} and --mask-layers "
                            f"{self.mask_layers}: use 1 or more of each")
        if self.mask_weight not in ("background", "image", "mask"):
            raise UserError(f"--mask-weight {self.mask_weight!r}: use background, image or mask")
        if self.mask_refine < 0 or (self.mask_refine and self.mask_window <= 0):
            raise UserError(f"--mask-refine {self.mask_refine} with --mask-window "
                            f"{self.mask_window}: use 0 or more steps, and a window > 0 "
                            "with steps (or --mask-refine 0)")
        if not (math.isfinite(self.mask_window) and self.mask_window >= 0):
            raise UserError(f"--mask-window {self.mask_window}: use a window of 0 (none) or "
                            f"more pixels")
        if self.encoder_kind == "keypoints" and (self.latent_dim % 2
                                                 or self.keypoint_channels < 1):
            raise UserError(f"the keypoints encoder gives two coordinates per keypoint: use an "
                            f"even latent_dim (got {self.latent_dim}) and keypoint_channels "
                            f">= 1 (got {self.keypoint_channels})")
        if self.decoder_kind == "sprite" and not self.pose_latent:
            raise UserError(f"the sprite decoder draws the object at the moments encoder's "
                            f"pose: use it with --encoder moments or mask_moments (got "
                            f"{self.encoder_kind!r}), or --decoder conv")
        if self.sprite_size is not None and (
                self.sprite_size < 1 or self.sprite_size % 2 == 0
                or (self.image_size is not None and self.sprite_size > min(self.hw))):
            raise UserError(f"sprite_size {self.sprite_size}: use an odd number of pixels "
                            f"(the template's centre is a pixel), at most the image's shorter "
                            f"side")
        if not self.mlp_widths or min(self.mlp_widths) < 1 or (
                self.mlp_activation not in ACTIVATIONS):
            raise UserError(f"--mlp-widths {self.mlp_widths} and --mlp-activation "
                            f"{self.mlp_activation!r}: use one or more positive widths and one "
                            f"of {', '.join(ACTIVATIONS)}")
        if self.sprite_supersample < 1:
            raise UserError(f"sprite_supersample {self.sprite_supersample}: use 1 or more")
        if self.decoder_channels < 1:
            raise UserError(f"decoder_channels {self.decoder_channels}: use 1 or more")
        if self.decoder_kind == "conv" and self.image_size is not None and (
                self.hw[0] % 4 or self.hw[1] % 4):
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
        if self.sprite_size is not None:
            return self.sprite_size
        return 2 * math.floor(5.5 * min(self.hw) / 32) + 1

    # ------------------------------------------------------------------ what the latent is
    @property
    def pose_latent(self) -> bool:
        """Whether the latent is a pose (x, y, cos nφ, sin nφ), as a face library needs."""
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
        return dataclasses.replace(resolved, sprite_size=resolved.sprite_side)

    def encoder_part(self) -> EncoderPart:
        """The encoder's own settings: its kind's, from this config's."""
        cls = ENCODER_PARTS[self.encoder_kind]
        return cls(**{name: getattr(self, flat) for name, flat in cls.flat.items()})

    def decoder_part(self) -> DecoderPart:
        """The decoder's own settings (the sprite's size: a resolved config's)."""
        cls = DECODER_PARTS[self.decoder_kind]
        return cls(**{name: getattr(self, flat) for name, flat in cls.flat.items()})

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
        self.encoder = ENCODERS[cfg.encoder_kind](cfg.encoder_part(), shape, cfg.latent_dim)
        self.decoder = DECODERS[cfg.decoder_kind](cfg.decoder_part(), shape, cfg.latent_dim)

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
            from latent_sindy.models.front import principal_components

            mean, basis = principal_components(frames.flatten(1), k)
            self.encoder.net[0].set(basis.T, -(mean @ basis))
            self.decoder.net[-1].set(basis, mean)

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
