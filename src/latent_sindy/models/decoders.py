"""Image decoders: latents z (..., nz) -> normalised images x̂ (..., C, H, W).

Four kinds (:data:`~.autoencoder.DECODERS`), each built from its settings
(:mod:`.autoencoder_parts`; ``AutoencoderConfig.decoder``), the image shape and nz:

* ``"fc"`` (:class:`Decoder`, the course's): fully connected, latent → 500 → 500 → C·H·W;
* ``"conv"`` (:class:`Decoder`): latent → 256 → a c × H/4 × W/4 feature map, then two 4×4
  transposed convolutions of stride 2 (ReLU between) up to C × H × W. Its convolutions draw
  an object the same way wherever it is, where the fully connected decoder learns every
  position separately, so it generalises better from few images (measured in RESULTS.md);
* ``"sprite"`` (:class:`SpriteDecoder`, with the moments encoder only): nothing but a
  learned C × P × P template of what the object adds to the background, drawn at the
  latent's pose;
* ``"mlp"`` (:class:`MlpDecoder`): the fully connected encoder's mirror, latent → the
  ``mlp_widths`` reversed (32, 64, 128) with ``mlp_activation`` → C·H·W (the SINDy
  autoencoder's).

The images are normalised, so the output is unbounded.

    >>> dec = Decoder(ConvDecoderConfig(), (3, 20, 28), latent_dim=16)
    >>> dec(torch.zeros(5, 16)).shape
    torch.Size([5, 3, 20, 28])
"""

from __future__ import annotations

from typing import ClassVar

import torch
from torch import nn

from latent_sindy.models.autoencoder_parts import (
    ConvDecoderConfig,
    FcDecoderConfig,
    ImageShape,
    MlpDecoderConfig,
    SpriteDecoderConfig,
    sprite_side,
)
from latent_sindy.models.encoders import median_background, mlp
from latent_sindy.models.pca_front import LinearMap

__all__ = ["Decoder", "MlpDecoder", "SpriteDecoder"]


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
    """z (..., nz) -> x̂ (..., C, H, W) normalised images: the "fc" or the "conv" kind."""

    def __init__(self, cfg: FcDecoderConfig | ConvDecoderConfig, shape: ImageShape,
                 latent_dim: int) -> None:
        super().__init__()
        self.shape = shape
        self.conv: nn.Module | None = None
        if isinstance(cfg, FcDecoderConfig):
            layers: list[nn.Module] = []
            width = latent_dim
            for hidden in cfg.hidden:
                layers += [nn.Linear(width, hidden), nn.ReLU()]
                width = hidden
            layers.append(nn.Linear(width, shape[0] * shape[1] * shape[2]))
            self.net = nn.Sequential(*layers)
            return
        c, h, w = cfg.channels, shape[1] // 4, shape[2] // 4
        self.map_shape = (c, h, w)
        self.net = nn.Sequential(  # (in-place ReLUs: no layer here keeps its output)
            nn.Linear(latent_dim, 256), nn.ReLU(inplace=True),
            nn.Linear(256, c * h * w), nn.ReLU(inplace=True))
        self.conv = nn.Sequential(  # each transposed convolution doubles both sides
            nn.ConvTranspose2d(c, c, 4, stride=2, padding=1), nn.ReLU(inplace=True),
            _ImageConvTranspose2d(c, shape[0], 4, stride=2, padding=1))
        self.conv.to(memory_format=torch.channels_last)  # 1.9x faster here, like the encoder

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        h = self.net(z)
        if self.conv is not None:
            h = h.reshape(-1, *self.map_shape).contiguous(memory_format=torch.channels_last)
            h = self.conv(h)
        return h.reshape(*z.shape[:-1], *self.shape)


class MlpDecoder(nn.Module):
    """The fully connected decoder: z (..., nz) -> x̂ (..., C, H, W) through the reversed
    ``mlp_widths``."""

    def __init__(self, cfg: MlpDecoderConfig, shape: ImageShape, latent_dim: int,
                 pca_components: int = 0) -> None:  # k principal components behind; 0: none
        super().__init__()
        self.shape = shape
        pixels = shape[0] * shape[1] * shape[2]
        k = pca_components
        self.net = mlp([latent_dim, *reversed(cfg.widths), k or pixels], cfg.activation)
        if k:  # back from the principal components (fitted with the model's statistics)
            self.net.append(LinearMap(k, pixels))

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.net(z).reshape(*z.shape[:-1], *self.shape)

    def along(self, z: torch.Tensor, *rates: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """x̂ and its time derivatives from z (B, nz) and its ż[, z̈]: (B, C, H, W) each
        (:func:`~latent_sindy.models.derivatives.along`)."""
        from latent_sindy.models.derivatives import along_layers

        out = along_layers(self.net, z, *rates)
        return tuple(o.reshape(*z.shape[:-1], *self.shape) for o in out)


class SpriteDecoder(nn.Module):
    """z (..., 4) = (x, y, cos nφ, sin nφ) -> x̂ (..., C, H, W): an object drawn at its pose.

    The moments encoder's inverse, with one learned thing: a template T (C, P, P), P odd, of
    what the object adds to the background, in the moment's own frame (so the offset between
    the moment's angle and the object's edges does not matter). The image is the background
    (the per-pixel median of the training images, as the encoder's: :meth:`fit_statistics`)
    plus T with its centre pixel at (x, y) (the encoder's isotropic image coordinates,
    :func:`~latent_sindy.models.encoders.image_coordinates`), turned by
    φ = atan2(sin nφ, cos nφ) / n from x toward y; template and image pixels are the same size.

    The parameter ``weight`` is T / :attr:`GAIN` (zero at first): an object that adds about
    −7 standard deviations to the normalised background would take Adam's steps of about the
    learning rate thousands of steps to reach in T's own units (for example, on the pushing
    demo 60 epochs at lr 1e-3 left the reconstruction MSE at 0.79 against the conv decoder's
    0.21).

    Drawn by ``affine_grid`` + ``grid_sample`` (bilinear, zeros outside the template), at
    ``sprite_supersample`` times the image's resolution and average-pooled: differentiable in
    the template and continuous in the pose, except where φ wraps (at ±π / n; a template with
    the object's symmetry looks alike there). Both use align_corners=False, whose normalised
    coordinates put pixel j of W at (2j + 1) / W − 1: image coordinate x = W / (L − 1) times
    that (y: H / (L − 1); L = max(H, W)), and an offset of d image units is d (L − 1) / P
    template units.
    """

    def __init__(self, cfg: SpriteDecoderConfig, shape: ImageShape, latent_dim: int = 4,
                 order: int = 4) -> None:  # order: the moments encoder's, n of nφ
        super().__init__()
        (c, h, w), p = shape, cfg.size or sprite_side(shape[1:])
        self.order = order
        self.supersample = cfg.supersample
        self.shape = (c, h, w)
        side = max(h, w) - 1
        self._to_template = side / p  # image units -> template units
        self._to_image = (w / side, h / side)  # output's normalised coordinates -> image units
        self.weight = nn.Parameter(torch.zeros(c, p, p))
        self.register_buffer("background", torch.zeros(c, h, w))

    GAIN: ClassVar[float] = 10.0
    """The template T in units of ``weight``."""

    @property
    def template(self) -> torch.Tensor:
        """T (C, P, P): what the object adds to the normalised background, in its own frame."""
        return self.GAIN * self.weight

    @torch.no_grad()
    def set_template(self, template: torch.Tensor) -> None:
        """Set T (C, P, P)."""
        self.weight.copy_(template / self.GAIN)

    @torch.no_grad()
    def fit_statistics(self, frames: torch.Tensor) -> None:
        """Set the background from normalised training images (N, C, H, W), as the encoder."""
        self.background.copy_(median_background(frames, self.background.shape))

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        lead = z.shape[:-1]
        z = z.reshape(-1, z.shape[-1])
        b, (c, h, w), f = len(z), self.shape, self.supersample
        cn, sn = z[:, 2], z[:, 3]
        # φ = arg(cos nφ + i sin nφ) / n; (0, 0) (no object seen) reads 0, with finite gradients
        none = (cn == 0) & (sn == 0)
        angle = torch.atan2(sn, torch.where(none, torch.ones_like(cn), cn)) / self.order
        cos, sin = torch.cos(angle), torch.sin(angle)
        # template coordinates = k R(-φ) (q - centre), q = the output's normalised coordinates
        # in image units
        rot = torch.stack([torch.stack([cos, sin], -1), torch.stack([-sin, cos], -1)], -2)
        sx, sy = self._to_image
        scaled = sx * rot if sx == sy else rot * rot.new_tensor([sx, sy])
        theta = self._to_template * torch.cat([scaled, -(rot @ z[:, :2, None])], -1)  # (B, 2, 3)
        rows, cols = h * f, w * f
        grid = nn.functional.affine_grid(theta, [b, 1, rows, cols], align_corners=False)
        # One template, B grids stacked as the rows of one: no copy of it per image
        t = self.template.to(z.dtype)[None]
        drawn = nn.functional.grid_sample(t, grid.reshape(1, b * rows, cols, 2),
                                          mode="bilinear", padding_mode="zeros",
                                          align_corners=False)  # (1, C, B·rows, cols)
        drawn = drawn.reshape(c, b, rows, cols).transpose(0, 1)
        if f > 1:
            drawn = nn.functional.avg_pool2d(drawn, f)
        return (self.background.to(z.dtype) + drawn).reshape(*lead, c, h, w)
