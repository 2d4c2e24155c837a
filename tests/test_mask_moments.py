"""The learned-mask moments encoder ("mask_moments"): its latent follows an object, its window
keeps far weight out of the orientation, training by reconstruction teaches it which object
counts, and the order chooser finds an object's visible symmetry."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from latent_sindy.errors import UserError
from latent_sindy.models import AutoencoderConfig
from latent_sindy.models.autoencoder import Autoencoder
from latent_sindy.models.encoders import (
    MaskMomentEncoder,
    image_coordinates,
    moment_pose,
    symmetry_order,
)

TABLE, BLOCK, SIDE = 191.0, 107.0, 32


def draw(px: float, py: float, theta: float, half: tuple[float, float] = (2.5, 2.5),
         disc: tuple[float, float] | None = None, supersample: int = 4) -> np.ndarray:
    """A rectangle of half sides ``half`` (pixels) centred at (px, py) (x right, y down),
    turned by theta, on the table, area-averaged; ``disc``: also a dark disc of radius 1.5
    there."""
    n = SIDE * supersample
    c = (np.arange(n) + 0.5) / supersample
    x, y = np.meshgrid(c, c)
    u = (x - px) * math.cos(theta) + (y - py) * math.sin(theta)
    v = -(x - px) * math.sin(theta) + (y - py) * math.cos(theta)
    img = np.full((n, n), TABLE)
    img[(np.abs(u) <= half[0]) & (np.abs(v) <= half[1])] = BLOCK
    if disc is not None:
        img[np.hypot(x - disc[0], y - disc[1]) <= 1.5] = 60.0
    return img.reshape(SIDE, supersample, SIDE, supersample).mean((1, 3))


def images(poses: np.ndarray, **kw) -> torch.Tensor:
    """Normalised drawings (N, 1, S, S) of poses (N, 3) in pixels."""
    x = torch.tensor(np.stack([draw(*p, **kw) for p in poses]))[:, None]
    return ((x - TABLE) / 12.0).float()


def poses(n: int, seed: int, low: float = 8, high: float = 24) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.c_[rng.uniform(low, high, (n, 2)), rng.uniform(-math.pi, math.pi, n)]


def config(**kw) -> AutoencoderConfig:
    return AutoencoderConfig(**{"channels": 1, "image_size": SIDE, "latent_dim": 4,
                                "encoder_kind": "mask_moments", "decoder_kind": "sprite", **kw})


def mask_encoder(**kw) -> MaskMomentEncoder:
    cfg = config(**kw)
    return MaskMomentEncoder(cfg.encoder_part(), cfg.image_shape)


def half_mask(enc: MaskMomentEncoder) -> MaskMomentEncoder:
    """The encoder with a mask of 0.5 everywhere (last convolution zero)."""
    with torch.no_grad():
        enc.net[-1].weight.zero_()
        enc.net[-1].bias.zero_()
    return enc


def to_pixels(z: torch.Tensor) -> np.ndarray:
    """Latent positions (..., 2) in [-1, 1] -> pixel centres' units (x right, y down)."""
    return (z.numpy() + 1) * (SIDE - 1) / 2 + 0.5


def test_the_latent_follows_a_square_moved_and_turned() -> None:
    """With a uniform mask the weight is the drawing's difference from the training
    background, so the centroid is the square's centre and the 4th moment turns 4 times as
    fast as the square (one constant offset, as the moments encoder's)."""
    p = poses(40, seed=1)
    x = images(p)
    torch.manual_seed(0)
    enc = half_mask(mask_encoder())
    enc.fit_statistics(x)
    with torch.no_grad():
        z = enc(x)
    assert np.abs(to_pixels(z[:, :2]) - p[:, :2]).max() < 0.1
    d = np.arctan2(z[:, 3].numpy(), z[:, 2].numpy()) - 4 * p[:, 2]
    offset = np.angle(np.exp(1j * d).mean())
    err = np.abs(np.angle(np.exp(1j * (d - offset)))) / 4
    assert np.degrees(err).mean() < 2.0


def test_the_refined_pose_is_the_objects_wherever_the_mask_puts_its_weight() -> None:
    """A mask that has drifted to a blob beside the square: its own centroid and moment are
    off, the centre moved by mean shift onto the square's own pixels is not (mask_refine)."""
    p = poses(40, seed=2)
    x = images(p)
    torch.manual_seed(0)
    errors = {}
    for steps in (0, 3):
        enc = half_mask(mask_encoder(mask_refine=steps))
        enc.fit_statistics(x)
        offsets = torch.tensor(p[:, :2] + 1.5)  # a blob 1.5 pixels down and right

        def blob(images: torch.Tensor, enc=enc, offsets=offsets) -> torch.Tensor:
            centres = (offsets - 0.5) * 2 / (SIDE - 1) - 1  # pixels -> latent units
            r2 = ((enc.xs[None, None, :] - centres[:, 0, None, None]).square()
                  + (enc.ys[None, :, None] - centres[:, 1, None, None]).square())
            return torch.exp(-r2 / (2 * (1.5 * enc.pixel) ** 2)).float()

        enc.weights = blob
        with torch.no_grad():
            z = enc(x)
        d = np.arctan2(z[:, 3].numpy(), z[:, 2].numpy()) - 4 * p[:, 2]
        spread = np.abs(np.angle(np.exp(1j * (d - np.angle(np.exp(1j * d).mean()))))) / 4
        errors[steps] = (np.abs(to_pixels(z[:, :2]) - p[:, :2]).max(),
                         np.degrees(spread).mean())
    assert errors[0][0] > 1.0 and errors[0][1] > 10
    assert errors[3][0] < 0.15 and errors[3][1] < 2.0


def test_the_window_keeps_far_weight_out_of_the_orientation() -> None:
    """A faint speck far from the square barely moves the centroid, but its weight times
    r⁴ turns the whole-image moment; the window's moment does not turn."""
    xs, ys = image_coordinates(SIDE, SIDE)
    w = torch.tensor(draw(16, 16, 0.3) - TABLE).abs()[None].float()
    speck = w.clone()
    speck[0, 2, 2] += 0.3 * float(w.max())
    pixel = float(xs[1] - xs[0])

    def angle(weights: torch.Tensor, window: float | None) -> float:
        z = moment_pose(weights, weights, xs, ys, 4, window)[0]
        return float(torch.atan2(z[3], z[2]))

    def turn(window: float | None) -> float:
        return abs(math.remainder(angle(speck, window) - angle(w, window), 2 * math.pi))

    assert turn(None) > 0.5
    assert turn(3 * pixel) < 0.02


@pytest.mark.parametrize(("half", "order"), [((2.5, 2.5), 4), ((4.0, 2.0), 2)])
def test_the_order_chooser_finds_the_visible_symmetry(half, order) -> None:
    """A square looks alike every quarter turn (n = 4), a 2:1 oblong every half turn (2)."""
    xs, ys = image_coordinates(SIDE, SIDE)
    w = torch.tensor(np.stack([TABLE - draw(*p, half=half) for p in poses(30, seed=2)])).float()
    assert symmetry_order(w, xs, ys) == order
    assert symmetry_order(w, xs, ys, window=3 * float(xs[1] - xs[0])) == order
    with pytest.raises(UserError, match="symmetry orders"):
        symmetry_order(w, xs, ys, orders=(0, 4))
    # the encoder's own chooser, on drawings, whatever order it is set to
    x = images(poses(30, seed=2), half=half)
    torch.manual_seed(0)
    enc = mask_encoder(moment_order=6 - order)
    enc.fit_statistics(x)
    assert enc.symmetry_order(x) == order


def test_training_by_reconstruction_learns_to_leave_out_a_distractor() -> None:
    """Every image holds the square and a darker disc elsewhere; only the square is drawn by
    the sprite decoder's one template at the latent's pose... and the disc is not at a fixed
    place, so the reconstruction is best with the centroid on the square: a brief training
    takes the centroid from between the two to the square."""
    rng = np.random.default_rng(3)
    p = np.c_[rng.uniform(8, 24, (64, 2)), rng.uniform(-math.pi, math.pi, 64)]
    discs = rng.uniform(4, 28, (64, 2))
    far = np.linalg.norm(discs - p[:, :2], axis=1) > 8
    p, discs = p[far], discs[far]
    x = torch.cat([images(q[None], disc=tuple(d)) for q, d in zip(p, discs, strict=True)])
    torch.manual_seed(0)
    ae = Autoencoder(config(moment_order=4, mask_refine=0))  # (the mask's own pose)
    ae.fit_statistics(x)

    def error() -> float:
        with torch.no_grad():
            return float(np.linalg.norm(to_pixels(ae.encode(x)[:, :2]) - p[:, :2], axis=1)
                         .mean())

    before = error()
    opt = torch.optim.Adam(ae.parameters(), lr=1e-2)
    for _ in range(60):
        opt.zero_grad()
        loss = (ae(x) - x).square().mean()
        loss.backward()
        opt.step()
    assert before > 1.5
    assert error() < 0.5 * before


def test_the_encoder_is_part_of_the_autoencoder_and_its_state() -> None:
    ae = Autoencoder(config(mask_channels=4, mask_layers=2))
    x = images(poses(8, seed=4))
    ae.fit_statistics(x)
    enc = ae.encoder
    assert isinstance(enc, MaskMomentEncoder) and enc.background.abs().sum() > 0
    assert "encoder.background" in ae.state_dict()
    assert ae.encode(x).shape == (8, 4) and ae(x).shape == x.shape
    assert ae.config.pose_latent and not ae.config.fixed_encoder
    z = ae.encode(x)
    assert torch.allclose(z[:, 2:].norm(dim=1), torch.ones(8), atol=1e-4)


@pytest.mark.parametrize(("kw", "match"), [
    ({"latent_dim": 8}, "--latent-dim 4"),
    ({"moment_order": -1}, "--moment-order >= 1, or 0 to choose it"),
    ({"mask_channels": 0}, "--mask-channels 0"),
    ({"mask_layers": 0}, "--mask-layers 0"),
    ({"mask_window": -1.0}, "--mask-window -1.0"),
    ({"mask_window": float("nan")}, "--mask-window nan"),
    ({"mask_weight": "edges"}, "--mask-weight 'edges'"),
    ({"mask_refine": -1}, "--mask-refine -1"),
    ({"mask_refine": 2, "mask_window": 0.0}, "a window > 0"),
])
def test_bad_settings_name_the_value_and_the_fix(kw, match) -> None:
    with pytest.raises(UserError, match=match):
        config(**kw)


def test_the_sprite_decoder_names_both_moments_encoders() -> None:
    with pytest.raises(UserError, match="--encoder moments or mask_moments"):
        AutoencoderConfig(encoder_kind="conv", decoder_kind="sprite", latent_dim=4)
