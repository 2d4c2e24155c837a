"""The sprite decoder: the moments encoder's inverse, a learned template drawn at the pose."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from latent_sindy.cli import main
from latent_sindy.data import write_sequences
from latent_sindy.data.windows import Normalizer
from latent_sindy.errors import UserError
from latent_sindy.models import AutoencoderConfig
from latent_sindy.models.autoencoder import SpriteDecoder
from latent_sindy.training import RunDir
from synthetic import make_trajectories
from test_moments import SIDE, TABLE, draw, poses

PIXEL = 2 / (SIDE - 1)  # one pixel in image coordinates


def sprite(order: int = 4, supersample: int = 2, size: int = 11):
    cfg = AutoencoderConfig(channels=1, image_size=SIDE, latent_dim=4, encoder_kind="moments",
                            decoder_kind="sprite", moment_order=order, sprite_size=size,
                            sprite_supersample=supersample)
    return cfg.build()


def square(size: int = 11, half: int = 2, marked: bool = False) -> torch.Tensor:
    """A (1, P, P) template: a (2·half + 1)-pixel square of −7 at the centre; ``marked``:
    its +x half darker (−12), so its first angular moment has an angle."""
    t = torch.zeros(1, size, size)
    c = size // 2
    t[0, c - half:c + half + 1, c - half:c + half + 1] = -7.0
    if marked:
        t[0, c - half:c + half + 1, c + 1:c + half + 1] = -12.0
    return t


def random_latents(n: int, order: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    xy = (torch.rand(n, 2, generator=g) * 2 - 1) * 0.6
    phi = (torch.rand(n, generator=g) * 2 - 1) * math.pi
    return torch.stack([xy[:, 0], xy[:, 1], torch.cos(order * phi), torch.sin(order * phi)], -1)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize(("order", "supersample"), [(4, 1), (4, 2), (1, 2)])
def test_the_decoder_draws_the_template_where_the_latent_says(order, supersample,
                                                              dtype) -> None:
    """encode(decode(z)) is z: the drawn square's centroid is (x, y) to a small fraction of
    a pixel (the marked square's, a fixed distance from it), and its n-th angular moment
    turns with the latent's angle (up to one constant phase, the template's own offset from
    the moment's frame)."""
    ae = sprite(order, supersample).to(dtype)
    ae.decoder.set_template(square(marked=order == 1).to(dtype))
    z = random_latents(40, order).to(dtype)
    with torch.no_grad():
        back = ae.encode(ae.decode(z))
    assert back.dtype == dtype
    err_px = ((back[:, :2] - z[:, :2]).norm(dim=-1) / PIXEL).double()
    # Drawn at the image's resolution, bilinear sampling moves the mass a little as the
    # square turns; at twice the resolution far less (measured: max 0.06 and 0.007 pixel)
    if order == 1:  # the mark moves the centroid off the centre, the same for every pose
        err_px = err_px - err_px.mean()
    assert err_px.abs().max() < (0.1 if supersample == 1 else 0.02), err_px
    read = torch.atan2(back[:, 3], back[:, 2]).double()
    true = torch.atan2(z[:, 3], z[:, 2]).double()
    d = torch.polar(torch.ones_like(read), read - true)
    residual = torch.angle(d * d.mean().conj()).abs() / order  # minus the mean phase
    # the marked square's first moment (of squared differences) reads less exactly, as
    # from real drawings (test_moments)
    mean, worst = (1.0, 2.5) if order == 4 else (2.0, 7.0)
    deg = np.degrees(residual.numpy())
    assert deg.mean() < mean and deg.max() < worst, (deg.mean(), deg.max())


def test_leading_dimensions_and_an_unseen_block_decode_alike() -> None:
    ae = sprite()
    ae.decoder.set_template(square())
    ae.decoder.background.fill_(0.5)
    z = random_latents(12, 4).reshape(3, 4, 4)
    with torch.no_grad():
        out = ae.decode(z)
        assert out.shape == (3, 4, 1, SIDE, SIDE)
        assert torch.allclose(out.reshape(12, 1, SIDE, SIDE), ae.decode(z.reshape(12, 4)))
        # a latent with no orientation (what the encoder reads from the empty table) draws
        # the template unturned, and the angle's gradient there is finite
    z0 = torch.zeros(1, 4, requires_grad=True)
    ae.decode(z0).sum().backward()
    assert torch.isfinite(z0.grad).all()


def test_the_template_learns_a_drawn_block() -> None:
    """A few hundred Adam steps on the template alone (the pose is the encoder's, nothing
    learned) reconstruct images of a square at random poses far better than the background
    alone, from a zero template."""
    torch.manual_seed(0)
    p = poses(48, seed=3)
    images = torch.tensor(np.stack([draw(*q) for q in p]))[:, None]
    images = ((images - TABLE) / 12.0).float()
    ae = sprite()
    ae.fit_statistics(images)
    assert torch.equal(ae.decoder.background, ae.encoder.background)
    with torch.no_grad():
        z = ae.encode(images)
        background_mse = float((ae.decode(z) - images).square().mean())
    opt = torch.optim.Adam(ae.decoder.parameters(), lr=1e-2)
    for _ in range(300):
        opt.zero_grad()
        loss = (ae.decode(z) - images).square().mean()
        loss.backward()
        opt.step()
    with torch.no_grad():
        mse = float((ae.decode(z) - images).square().mean())
    assert mse < 0.01 * background_mse, (mse, background_mse)
    assert float(ae.decoder.template.detach().min()) < -4  # the block darkens the table


def test_the_sprite_decoder_needs_the_moments_encoder_and_an_odd_patch() -> None:
    for encoder in ("conv", "keypoints"):
        with pytest.raises(UserError, match=r"sprite decoder.*--encoder moments"):
            AutoencoderConfig(encoder_kind=encoder, latent_dim=4, decoder_kind="sprite")
    for size in (0, 10, 33):
        with pytest.raises(UserError, match="sprite_size"):
            AutoencoderConfig(encoder_kind="moments", latent_dim=4, decoder_kind="sprite",
                              image_size=SIDE, sprite_size=size)
    with pytest.raises(UserError, match="sprite_supersample"):
        AutoencoderConfig(encoder_kind="moments", latent_dim=4, decoder_kind="sprite",
                          sprite_supersample=0)
    with pytest.raises(UserError, match="unknown"):
        AutoencoderConfig(decoder_kind="sprites")


def test_training_with_decoder_sprite_keeps_the_background_and_the_template(
        tmp_path: Path) -> None:
    """`--decoder sprite` trains; the saved model holds the training split's median image as
    the decoder's background (as the encoder's) and the trained template, and a state dict
    round trip restores both."""
    d = make_trajectories(n=6, steps=3)
    data = tmp_path / "d.h5"
    write_sequences(data, d)
    out = tmp_path / "run"
    assert main(["train", "sindy", "--order", "1", "--library", "face", "--no-include-sine",
                 "--data", str(data), "--epochs", "2", "--batch-size", "4", "--no-progress",
                 "--out", str(out), "image", "--encoder", "moments", "--latent-dim", "4",
                 "--decoder", "sprite", "--sprite-size", "9"]) == 0
    model = RunDir(out).load().model
    norm = Normalizer.from_trajectories(d)
    train_frames = norm.normalize(d.split("train").images).reshape(-1, 1, SIDE, SIDE)
    dec = model.autoencoder.decoder
    assert dec.template.shape == (1, 9, 9)
    assert torch.allclose(dec.background, train_frames.median(0).values)
    assert dec.template.abs().max() > 0  # trained away from its zero start
    path = tmp_path / "ae.pt"
    torch.save(model.autoencoder.state_dict(), path)
    fresh = model.autoencoder.config.build()
    fresh.load_state_dict(torch.load(path))
    assert torch.equal(fresh.decoder.background, dec.background)
    assert torch.equal(fresh.decoder.template, dec.template)


def test_sprite_side_follows_the_image_side_unless_given():
    """A resolved config states the template's side: 11 at 32 pixels, 23 at 64, or the one
    given; the decoder's template has it."""
    base = AutoencoderConfig(encoder_kind="moments", latent_dim=4, decoder_kind="sprite")
    assert base.resolve(1, 32).sprite_size == 11
    assert base.resolve(1, 64).sprite_size == 23
    assert base.resolve(1, 16).sprite_size == 5
    given = dataclasses.replace(base, sprite_size=7).resolve(1, 64)
    assert given.sprite_size == 7
    big = base.resolve(1, 64)
    assert SpriteDecoder(big.decoder_part(), big.image_shape).template.shape == (1, 23, 23)


def test_on_a_non_square_image_moments_and_sprite_share_isotropic_coordinates() -> None:
    """On 24 x 40 images a pixel is 2 / 39 wide in x and in y (the longer side runs from -1
    to 1), so a pixel's moments read its place, and encode(decode(z)) is z as on squares."""
    cfg = AutoencoderConfig(channels=1, image_size=(24, 40), latent_dim=4,
                            encoder_kind="moments", decoder_kind="sprite", sprite_size=11)
    ae = cfg.build()
    x = torch.zeros(1, 1, 24, 40)
    x[0, 0, 3, 30] = 1.0
    with torch.no_grad():
        z = ae.encode(x)[0]
    torch.testing.assert_close(z[:2], torch.tensor([10.5 * 2 / 39, -8.5 * 2 / 39]))
    ae.decoder.set_template(square())
    g = torch.Generator().manual_seed(0)
    xy = (torch.rand(30, 2, generator=g) * 2 - 1) * torch.tensor([0.6, 0.3])
    phi = (torch.rand(30, generator=g) * 2 - 1) * math.pi
    z = torch.stack([xy[:, 0], xy[:, 1], torch.cos(4 * phi), torch.sin(4 * phi)], -1)
    with torch.no_grad():
        back = ae.encode(ae.decode(z))
    err_px = (back[:, :2] - z[:, :2]).norm(dim=-1) / (2 / 39)
    assert err_px.max() < 0.02, err_px
    turn = torch.polar(torch.ones(30), torch.atan2(back[:, 3], back[:, 2])
                       - torch.atan2(z[:, 3], z[:, 2]))
    residual = torch.angle(turn * turn.mean().conj()).abs() / 4  # minus the mean phase
    assert math.degrees(float(residual.max())) < 2.5
