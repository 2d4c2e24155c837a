"""Image encoder and decoder between normalised camera images and the latent state.

The encoder is the course's by default: two stages of 5×5 convolution + ReLU + 2×2 max-pool
followed by a fully connected layer of 100 units and a linear map to the latent size;
``"keypoints"``, a spatial softmax whose latent is the image positions of learned feature
maps (:class:`KeypointEncoder`); or ``"moments"``, no learned weights: the image moments of
what differs from the empty table, i.e. the block's position and orientation in image units
(:class:`MomentEncoder`). Three decoders:

* ``"fc"``, the course's: fully connected, latent → 500 → 500 → C·S·S;
* ``"conv"``: latent → 256 → a c × S/4 × S/4 feature map, then two 4×4 transposed
  convolutions of stride 2 (ReLU between) up to C × S × S. Its convolutions draw the block
  the same way wherever it is, where the fully connected decoder learns every position
  separately, so it generalises better from few images (measured in RESULTS.md);
* ``"sprite"`` (moments encoder only): nothing but a learned C × P × P template of what the
  block adds to the empty table, drawn at the latent's pose (:class:`SpriteDecoder`).

Both work on normalised images (see :class:`latent_sindy.data.windows.Normalizer`), so the
decoder's output is unbounded. Dimensions: B batch, C channels, S image side, nz latent size.

    >>> ae = Autoencoder(AutoencoderConfig(channels=1, image_size=32, latent_dim=16))
    >>> AutoencoderConfig().resolve(channels=1, image_size=32)  # the shape taken from data
    >>> z = ae.encode(torch.zeros(8, 1, 32, 32))  # (8, 16)
    >>> ae.decode(z).shape
    torch.Size([8, 1, 32, 32])
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import ClassVar, Literal

import torch
from torch import nn

from latent_sindy.errors import UserError
from latent_sindy.models.state import StateConfig, pose_cost_weights

__all__ = ["DECODERS", "ENCODERS", "Autoencoder", "AutoencoderConfig", "Decoder", "Encoder",
           "KeypointEncoder", "MomentEncoder", "SpriteDecoder"]

_KERNEL = 5


@dataclass(frozen=True)
class AutoencoderConfig:
    """Sizes of the encoder and decoder; equal resolved configs build identical architectures.

    ``channels`` and ``image_size`` left as None are taken from the training data
    (:meth:`resolve`); an autoencoder is built only from a resolved config.
    """

    kind: ClassVar[str] = "image"
    channels: int | None = None
    """Image channels C (1 grayscale, 3 RGB); None: from the data file."""
    image_size: int | None = None
    """Image side S in pixels; None: from the data file."""
    latent_dim: int = 16
    """Latent size nz (the paper: 16)."""
    conv_channels: tuple[int, int] = (4, 4)
    """Feature maps of the two 5×5 convolution stages (the course used 4 and 4)."""
    encoder_hidden: int = 100
    """Width of the encoder's fully connected layer (the course: 100)."""
    decoder: Literal["fc", "conv", "sprite"] = "fc"
    """Decoder kind: "fc" fully connected (the course's), "conv" upsampling convolutions,
    "sprite" (moments encoder only) a learned patch of the block drawn at the latent's pose
    on the encoder's background."""
    decoder_hidden: tuple[int, ...] = (500, 500)
    """fc decoder: widths of the hidden layers (the course: 500, 500)."""
    decoder_channels: int = 16
    """conv decoder: feature maps of its convolutions."""
    encoder: Literal["conv", "keypoints", "moments"] = "conv"
    """Encoder kind: "conv" (the course's: conv + pool stages, then fully connected),
    "keypoints" (a spatial softmax: the latent is the expected image position of
    latent_dim / 2 learned feature maps, so it is a position by construction) or "moments"
    (nothing learned: the latent is the centroid and the orientation of what differs from the
    empty table, (x, y, cos nφ, sin nφ); latent_dim 4)."""
    keypoint_channels: int = 16
    """keypoints encoder: feature maps of its two hidden 5×5 convolutions."""
    sprite_size: int | None = None
    """sprite decoder: side P of its template in pixels (odd); None: from the image side S,
    2 ⌊5.5 S / 32⌋ + 1 (11 at 32 pixels, which holds the demo's 4-pixel block turned by any
    angle, with its sides and shading; 23 at 64)."""
    sprite_supersample: int = 2
    """sprite decoder: draw at this many times the image side, then average-pool (1: draw at
    the image's resolution)."""
    moment_order: int = 4
    """moments encoder: n, the order of the angular moment that gives the orientation; the
    block's visible symmetry: 4 for the uniform square block (it looks alike every quarter
    turn), 1 for the marked one (2π / the world's angle period; training checks it)."""

    def __post_init__(self) -> None:
        if self.latent_dim < 1 or (self.channels is not None and self.channels < 1):
            raise UserError(f"latent_dim {self.latent_dim} and channels {self.channels}: use 1 "
                            "or more")
        if self.image_size is not None and self.conv_size() < 1:
            raise UserError(
                f"image_size {self.image_size} is too small for two 5x5 conv + 2x2 pool "
                "stages: use at least 16"
            )
        if len(self.conv_channels) != 2 or min(self.conv_channels) < 1:
            raise UserError(f"conv_channels must be two positive ints, got {self.conv_channels}")
        if self.encoder_hidden < 1 or not self.decoder_hidden or min(self.decoder_hidden) < 1:
            raise UserError(
                f"hidden sizes must be positive (and the decoder needs at least one layer), "
                f"got encoder_hidden={self.encoder_hidden}, decoder_hidden={self.decoder_hidden}"
            )
        if self.decoder not in DECODERS:
            raise UserError(f"decoder {self.decoder!r} is unknown: use one of "
                            + ", ".join(DECODERS))
        if self.encoder not in ENCODERS:
            raise UserError(f"encoder {self.encoder!r} is unknown: use one of "
                            + ", ".join(ENCODERS))
        if self.encoder == "moments" and (self.latent_dim != 4 or self.moment_order < 1):
            raise UserError(f"the moments encoder's latent is (x, y, cos nφ, sin nφ): use "
                            f"--latent-dim 4 (got {self.latent_dim}) and --moment-order >= 1 "
                            f"(got {self.moment_order})")
        if self.encoder == "keypoints" and (self.latent_dim % 2 or self.keypoint_channels < 1):
            raise UserError(f"the keypoints encoder gives two coordinates per keypoint: use an "
                            f"even latent_dim (got {self.latent_dim}) and keypoint_channels "
                            f">= 1 (got {self.keypoint_channels})")
        if self.decoder == "sprite" and self.encoder != "moments":
            raise UserError(f"the sprite decoder draws the block at the moments encoder's pose: "
                            f"use it with --encoder moments (got {self.encoder!r}), or "
                            f"--decoder conv")
        if self.sprite_size is not None and (
                self.sprite_size < 1 or self.sprite_size % 2 == 0
                or (self.image_size is not None and self.sprite_size > self.image_size)):
            raise UserError(f"sprite_size {self.sprite_size}: use an odd number of pixels "
                            f"(the template's centre is a pixel), at most the image side")
        if self.sprite_supersample < 1:
            raise UserError(f"sprite_supersample {self.sprite_supersample}: use 1 or more")
        if self.decoder_channels < 1:
            raise UserError(f"decoder_channels {self.decoder_channels}: use 1 or more")
        if self.decoder == "conv" and self.image_size is not None and self.image_size % 4:
            raise UserError(
                f"the conv decoder needs an image side divisible by 4 (got {self.image_size}): "
                "use --decoder fc or another image size"
            )

    @property
    def resolved(self) -> bool:
        return self.channels is not None and self.image_size is not None

    @property
    def sprite_side(self) -> int:
        """The sprite decoder's template side P: ``sprite_size``, or the one for the image
        side (a resolved config states it)."""
        if self.sprite_size is not None:
            return self.sprite_size
        if self.image_size is None:
            raise ValueError("the sprite's side follows the image side: resolve() first")
        return 2 * math.floor(5.5 * self.image_size / 32) + 1

    @property
    def pose_latent(self) -> bool:
        """Whether the latent is a pose (x, y, cos nφ, sin nφ), as a face library needs."""
        return self.encoder == "moments"

    @property
    def fixed_encoder(self) -> bool:
        """Whether the encoder learns nothing (the moments'), so its latents are data."""
        return self.encoder == "moments"

    def resolve(self, channels: int, image_size: int, source: str = "the data"
                ) -> AutoencoderConfig:
        """This config with the data's image shape filled in; UserError if it contradicts it."""
        for name, value in (("channels", channels), ("image_size", image_size)):
            mine = getattr(self, name)
            if mine is not None and mine != value:
                raise UserError(
                    f"model {name} is {mine} but {source} has {name} {value}: "
                    f"leave model {name} unset to use the data's"
                )
        resolved = dataclasses.replace(self, channels=channels, image_size=image_size)
        return dataclasses.replace(resolved, sprite_size=resolved.sprite_side)

    def build(self) -> Autoencoder:
        return Autoencoder(self)

    def conv_size(self) -> int:
        """Side of the feature maps after both conv + pool stages (5 for 32×32 images)."""
        s = self.image_size
        for _ in range(2):
            s = (s - _KERNEL + 1) // 2
        return s


class Encoder(nn.Module):
    """x (B, C, S, S) normalised images -> z (B, nz)."""

    def __init__(self, cfg: AutoencoderConfig) -> None:
        super().__init__()
        c1, c2 = cfg.conv_channels
        # Max-pooling before the ReLU (they commute: max(relu(a)) = relu(max(a))) applies
        # the ReLU to a quarter of the values; the layers' indices, hence the state dict's
        # keys, are those of the course's conv, ReLU, pool order.
        self.net = nn.Sequential(
            nn.Conv2d(cfg.channels, c1, _KERNEL),
            nn.MaxPool2d(2),
            nn.ReLU(inplace=True),
            nn.Conv2d(c1, c2, _KERNEL),
            nn.MaxPool2d(2),
            nn.ReLU(inplace=True),
            nn.Flatten(),
            nn.Linear(c2 * cfg.conv_size() ** 2, cfg.encoder_hidden),
            nn.ReLU(),
            nn.Linear(cfg.encoder_hidden, cfg.latent_dim),
        )
        # Channels-last conv weights (and input) take oneDNN's NHWC path on CPU: about 2.5x
        # faster convolution backward for these few-channel convs (benchmarks/train.py).
        self.to(memory_format=torch.channels_last)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x.contiguous(memory_format=torch.channels_last))


class KeypointEncoder(nn.Module):
    """x (B, C, S, S) -> z (B, nz): nz / 2 keypoints (x_1, y_1, x_2, y_2, ...) in [-1, 1].

    Three 5×5 convolutions at full resolution give one feature map per keypoint; a softmax
    over each map's pixels (with a learned temperature) weights the pixel coordinates, whose
    expectation is the keypoint (the spatial autoencoder of Finn et al., 2016). A block that
    moves moves its keypoints with it, by construction rather than learnt.
    """

    def __init__(self, cfg: AutoencoderConfig) -> None:
        super().__init__()
        c, k, s = cfg.keypoint_channels, cfg.latent_dim // 2, cfg.image_size
        pad = _KERNEL // 2
        self.net = nn.Sequential(
            nn.Conv2d(cfg.channels, c, _KERNEL, padding=pad), nn.ReLU(),
            nn.Conv2d(c, c, _KERNEL, padding=pad), nn.ReLU(),
            nn.Conv2d(c, k, _KERNEL, padding=pad))
        self.log_temperature = nn.Parameter(torch.zeros(()))
        coords = torch.linspace(-1.0, 1.0, s)
        rows, cols = torch.meshgrid(coords, coords, indexing="ij")
        self.register_buffer("grid", torch.stack([cols.flatten(), rows.flatten()], -1),
                             persistent=False)  # (S·S, 2): x right, y down
        self.net.to(memory_format=torch.channels_last)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        f = self.net(x.contiguous(memory_format=torch.channels_last))  # (B, K, S, S)
        p = torch.softmax(f.flatten(2) / self.log_temperature.exp(), dim=-1)  # (B, K, S·S)
        return (p @ self.grid).flatten(1)  # (B, K, 2) -> (B, 2K)


def median_background(frames: torch.Tensor, shape: torch.Size) -> torch.Tensor:
    """The per-pixel median (C, S, S) of normalised images (..., C, S, S): the empty table,
    for a block that covers any one pixel in few of them."""
    return frames.reshape(-1, *shape).median(0).values


class MomentEncoder(nn.Module):
    """x (B, C, S, S) -> z (B, 4) = (x, y, cos nφ, sin nφ): the block's pose in image units.

    Nothing is learned. The background (the empty table) is the per-pixel median of the
    training images (:meth:`fit_statistics`; the block covers any one pixel in few of them),
    and a pixel's weight w is its absolute difference from it, summed over channels. Then

    * (x, y) is the centroid of w, in the keypoints' image coordinates ([-1, 1], x to the
      right, y down);
    * nφ is the argument of the n-th angular moment Σ w' (r_x + i r_y)ⁿ about the centroid,
      so (cos nφ, sin nφ) is the orientation modulo the block's symmetry 2π / n. For n >= 2,
      w' = w; for n = 1 the moment of w about its own centroid is 0 by construction, so
      w' is the squared difference, where a face marked in another colour shows.

    On the demo's images (200 trajectories, uniform block, n = 4) a linear map of (x, y)
    reads the block's position to 0.54 cm (mean; R² 0.999) and nφ the orientation to 4.0°
    (mean; 93 % within 10°); on the marked block (n = 1) to 9.3° (mean). An image with no
    block reads the image centre and the angle features (0, 0).
    """

    def __init__(self, cfg: AutoencoderConfig) -> None:
        super().__init__()
        self.order = cfg.moment_order
        self.register_buffer("background", torch.zeros(cfg.channels, cfg.image_size,
                                                       cfg.image_size))
        coords = torch.linspace(-1.0, 1.0, cfg.image_size)
        self.register_buffer("coords", coords, persistent=False)

    @torch.no_grad()
    def fit_statistics(self, frames: torch.Tensor) -> None:
        """Set the background from normalised training images (N, C, S, S)."""
        self.background.copy_(median_background(frames, self.background.shape))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        d = x - self.background  # (B, C, S, S)
        w = d.abs().sum(1)  # (B, S, S)
        tiny = torch.finfo(x.dtype).tiny
        mass = w.sum((1, 2)).clamp_min(tiny)  # (B,)
        c = self.coords
        cx = (w.sum(1) * c).sum(1) / mass  # columns: x
        cy = (w.sum(2) * c).sum(1) / mass  # rows: y
        rx = c[None, None, :] - cx[:, None, None]  # (B, 1, S)
        ry = c[None, :, None] - cy[:, None, None]  # (B, S, 1)
        re, im = rx.expand_as(w), ry.expand_as(w)
        pr, pi = re, im  # (rx + i ry)^n by repeated products
        for _ in range(self.order - 1):
            pr, pi = pr * re - pi * im, pr * im + pi * re
        wm = w if self.order > 1 else d.square().sum(1)
        mr, mi = (wm * pr).sum((1, 2)), (wm * pi).sum((1, 2))
        size = (wm * (re.square() + im.square()).pow(self.order / 2)).sum((1, 2))
        norm = torch.sqrt(mr.square() + mi.square() + (1e-6 * size).square() + tiny)
        return torch.stack([cx, cy, mr / norm, mi / norm], -1)

    def cost_weights(self) -> torch.Tensor:
        """Q of MPPI's latent cost: one pixel of position error costs 1 (about 2.5 cm on the
        default camera), and so does 10° of orientation (as the state's cost,
        :func:`~latent_sindy.models.state.pose_cost_weights`)."""
        pixel = float(self.coords[1] - self.coords[0])
        return pose_cost_weights(2 * math.pi / self.order, StateConfig(position_scale=pixel))


class _NativeForwardConvTranspose(torch.autograd.Function):
    """conv_transpose2d with PyTorch's own CPU kernel forward and oneDNN's backward.

    For one output channel (grayscale images) oneDNN pads the output channels to a vector
    width and its forward costs 3x the native kernel's; its backward is the faster one.
    Deterministic: both kernels are (results depend on the thread count, like every kernel).
    """

    @staticmethod
    def forward(ctx, x, weight, bias, stride, padding):  # type: ignore[override]
        ctx.save_for_backward(x, weight)
        ctx.geometry = (stride, padding)
        return torch.ops.aten.slow_conv_transpose2d(
            x, weight, list(weight.shape[2:]), bias, stride, padding)

    @staticmethod
    def backward(ctx, grad):  # type: ignore[override]
        x, weight = ctx.saved_tensors
        stride, padding = ctx.geometry
        gx, gw, gb = torch.ops.aten.convolution_backward(
            grad, x, weight, [weight.shape[1]], stride, padding, [1, 1], True, [0, 0], 1,
            list(ctx.needs_input_grad[:3]))
        return gx, gw, gb, None, None


class _ImageConvTranspose2d(nn.ConvTranspose2d):
    """The decoder's last layer: for one output channel on the CPU through
    :class:`_NativeForwardConvTranspose` (1.7x faster forward + backward at the paper's
    sizes; for 3 channels it would be 0.76x, BENCHMARKS.md), otherwise ``nn.ConvTranspose2d``;
    the same parameters, so the same state dict."""

    def forward(self, x: torch.Tensor, output_size: list[int] | None = None) -> torch.Tensor:
        if x.device.type != "cpu" or self.out_channels != 1 or output_size is not None or (
                self.groups != 1 or any(d != 1 for d in self.dilation)
                or any(self.output_padding)):
            return super().forward(x, output_size)
        return _NativeForwardConvTranspose.apply(x, self.weight, self.bias, list(self.stride),
                                                 list(self.padding))


class Decoder(nn.Module):
    """z (..., nz) -> x̂ (..., C, S, S) normalised images (the config's decoder kind)."""

    def __init__(self, cfg: AutoencoderConfig) -> None:
        super().__init__()
        self.shape = (cfg.channels, cfg.image_size, cfg.image_size)
        self.conv: nn.Module | None = None
        if cfg.decoder == "fc":
            layers: list[nn.Module] = []
            width = cfg.latent_dim
            for hidden in cfg.decoder_hidden:
                layers += [nn.Linear(width, hidden), nn.ReLU()]
                width = hidden
            layers.append(nn.Linear(width, cfg.channels * cfg.image_size**2))
            self.net = nn.Sequential(*layers)
            return
        c, side = cfg.decoder_channels, cfg.image_size // 4
        self.map_shape = (c, side, side)
        self.net = nn.Sequential(  # (in-place ReLUs: no layer here keeps its output)
            nn.Linear(cfg.latent_dim, 256), nn.ReLU(inplace=True),
            nn.Linear(256, c * side * side), nn.ReLU(inplace=True))
        self.conv = nn.Sequential(  # each transposed convolution doubles the side
            nn.ConvTranspose2d(c, c, 4, stride=2, padding=1), nn.ReLU(inplace=True),
            _ImageConvTranspose2d(c, cfg.channels, 4, stride=2, padding=1))
        self.conv.to(memory_format=torch.channels_last)  # 1.9x faster here, like the encoder

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        h = self.net(z)
        if self.conv is not None:
            h = h.reshape(-1, *self.map_shape).contiguous(memory_format=torch.channels_last)
            h = self.conv(h)
        return h.reshape(*z.shape[:-1], *self.shape)


class SpriteDecoder(nn.Module):
    """z (..., 4) = (x, y, cos nφ, sin nφ) -> x̂ (..., C, S, S): the block drawn at its pose.

    The moments encoder's inverse, with one learned thing: a template T (C, P, P), P odd, of
    what the block adds to the empty table, in the moment's own frame (so the offset between
    the moment's angle and the block's edges does not matter). The image is the background
    (the per-pixel median of the training images, as the encoder's: :meth:`fit_statistics`)
    plus T with its centre pixel at (x, y) (image coordinates, pixel centres at
    ``linspace(-1, 1, S)``, x right, y down), turned by φ = atan2(sin nφ, cos nφ) / n from x
    toward y; template and image pixels are the same size.

    The parameter ``weight`` is T / :attr:`GAIN` (zero at first): a block adds about −7
    standard deviations to the normalised table, which Adam's steps of about the learning
    rate would take thousands of steps to reach in T's own units (on the demo, 60 epochs at
    lr 1e-3 left the reconstruction MSE at 0.79 against the conv decoder's 0.21).

    Drawn by ``affine_grid`` + ``grid_sample`` (bilinear, zeros outside the template), at
    ``sprite_supersample`` times the image side and average-pooled: differentiable in the
    template and continuous in the pose, except where φ wraps (at ±π / n; a template with the
    block's symmetry looks alike there). Both use align_corners=False, whose normalised
    coordinates put pixel j of S at (2j + 1) / S − 1: image coordinate q = S / (S − 1) times
    that, and a template offset of d image units is d (S − 1) / P template units.
    """

    def __init__(self, cfg: AutoencoderConfig) -> None:
        super().__init__()
        c, s, p = cfg.channels, cfg.image_size, cfg.sprite_side
        self.order = cfg.moment_order
        self.supersample = cfg.sprite_supersample
        self.shape = (c, s, s)
        self.weight = nn.Parameter(torch.zeros(c, p, p))
        self.register_buffer("background", torch.zeros(c, s, s))

    GAIN: ClassVar[float] = 10.0
    """The template T in units of ``weight``."""

    @property
    def template(self) -> torch.Tensor:
        """T (C, P, P): what the block adds to the normalised background, in its own frame."""
        return self.GAIN * self.weight

    @torch.no_grad()
    def set_template(self, template: torch.Tensor) -> None:
        """Set T (C, P, P)."""
        self.weight.copy_(template / self.GAIN)

    @torch.no_grad()
    def fit_statistics(self, frames: torch.Tensor) -> None:
        """Set the background from normalised training images (N, C, S, S), as the encoder."""
        self.background.copy_(median_background(frames, self.background.shape))

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        lead = z.shape[:-1]
        z = z.reshape(-1, z.shape[-1])
        b, (c, s, _), p, f = len(z), self.shape, self.template.shape[-1], self.supersample
        cn, sn = z[:, 2], z[:, 3]
        # φ = arg(cos nφ + i sin nφ) / n; (0, 0) (no block seen) reads 0, with finite gradients
        none = (cn == 0) & (sn == 0)
        angle = torch.atan2(sn, torch.where(none, torch.ones_like(cn), cn)) / self.order
        cos, sin = torch.cos(angle), torch.sin(angle)
        # template coordinates = k R(-φ) (q - centre), q = s_img · (output's normalised coords)
        k, s_img = (s - 1) / p, s / (s - 1)
        rot = torch.stack([torch.stack([cos, sin], -1), torch.stack([-sin, cos], -1)], -2)
        theta = k * torch.cat([s_img * rot, -(rot @ z[:, :2, None])], -1)  # (B, 2, 3)
        side = s * f
        grid = nn.functional.affine_grid(theta, [b, 1, side, side], align_corners=False)
        # One template, B grids stacked as the rows of one: no copy of it per image
        t = self.template.to(z.dtype)[None]
        drawn = nn.functional.grid_sample(t, grid.reshape(1, b * side, side, 2),
                                          mode="bilinear", padding_mode="zeros",
                                          align_corners=False)  # (1, C, B·side, side)
        drawn = drawn.reshape(c, b, side, side).transpose(0, 1)
        if f > 1:
            drawn = nn.functional.avg_pool2d(drawn, f)
        return (self.background.to(z.dtype) + drawn).reshape(*lead, c, s, s)


class Autoencoder(nn.Module):
    """Encoder and decoder of one :class:`AutoencoderConfig`."""

    def __init__(self, cfg: AutoencoderConfig) -> None:
        super().__init__()
        if not cfg.resolved:
            raise ValueError("AutoencoderConfig needs channels and image_size: resolve() first")
        self.config = cfg
        self.encoder = ENCODERS[cfg.encoder](cfg)
        self.decoder = DECODERS[cfg.decoder](cfg)

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """x (..., C, S, S) -> z (..., nz); any leading dimensions."""
        lead = x.shape[:-3]
        return self.encoder(x.reshape(-1, *x.shape[-3:])).view(*lead, -1)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """z (..., nz) -> x̂ (..., C, S, S); any leading dimensions."""
        return self.decoder(z)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.decode(self.encode(x))

    @torch.no_grad()
    def fit_statistics(self, frames: torch.Tensor) -> None:
        """Let an encoder or a decoder that needs them (the moments encoder's and the sprite
        decoder's background) take their statistics from normalised training images
        (N, C, S, S); the learned ones need none."""
        for part in (self.encoder, self.decoder):
            fit = getattr(part, "fit_statistics", None)
            if fit is not None:
                fit(frames)

    def cost_weights(self, angle_period: float) -> torch.Tensor:
        """Q of MPPI's latent cost: the moments encoder's pose scales, else every latent
        coordinate alike."""
        if isinstance(self.encoder, MomentEncoder):
            return self.encoder.cost_weights()
        return torch.ones(self.config.latent_dim)


#: The encoder kinds of ``AutoencoderConfig.encoder``.
ENCODERS: dict[str, type[nn.Module]] = {"conv": Encoder, "keypoints": KeypointEncoder,
                                        "moments": MomentEncoder}

#: The decoder kinds of ``AutoencoderConfig.decoder``.
DECODERS: dict[str, type[nn.Module]] = {"fc": Decoder, "conv": Decoder,
                                        "sprite": SpriteDecoder}
