"""Image encoders: normalised images x (B, C, H, W) -> latents z (B, nz).

Five kinds (:data:`~.autoencoder.ENCODERS`), each built from its settings
(:mod:`.autoencoder_parts`; ``AutoencoderConfig.encoder``), the image shape and nz:

* ``"conv"`` (:class:`Encoder`, the course's): two stages of 5×5 convolution + ReLU + 2×2
  max-pool, a fully connected layer and a linear map to the latent size;
* ``"keypoints"`` (:class:`KeypointEncoder`): a spatial softmax, whose latent is the image
  positions of learned feature maps;
* ``"moments"`` (:class:`MomentEncoder`): nothing learned, the image moments of what differs
  from the background: the position and orientation of the one object that moves;
* ``"mask_moments"`` (:class:`MaskMomentEncoder`): the same moments of a learned per-pixel
  weight (a small convolutional net) instead of the difference from a median background;
* ``"mlp"`` (:class:`MlpEncoder`): fully connected on the flattened image, hidden widths
  (the SINDy autoencoder's 128, 64, 32; sigmoid), and a linear map to the latent; smooth.

Every kind takes any image shape (C, H, W). Image coordinates, where a latent is a position,
run from -1 to 1 across the image (x to the right, y down; pixel centres); the moments'
are isotropic (see :func:`image_coordinates`).

    >>> enc = Encoder(ConvEncoderConfig(), (3, 20, 28), latent_dim=8)
    >>> enc(torch.zeros(5, 3, 20, 28)).shape
    torch.Size([5, 8])
"""

from __future__ import annotations

import itertools

import torch
from torch import nn

import latent_sindy.models.autoencoder_parts as parts
from latent_sindy.errors import UserError
from latent_sindy.models.autoencoder_parts import KERNEL, ImageShape, conv_shape
from latent_sindy.models.pca_front import LinearMap

__all__ = ["ACTIVATIONS", "KERNEL", "Encoder", "KeypointEncoder", "MaskMomentEncoder",
           "MlpEncoder", "MomentEncoder", "angular_moments", "image_coordinates",
           "median_background", "mlp", "moment_pose", "symmetry_order"]

#: The activations of the fully connected ("mlp") encoder and decoder, by name.
ACTIVATIONS: dict[str, type[nn.Module]] = {"sigmoid": nn.Sigmoid, "relu": nn.ReLU,
                                           "elu": nn.ELU, "tanh": nn.Tanh}


def mlp(widths: list[int], activation: str) -> nn.Sequential:
    """Linear layers through ``widths`` (in, hidden..., out), ``activation`` after every
    hidden one, the last linear."""
    layers: list[nn.Module] = []
    for a, b in itertools.pairwise(widths[:-1]):
        layers += [nn.Linear(a, b), ACTIVATIONS[activation]()]
    layers.append(nn.Linear(widths[-2], widths[-1]))
    return nn.Sequential(*layers)


class MlpEncoder(nn.Module):
    """The fully connected encoder: x (B, C, H, W) -> z (B, nz) through ``mlp_widths``."""

    def __init__(self, cfg: parts.MlpEncoderConfig, shape: ImageShape, latent_dim: int,
                 pca_components: int = 0) -> None:  # k principal components in front; 0: none
        super().__init__()
        pixels = shape[0] * shape[1] * shape[2]
        k = pca_components
        self.net = mlp([k or pixels, *cfg.widths, latent_dim], cfg.activation)
        if k:  # the principal components in front (fitted with the model's statistics)
            self.net.insert(0, LinearMap(pixels, k))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x.flatten(1))

    def along(self, x: torch.Tensor, *rates: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """z and its time derivatives from x (B, C, H, W) and its ẋ[, ẍ]: (B, nz) each
        (:func:`~latent_sindy.models.derivatives.along`)."""
        from latent_sindy.models.derivatives import along_layers

        return along_layers(self.net, x.flatten(1), *(r.flatten(1) for r in rates))


class Encoder(nn.Module):
    """The conv encoder: x (B, C, H, W) normalised images -> z (B, nz)."""

    def __init__(self, cfg: parts.ConvEncoderConfig, shape: ImageShape, latent_dim: int) -> None:
        super().__init__()
        c1, c2 = cfg.channels
        h, w = conv_shape(shape[1:])
        # Max-pooling before the ReLU (they commute: max(relu(a)) = relu(max(a))) applies
        # the ReLU to a quarter of the values; the layers' indices, hence the state dict's
        # keys, are those of the course's conv, ReLU, pool order.
        self.net = nn.Sequential(
            nn.Conv2d(shape[0], c1, KERNEL),
            nn.MaxPool2d(2),
            nn.ReLU(inplace=True),
            nn.Conv2d(c1, c2, KERNEL),
            nn.MaxPool2d(2),
            nn.ReLU(inplace=True),
            nn.Flatten(),
            nn.Linear(c2 * h * w, cfg.hidden),
            nn.ReLU(),
            nn.Linear(cfg.hidden, latent_dim),
        )
        # Channels-last conv weights (and input) take oneDNN's NHWC path on CPU: about 2.5x
        # faster convolution backward for these few-channel convs (benchmarks/train.py).
        self.to(memory_format=torch.channels_last)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x.contiguous(memory_format=torch.channels_last))


class KeypointEncoder(nn.Module):
    """x (B, C, H, W) -> z (B, nz): nz / 2 keypoints (x_1, y_1, x_2, y_2, ...) in [-1, 1].

    Three 5×5 convolutions at full resolution give one feature map per keypoint; a softmax
    over each map's pixels (with a learned temperature) weights the pixel coordinates (x from
    -1 to 1 across the width, y across the height), whose expectation is the keypoint (the
    spatial autoencoder of Finn et al., 2016). An object that moves moves its keypoints with
    it, by construction rather than learnt.
    """

    def __init__(self, cfg: parts.KeypointEncoderConfig, shape: ImageShape, latent_dim: int
                 ) -> None:
        super().__init__()
        c = cfg.channels
        k = latent_dim // 2
        pad = KERNEL // 2
        self.net = nn.Sequential(
            nn.Conv2d(shape[0], c, KERNEL, padding=pad), nn.ReLU(),
            nn.Conv2d(c, c, KERNEL, padding=pad), nn.ReLU(),
            nn.Conv2d(c, k, KERNEL, padding=pad))
        self.log_temperature = nn.Parameter(torch.zeros(()))
        rows, cols = torch.meshgrid(torch.linspace(-1.0, 1.0, shape[1]),
                                    torch.linspace(-1.0, 1.0, shape[2]), indexing="ij")
        self.register_buffer("grid", torch.stack([cols.flatten(), rows.flatten()], -1),
                             persistent=False)  # (H·W, 2): x right, y down
        self.net.to(memory_format=torch.channels_last)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        f = self.net(x.contiguous(memory_format=torch.channels_last))  # (B, K, H, W)
        p = torch.softmax(f.flatten(2) / self.log_temperature.exp(), dim=-1)  # (B, K, H·W)
        return (p @ self.grid).flatten(1)  # (B, K, 2) -> (B, 2K)


def image_coordinates(height: int, width: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Isotropic image coordinates of the pixel centres: x (W,) and y (H,), centred, one pixel
    2 / (L - 1) wide, L = max(H, W): the longer side runs from -1 to 1 (both, when square)."""
    side = max(height, width)
    xs = torch.linspace(-1.0, 1.0, width) * ((width - 1) / (side - 1) if side > 1 else 1.0)
    ys = torch.linspace(-1.0, 1.0, height) * ((height - 1) / (side - 1) if side > 1 else 1.0)
    return xs, ys


def median_background(frames: torch.Tensor, shape: torch.Size) -> torch.Tensor:
    """The per-pixel median (C, H, W) of normalised images (..., C, H, W): the background,
    for an object that covers any one pixel in few of them."""
    return frames.reshape(-1, *shape).median(0).values


class _PoseFrame(nn.Module):
    """What both moments encoders hold: the order n, the background buffer (C, H, W) and the
    pixel coordinates xs (W,), ys (H,) of :func:`image_coordinates`."""

    def __init__(self, cfg: parts.MomentEncoderConfig | parts.MaskMomentEncoderConfig,
                 shape: ImageShape, latent_dim: int = 4) -> None:
        super().__init__()
        self.order = cfg.order
        self.register_buffer("background", torch.zeros(shape))
        xs, ys = image_coordinates(shape[1], shape[2])
        self.register_buffer("xs", xs, persistent=False)
        self.register_buffer("ys", ys, persistent=False)

    @property
    def pixel(self) -> float:
        """One pixel's width in the latent's position units."""
        return float(self.xs[1] - self.xs[0])


class MomentEncoder(_PoseFrame):
    """x (B, C, H, W) -> z (B, 4) = (x, y, cos nφ, sin nφ): the pose of the one object that
    differs from the background, in image coordinates.

    Nothing is learned. The background is the per-pixel median of the training images
    (:meth:`fit_statistics`; the object covers any one pixel in few of them), and a pixel's
    weight w is its absolute difference from it, summed over channels. Then

    * (x, y) is the centroid of w, in the isotropic coordinates of
      :func:`image_coordinates` (x to the right, y down);
    * nφ is the argument of the n-th angular moment Σ w' (r_x + i r_y)ⁿ about the centroid,
      so (cos nφ, sin nφ) is the orientation modulo the object's symmetry 2π / n. For n >= 2,
      w' = w; for n = 1 the moment of w about its own centroid is 0 by construction, so
      w' is the squared difference, where a part marked in another colour shows.

    An image equal to the background reads the image centre and the angle features (0, 0).
    (For example, on the pushing world's images a linear map of (x, y) reads the block's
    position to 0.54 cm and nφ its orientation to 4.0°, mean errors; RESULTS.md.)
    """

    @torch.no_grad()
    def fit_statistics(self, frames: torch.Tensor) -> None:
        """Set the background from normalised training images (N, C, H, W)."""
        self.background.copy_(median_background(frames, self.background.shape))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        d = x - self.background  # (B, C, H, W)
        w = d.abs().sum(1)  # (B, H, W)
        return moment_pose(w, d.square().sum(1) if self.order == 1 else w, self.xs, self.ys,
                           self.order)


def moment_pose(w: torch.Tensor, wm: torch.Tensor, xs: torch.Tensor, ys: torch.Tensor,
                order: int, window: float | None = None) -> torch.Tensor:
    """(x, y, cos nφ, sin nφ) (B, 4) of weights w (B, H, W) >= 0: the centroid of w (pixel
    coordinates xs (W,), ys (H,)) and the unit direction of the n-th angular moment
    Σ wm (r_x + i r_y)ⁿ of ``wm`` about it (``wm`` is w itself for n >= 2; for n = 1, where
    the moment of w about its own centroid is 0, another weight such as w²). ``window`` σ
    (position units): the moment of wm times exp(−r² / 2σ²) instead, so that weight far from
    the centroid, which rⁿ would magnify, does not drown the object's. Weights that are all 0
    read the image centre and (0, 0)."""
    tiny = torch.finfo(w.dtype).tiny
    mass = w.sum((1, 2)).clamp_min(tiny)  # (B,)
    cx = (w.sum(1) * xs).sum(1) / mass  # columns: x
    cy = (w.sum(2) * ys).sum(1) / mass  # rows: y
    rx = xs[None, None, :] - cx[:, None, None]  # (B, 1, W)
    ry = ys[None, :, None] - cy[:, None, None]  # (B, H, 1)
    re, im = rx.expand_as(w), ry.expand_as(w)
    pr, pi = re, im  # (rx + i ry)^n by repeated products
    for _ in range(order - 1):
        pr, pi = pr * re - pi * im, pr * im + pi * re
    if window is not None:
        wm = wm * torch.exp((re.square() + im.square()) / (-2 * window**2))
    mr, mi = (wm * pr).sum((1, 2)), (wm * pi).sum((1, 2))
    size = (wm * (re.square() + im.square()).pow(order / 2)).sum((1, 2))
    norm = torch.sqrt(mr.square() + mi.square() + (1e-6 * size).square() + tiny)
    return torch.stack([cx, cy, mr / norm, mi / norm], -1)


def angular_moments(w: torch.Tensor, xs: torch.Tensor, ys: torch.Tensor,
                    orders: tuple[int, ...] = (1, 2, 3, 4, 5, 6),
                    window: float | None = None, centre: torch.Tensor | None = None
                    ) -> torch.Tensor:
    """(B, len(orders)) complex: for each image's weights w (B, H, W) >= 0 and each order n
    the normalised angular moment Σ w' rⁿ e^{inφ} / Σ w' rⁿ about the centroid of w (or
    ``centre`` (B, 2), points (x, y)), of modulus at most 1: 1 for weight on n rays 2π / n
    apart, 0 for weight with no n-fold part (a disc: 0 for every n). w' = w for n >= 2 and
    w² for n = 1, as the encoders' moments, times the Gaussian ``window`` σ about the centre
    where given (:func:`moment_pose`)."""
    tiny = torch.finfo(w.dtype).tiny
    if centre is None:
        mass = w.sum((1, 2)).clamp_min(tiny)
        cx = (w.sum(1) * xs).sum(1) / mass
        cy = (w.sum(2) * ys).sum(1) / mass
    else:
        cx, cy = centre[:, 0], centre[:, 1]
    rx = (xs[None, None, :] - cx[:, None, None]).expand_as(w)
    ry = (ys[None, :, None] - cy[:, None, None]).expand_as(w)
    r, phi = torch.hypot(rx, ry), torch.atan2(ry, rx)
    g = torch.ones_like(r) if window is None else torch.exp(r.square() / (-2 * window**2))
    out = []
    for n in orders:
        rn = (w.square() if n == 1 else w) * g * r.pow(n)
        m = torch.complex((rn * torch.cos(n * phi)).sum((1, 2)),
                          (rn * torch.sin(n * phi)).sum((1, 2)))
        out.append(m / rn.sum((1, 2)).clamp_min(tiny))
    return torch.stack(out, -1)


def symmetry_order(w: torch.Tensor, xs: torch.Tensor, ys: torch.Tensor,
                   orders: tuple[int, ...] = (1, 2, 3, 4, 5, 6),
                   window: float | None = None, centre: torch.Tensor | None = None) -> int:
    """The order n among ``orders`` whose normalised angular moment
    (:func:`angular_moments`) turns most between the images' weights w (B, H, W): the mean
    modulus of its deviation from its mean over the images. An object's moment turns with
    it, where a fixed pattern's (a table's grain about the object) stays put; of an object
    seen at many orientations, its visible rotational symmetry 2π / n as far as the moments
    see it (4 for a square, 2 for an oblong)."""
    if not orders or min(orders) < 1:
        raise UserError(f"symmetry orders {orders}: give one or more orders >= 1")
    m = angular_moments(w, xs, ys, tuple(orders), window, centre)
    strength = (m - m.mean(0)).abs().mean(0)
    return int(orders[int(strength.argmax())])


class MaskMomentEncoder(_PoseFrame):
    """x (B, C, H, W) -> z (B, 4) = (x, y, cos nφ, sin nφ): the moments of a learned weight.

    :class:`MomentEncoder`'s latent, with a learned say in which pixels count. Each image is
    first standardised on its own (``mask_normalise``: its median subtracted, divided by its
    standard deviation), so a change of lighting is not a change of weight. A few 3×3
    convolutions (``mask_layers`` hidden ones of ``mask_channels`` maps, ReLU, the same size;
    then one map) and a sigmoid give a mask in (0, 1); a pixel's weight w is the mask times
    its deviation from the per-pixel median of the standardised training images
    (``mask_weight`` "background", :meth:`fit_statistics`), from its image's median ("image"),
    or the mask alone ("mask"): the mask chooses which pixels are the object, the image keeps
    their shape. The centroid of w is moved ``mask_refine`` times (mean shift) to the
    centroid of the image's own deviation in a Gaussian window of σ = ``mask_window`` pixels
    about it; the latent is that centre and the direction of the deviation's n-th angular
    moment (n = ``moment_order``) in the window (:func:`moment_pose`): the mask says where
    the object is, the image what shape it has, and what lies far from the object does not
    turn it (``mask_refine`` 0: the centroid and moment of w itself). The convolutions see
    every position alike, so what they learn to weigh moves with the object.

    Trained by the autoencoder's reconstruction through the sprite decoder (no pose labels);
    :meth:`symmetry_order` of a trained encoder on training images chooses n from the data.
    Measured (RESULTS.md, "A learned object mask for the moments"): in the textured world
    it reads the block's position where the moments encoder cannot.
    """

    def __init__(self, cfg: parts.MaskMomentEncoderConfig, shape: ImageShape,
                 latent_dim: int = 4) -> None:
        super().__init__(cfg, shape, latent_dim)
        self.normalise = cfg.normalise
        self.kind = cfg.weight
        self.window_pixels = cfg.window
        self.refine = cfg.refine
        c = shape[0]
        layers = []
        width = cfg.channels
        for _ in range(cfg.layers):
            layers += [nn.Conv2d(c, width, 3, padding=1), nn.ReLU()]
            c = width
        layers.append(nn.Conv2d(c, 1, 3, padding=1))
        self.net = nn.Sequential(*layers)

    @property
    def window(self) -> float | None:
        """σ of the angular moment's window in position units (None: no window)."""
        return self.window_pixels * self.pixel if self.window_pixels > 0 else None

    @torch.no_grad()
    def symmetry_order(self, x: torch.Tensor, orders: tuple[int, ...] = (1, 2, 3, 4, 5, 6),
                       steps: int = 3) -> int:
        """The visible symmetry order n of the object this encoder finds in images
        x (B, C, H, W): :func:`symmetry_order` of the images' own deviation (from the
        background or their median, as ``mask_weight``; the mask for "mask") in the window
        about its centre: the masked weights' centroid moved ``steps`` times to the centroid
        of the deviation in the window there. The mask only places the window: its own
        shape, trained at some order, could favour that order."""
        d = self._deviation(x)
        c = self._shifted(d, self._centroid(self.weights(x)), steps)
        return symmetry_order(d, self.xs, self.ys, orders, self.window, c)

    def _deviation(self, x: torch.Tensor) -> torch.Tensor:
        """The images' own deviation (B, H, W) that ``mask_weight`` names, without the mask
        (the mask itself for "mask")."""
        if self.kind == "mask":
            return self.weights(x)
        s = self._standardised(x)
        ref = self.background if self.kind == "background" else (
            s.flatten(1).median(1).values[:, None, None, None])
        return (s - ref).abs().sum(1)

    def _centroid(self, w: torch.Tensor) -> torch.Tensor:
        mass = w.sum((1, 2)).clamp_min(torch.finfo(w.dtype).tiny)
        return torch.stack([(w.sum(1) * self.xs).sum(1) / mass,
                            (w.sum(2) * self.ys).sum(1) / mass], -1)

    def _shifted(self, d: torch.Tensor, c: torch.Tensor, steps: int) -> torch.Tensor:
        """The centre c (B, 2) moved ``steps`` times to the centroid of d in the window
        about it (mean shift)."""
        for _ in range(steps):
            c = self._centroid(self._windowed(d, c))
        return c

    def _windowed(self, d: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
        """d (B, H, W) times the Gaussian window about each centre c (B, 2)."""
        window = self.window if self.window is not None else float("inf")
        r2 = ((self.xs[None, None, :] - c[:, 0, None, None]).square()
              + (self.ys[None, :, None] - c[:, 1, None, None]).square())
        return d * torch.exp(r2 / (-2 * window**2))

    @torch.no_grad()
    def fit_statistics(self, frames: torch.Tensor) -> None:
        """Set the background from normalised training images (N, C, H, W): the per-pixel
        median of the images as the encoder sees them (standardised each on its own where
        ``mask_normalise``)."""
        self.background.copy_(median_background(self._standardised(frames),
                                                self.background.shape))

    def _standardised(self, x: torch.Tensor) -> torch.Tensor:
        if not self.normalise:
            return x
        flat = x.flatten(1)
        median = flat.median(1, keepdim=True).values
        return ((flat - median) / (flat.std(1, keepdim=True) + 1e-6)).view_as(x)

    def weights(self, x: torch.Tensor) -> torch.Tensor:
        """The per-pixel weights w (B, H, W) >= 0 of images x (B, C, H, W): the learned mask,
        times the deviation that ``mask_weight`` names."""
        x = self._standardised(x)
        mask = torch.sigmoid(self.net(x))[:, 0]  # (B, H, W)
        if self.kind == "mask":
            return mask
        ref = self.background if self.kind == "background" else (
            x.flatten(1).median(1).values[:, None, None, None])
        return mask * (x - ref).abs().sum(1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        w = self.weights(x)
        if self.refine:  # the mask places the window; the object's own pixels give the pose
            d = self._deviation(x)
            c = self._shifted(d, self._centroid(w), self.refine)
            w = self._windowed(d, c)  # its centroid: one more step
            return moment_pose(w, d.square() if self.order == 1 else d, self.xs, self.ys,
                               self.order, self.window)
        return moment_pose(w, w.square() if self.order == 1 else w, self.xs, self.ys,
                           self.order, self.window)
