"""Image encoder and decoder between normalised camera images and the latent state.

The course's architecture: the encoder is two stages of 5×5 convolution + ReLU + 2×2 max-pool
followed by a fully connected layer of 100 units and a linear map to the latent size; the
decoder is fully connected, latent → 500 → 500 → C·S·S. Both work on normalised images
(see :class:`latent_sindy.data.windows.Normalizer`), so the decoder's output is unbounded.
Dimensions: B batch, C channels, S image side, nz latent size.

    >>> ae = Autoencoder(AutoencoderConfig(channels=1, image_size=32, latent_dim=16))
    >>> z = ae.encode(torch.zeros(8, 1, 32, 32))  # (8, 16)
    >>> ae.decode(z).shape
    torch.Size([8, 1, 32, 32])
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

__all__ = ["Autoencoder", "AutoencoderConfig", "Decoder", "Encoder"]

_KERNEL = 5


@dataclass(frozen=True)
class AutoencoderConfig:
    """Sizes of the encoder and decoder; equal configs build identical architectures."""

    channels: int = 1
    """Image channels C (1 grayscale, 3 RGB)."""
    image_size: int = 32
    """Image side S in pixels."""
    latent_dim: int = 16
    """Latent size nz."""
    conv_channels: tuple[int, int] = (4, 4)
    """Feature maps of the two 5×5 convolution stages (the course used 4 and 4)."""
    encoder_hidden: int = 100
    """Width of the encoder's fully connected layer (the course: 100)."""
    decoder_hidden: tuple[int, ...] = (500, 500)
    """Widths of the decoder's hidden layers (the course: 500, 500)."""

    def __post_init__(self) -> None:
        if self.channels < 1 or self.latent_dim < 1:
            raise ValueError(f"need channels >= 1 and latent_dim >= 1, got {self}")
        if self.conv_size() < 1:
            raise ValueError(
                f"image_size {self.image_size} is too small for two 5x5 conv + 2x2 pool "
                "stages: use at least 16"
            )
        if len(self.conv_channels) != 2 or min(self.conv_channels) < 1:
            raise ValueError(f"conv_channels must be two positive ints, got {self.conv_channels}")
        if self.encoder_hidden < 1 or not self.decoder_hidden or min(self.decoder_hidden) < 1:
            raise ValueError(
                f"hidden sizes must be positive (and the decoder needs at least one layer), "
                f"got encoder_hidden={self.encoder_hidden}, decoder_hidden={self.decoder_hidden}"
            )

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
        self.net = nn.Sequential(
            nn.Conv2d(cfg.channels, c1, _KERNEL),
            nn.ReLU(),
            nn.MaxPool2d(2),
            nn.Conv2d(c1, c2, _KERNEL),
            nn.ReLU(),
            nn.MaxPool2d(2),
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


class Decoder(nn.Module):
    """z (B, nz) -> x̂ (B, C, S, S) normalised images, fully connected."""

    def __init__(self, cfg: AutoencoderConfig) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        width = cfg.latent_dim
        for hidden in cfg.decoder_hidden:
            layers += [nn.Linear(width, hidden), nn.ReLU()]
            width = hidden
        layers.append(nn.Linear(width, cfg.channels * cfg.image_size**2))
        self.net = nn.Sequential(*layers)
        self.shape = (cfg.channels, cfg.image_size, cfg.image_size)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.net(z).view(*z.shape[:-1], *self.shape)


class Autoencoder(nn.Module):
    """Encoder and decoder of one :class:`AutoencoderConfig`."""

    def __init__(self, cfg: AutoencoderConfig) -> None:
        super().__init__()
        self.config = cfg
        self.encoder = Encoder(cfg)
        self.decoder = Decoder(cfg)

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """x (..., C, S, S) -> z (..., nz); any leading dimensions."""
        lead = x.shape[:-3]
        return self.encoder(x.reshape(-1, *x.shape[-3:])).view(*lead, -1)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """z (..., nz) -> x̂ (..., C, S, S); any leading dimensions."""
        return self.decoder(z)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.decode(self.encode(x))
