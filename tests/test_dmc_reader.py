"""The cart-pole pose read by image moments (the dmc world's ColourPoseReader), on drawn
frames: no dm-control needed."""

from __future__ import annotations

import math

import pytest
import torch

from latent_sindy.errors import UserError
from latent_sindy.worlds.dmc.reader import ColourPoseReader

BACKGROUND, BODY = (0.30, 0.40, 0.55), (0.85, 0.35, 0.20)


def _draw(x: float, phi: float, size: int = 64, pole: float = 0.45, cart=(0.25, 0.125),
          y: float = 0.1, supersample: int = 4, pivot: float = 1.0) -> torch.Tensor:
    """(3, size, size) float frame: a cart (a box centred at (x, y), image coordinates) and
    a pole of length ``pole`` from (pivot·x, y) towards angle φ (from x towards y): pivot < 1
    as a camera sees a pole hinged behind the cart's face."""
    n = size * supersample
    c = (torch.arange(n, dtype=torch.float64) + 0.5) / n * 2 * size / (size - 1) - size / (
        size - 1)  # sub-pixel centres on the pixel-centre scale of image_coordinates
    gy, gx = torch.meshgrid(c, c, indexing="ij")
    in_cart = ((gx - x).abs() < cart[0] / 2) & ((gy - y).abs() < cart[1] / 2)
    along = (gx - pivot * x) * math.cos(phi) + (gy - y) * math.sin(phi)
    across = -(gx - pivot * x) * math.sin(phi) + (gy - y) * math.cos(phi)
    in_pole = (along > 0) & (along < pole) & (across.abs() < 0.025)
    cover = (in_cart | in_pole).double().reshape(size, supersample, size, supersample)
    cover = cover.mean((1, 3))
    bg = torch.tensor(BACKGROUND, dtype=torch.float64)[:, None, None]
    body = torch.tensor(BODY, dtype=torch.float64)[:, None, None]
    shade = 1 + 0.1 * torch.linspace(-1, 1, size, dtype=torch.float64)[None, :, None]
    return (bg * shade * (1 - cover) + body * cover).float()


def _poses(n: int, seed: int):
    g = torch.Generator().manual_seed(seed)
    xs = (torch.rand(n, generator=g) * 1.2 - 0.6).tolist()
    phis = (torch.rand(n, generator=g) * 2 * math.pi).tolist()
    return xs, phis


def _training() -> torch.Tensor:
    frames = torch.stack([_draw(x, p) for x, p in zip(*_poses(120, 0), strict=True)])
    return (frames * 255).round().to(torch.uint8)


@pytest.fixture(scope="module")
def fitted():
    return ColourPoseReader(64).fit(_training())


@pytest.mark.parametrize("size", [64, 128])
def test_the_cart_and_the_pole_are_read_within_a_pixel_and_a_few_degrees(size, fitted):
    reader = fitted if size == 64 else ColourPoseReader(size).fit(torch.stack(
        [_draw(x, p, size) for x, p in zip(*_poses(120, 0), strict=True)]))
    xs, phis = _poses(40, 1)
    pose, seen = reader.read(torch.stack([_draw(x, p, size) for x, p in zip(xs, phis,
                                                                            strict=True)]))
    assert bool(seen.all())
    pixel = 2 / 63  # a pixel of a 64×64 frame
    x_error = (pose[:, 0] - torch.tensor(xs, dtype=torch.float64)).abs() / pixel
    angle = torch.atan2(pose[:, 3], pose[:, 2])
    angle_error = torch.rad2deg((angle - torch.tensor(phis, dtype=torch.float64) + math.pi)
                                % (2 * math.pi) - math.pi).abs()
    # (the mode is the cart pulled a little towards the pole: within a pixel)
    assert float(x_error.median()) < 1 and float(x_error.max()) < 1.5, x_error
    assert float(angle_error.median()) < 2 and float(angle_error.max()) < 6, angle_error
    assert torch.allclose(pose[:, 2:].norm(dim=1), torch.ones(40, dtype=torch.float64),
                          atol=1e-12)


def test_the_body_box_reads_the_angle_nearer_than_the_mode(fitted):
    # (the mode is pulled towards the pole, and so turns the angle read from it)
    frames = torch.stack([_draw(x, p) for x, p in zip(*_poses(120, 0), strict=True)])
    xs, phis = _poses(40, 1)
    test = torch.stack([_draw(x, p) for x, p in zip(xs, phis, strict=True)])
    errors = {}
    for body in (None, (4.0, 2.0)):
        pose, _ = ColourPoseReader(64, body=body, edges=False).fit(frames).read(test)
        errors[body] = _angle_errors(pose, phis)
    assert float(errors[(4.0, 2.0)].median()) < 0.8 * float(errors[None].median()), errors
    assert float(errors[(4.0, 2.0)].max()) < 0.8 * float(errors[None].max()), errors
    with pytest.raises(UserError, match="body"):
        ColourPoseReader(64, body=(4.0,))


def _angle_errors(pose: torch.Tensor, phis: list[float]) -> torch.Tensor:
    angle = torch.atan2(pose[:, 3], pose[:, 2])
    return torch.rad2deg((angle - torch.tensor(phis, dtype=torch.float64) + math.pi)
                         % (2 * math.pi) - math.pi).abs()


def test_the_edges_place_the_cart_within_a_tenth_of_a_pixel_and_find_a_pivot_behind_it():
    # a pole hinged behind the cart's face moves 0.9 times as far across the image
    xs0, phis0 = _poses(160, 2)
    frames = torch.stack([_draw(x, p, pivot=0.9) for x, p in zip(xs0, phis0, strict=True)])
    xs, phis = _poses(40, 3)
    test = torch.stack([_draw(x, p, pivot=0.9) for x, p in zip(xs, phis, strict=True)])
    pixel = 2 / 63
    read = {}
    for edges in (False, True):
        reader = ColourPoseReader(64, edges=edges).fit(frames)
        pose, seen = reader.read(test)
        x_error = (pose[:, 0] - torch.tensor(xs, dtype=torch.float64)).abs()[seen] / pixel
        read[edges] = x_error, _angle_errors(pose, phis)[seen], reader
    x_error, angle_error, reader = read[True]
    assert abs(reader.pivot[0] - 0.9) < 0.02 and abs(reader.pivot[1]) < 0.3 * pixel, \
        reader.pivot
    assert float(x_error.median()) < 0.1 and float(x_error.max()) < 0.4, x_error
    assert float(x_error.median()) < 0.5 * float(read[False][0].median()), read
    assert float(angle_error.median()) < 0.5 * float(read[False][1].median()), read
    assert len(angle_error) >= 30  # a horizontal pole across the cart may hide its edges


def test_a_frame_without_the_cart_in_view_is_not_seen(fitted):
    # the last: the cart beyond the frame's edge, the pole reaching into it
    frames = torch.stack([_draw(0.2, 1.0), _draw(0.85, 1.0), _draw(3.0, 1.0),
                          _draw(1.15, math.pi + 0.3, pole=0.7)])
    _, seen = fitted.read(frames)
    assert seen.tolist() == [True, False, False, False]
    _, seen = ColourPoseReader(64, edge=1.0).fit(_training()).read(frames)
    assert seen.tolist() == [True, True, False, False]


def test_two_frames_give_the_turn_and_the_cart_speed_and_the_action():
    reader = ColourPoseReader(64).fit(torch.stack(
        [_draw(x, p) for x, p in zip(*_poses(120, 0), strict=True)]))
    dt = 0.08
    obs = torch.cat([_draw(0.10, 0.3), _draw(0.16, 0.5)])[None]  # (1, 6, 64, 64)
    z, seen = reader.latent(obs, torch.tensor([[0.7]], dtype=torch.float64), dt)
    assert z.shape == (1, 6) and z.dtype == torch.float64 and bool(seen[0])
    assert float(z[0, 3]) == pytest.approx(0.06 / dt, rel=0.15)
    assert float(z[0, 4]) == pytest.approx(0.2 / dt, rel=0.15)
    assert float(z[0, 5]) == 0.7
    images = torch.stack([torch.cat([_draw(0.1 * t, 0.2 * t), _draw(0.1 * t + 0.05,
                                                                    0.2 * t + 0.1)])
                          for t in range(3)])
    Z, seen = reader.episode(images, torch.tensor([[0.1], [0.2]], dtype=torch.float64), dt)
    single, _ = reader.latent(images[:1], torch.zeros(1, 1), dt)
    assert Z.shape == (3, 6) and Z[:, 5].tolist() == [0.0, 0.1, 0.2]
    assert torch.allclose(Z[0], single[0])
    # row 1: its current frame (φ 0.3) against row 0's current frame (φ 0.1), not its own stack's
    assert float(Z[1, 4]) == pytest.approx((0.3 - 0.1) / dt, rel=0.15)


def test_bad_frames_raise_user_errors(fitted):
    with pytest.raises(UserError, match="before fit"):
        ColourPoseReader(64).read(torch.zeros(1, 3, 64, 64))
    with pytest.raises(UserError, match=r"\(B, 3, H, W\)"):
        fitted.read(torch.zeros(2, 64, 64))
    with pytest.raises(UserError, match="32, 32"):
        fitted.read(torch.zeros(1, 3, 32, 32))
    with pytest.raises(UserError, match="do not differ"):
        ColourPoseReader(64).fit(torch.zeros(5, 3, 64, 64))
    with pytest.raises(UserError, match="size"):
        ColourPoseReader(4)
    with pytest.raises(UserError, match="two stacked"):
        fitted.latent(torch.zeros(1, 3, 64, 64), torch.zeros(1, 1), 0.1)


def test_frames_that_hide_the_cart_in_the_background_fall_back_to_its_box():
    # the cart in one place in most frames: the median background holds it, its edges do not
    # show, and the reader reads the box's centroid rather than seeing almost nothing
    xs, phis = _poses(40, 4)
    frames = torch.stack([_draw(0.0, p) for p in phis] + [_draw(x, p) for x, p in zip(
        xs[:10], phis[:10], strict=True)])
    reader = ColourPoseReader(64).fit(frames)
    assert not reader.found_edges
    _, seen = reader.read(frames)
    assert float(seen.double().mean()) > 0.5
    assert ColourPoseReader(64).fit(_training()).found_edges
