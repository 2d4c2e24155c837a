"""The moments encoder: the block's pose read from an image without learning or simulator data."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from latent_sindy.cli import main
from latent_sindy.data import write_sequences
from latent_sindy.data.windows import Normalizer
from latent_sindy.errors import UserError
from latent_sindy.models import AutoencoderConfig, ModelConfig, SindyConfig
from latent_sindy.training import RunDir
from synthetic import make_trajectories

TABLE, BLOCK, MARK, SIDE = 191.0, 107.0, 60.0, 32


def draw(px: float, py: float, theta: float, half: float = 2.5, marked: bool = False,
         supersample: int = 8) -> np.ndarray:
    """A square of side 2·half pixels centred at (px, py) (pixel units, x right, y down,
    pixel j spanning [j, j + 1]), turned by theta from the x axis toward y, on the table;
    area-averaged from a supersampled drawing. ``marked``: its +x half (in the block's
    frame) is darker."""
    n = SIDE * supersample
    c = (np.arange(n) + 0.5) / supersample
    x, y = np.meshgrid(c, c)  # x: columns, y: rows
    u = (x - px) * math.cos(theta) + (y - py) * math.sin(theta)  # block frame
    v = -(x - px) * math.sin(theta) + (y - py) * math.cos(theta)
    inside = (np.abs(u) <= half) & (np.abs(v) <= half)
    img = np.full((n, n), TABLE)
    img[inside] = BLOCK
    if marked:
        img[inside & (u > 0)] = MARK
    return img.reshape(SIDE, supersample, SIDE, supersample).mean((1, 3))


def encoder(order: int = 4):
    from latent_sindy.models.autoencoder import MomentEncoder

    cfg = AutoencoderConfig(channels=1, image_size=SIDE, latent_dim=4, encoder_kind="moments",
                            moment_order=order)
    return MomentEncoder(cfg.encoder_part(), cfg.image_shape)


def poses(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.c_[rng.uniform(6, 26, (n, 2)), rng.uniform(-math.pi, math.pi, n)]


def fitted(order: int, marked: bool = False, n: int = 60):
    """An encoder whose background is fitted on n random drawings; (encoder, poses, images)."""
    p = poses(n, seed=order)
    images = torch.tensor(np.stack([draw(*q, marked=marked) for q in p]))[:, None]
    images = ((images - TABLE) / 12.0).float()  # normalised as the data pipeline does
    enc = encoder(order)
    enc.fit_statistics(images)
    return enc, p, images


def angle_error(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs(np.angle(np.exp(1j * (a - b))))


def test_the_background_is_the_per_pixel_median_of_the_training_images() -> None:
    enc, _, images = fitted(4)
    assert torch.allclose(enc.background, images.median(0).values)
    assert torch.allclose(enc.background, torch.zeros(1, SIDE, SIDE))  # the empty table
    assert "background" in enc.state_dict()  # saved with the model


@pytest.mark.parametrize("marked", [False, True])
def test_moments_read_the_position_and_the_orientation_modulo_the_symmetry(marked) -> None:
    """The centroid is the square's centre in the keypoints' [-1, 1] coordinates; the n-th
    angular moment turns n times as fast as the square (n = 4 for the uniform square, which
    looks alike every quarter turn; n = 1 for the marked one), so its angle is nθ up to one
    constant phase."""
    order = 1 if marked else 4
    enc, p, images = fitted(order, marked)
    z = enc(images).double().numpy()
    centre = -1 + 2 * (p[:, :2] - 0.5) / (SIDE - 1)
    if not marked:  # the mark moves the weighted centroid off the centre
        np.testing.assert_allclose(z[:, :2], centre, atol=0.01)  # 0.16 pixel
    np.testing.assert_allclose(np.hypot(z[:, 2], z[:, 3]), 1.0, atol=1e-6)
    read = np.arctan2(z[:, 3], z[:, 2])
    phase = np.angle(np.exp(1j * (read - order * p[:, 2])).mean())
    err_deg = np.degrees(angle_error(read, order * p[:, 2] + phase)) / order
    # A 5-pixel square's quarter-turn staircase reads to a few degrees; the mark's first
    # moment is shorter-armed and less exact
    bound = (5.0, 15.0) if marked else (0.6, 2.0)
    assert err_deg.mean() < bound[0] and err_deg.max() < bound[1], (err_deg.mean(),
                                                                    err_deg.max())


def test_an_image_of_the_empty_table_reads_the_centre_and_no_orientation() -> None:
    enc, _, _ = fitted(4)
    z = enc(torch.zeros(2, 1, SIDE, SIDE))
    assert torch.isfinite(z).all()
    assert torch.allclose(z, torch.zeros(2, 4))


def test_the_moments_latent_has_four_coordinates_and_takes_the_face_library() -> None:
    with pytest.raises(UserError, match="--latent-dim 4"):
        AutoencoderConfig(encoder_kind="moments", latent_dim=16)
    with pytest.raises(UserError, match="--moment-order"):
        AutoencoderConfig(encoder_kind="moments", latent_dim=4, moment_order=0)
    face = SindyConfig(order=1, library="face", include_sine=False)
    assert ModelConfig(observation=AutoencoderConfig(encoder_kind="moments", latent_dim=4),
                       dynamics=face).observation.pose_latent
    with pytest.raises(UserError, match="moments encoder"):
        ModelConfig(observation=AutoencoderConfig(latent_dim=4), dynamics=face)


def test_the_moments_cost_weighs_a_pixel_and_ten_degrees_alike() -> None:
    """MPPI's latent cost Q: one pixel of position error costs 1, and so does an orientation
    error of 10° (its angle features 2 - 2 cos(n·10°) apart, squared)."""
    from latent_sindy.models import cost_weights

    enc, _, _ = fitted(4)
    q = cost_weights(4, positions=(0, 1), position_scale=enc.pixel, circle=(2, 3),
                     period=2 * math.pi / enc.order, angle_scale=math.radians(10.0))
    pixel = 2 / (SIDE - 1)
    assert math.isclose(float(q[0]) * pixel**2, 1.0, rel_tol=1e-5)
    z0, z1 = torch.tensor([0.0, 0, 1, 0]), torch.tensor(
        [pixel, 0, math.cos(math.radians(40)), math.sin(math.radians(40))])
    assert math.isclose(float((q * (z1 - z0).square()).sum()), 2.0, rel_tol=1e-5)


def test_training_fits_the_background_and_checks_the_order_against_the_world(
        tmp_path: Path) -> None:
    """A trained moments model keeps the training split's median image as its background;
    an order that does not match the block's symmetry is refused with the one that does."""
    d = make_trajectories(n=6, steps=3)
    data = tmp_path / "d.h5"
    write_sequences(data, d)
    common = ["train", "sindy", "--order", "1", "--library", "face", "--no-include-sine",
              "--data", str(data), "--epochs", "2", "--batch-size", "4", "--no-progress"]
    image = ["image", "--encoder", "moments", "--latent-dim", "4", "--decoder", "conv"]
    assert main([*common, "--out", str(tmp_path / "bad"), *image, "--moment-order", "1"]) == 2
    assert not (tmp_path / "bad" / "model.pt").exists()
    out = tmp_path / "run"
    assert main([*common, "--out", str(out), *image]) == 0
    run = RunDir(out).load()
    norm = Normalizer.from_trajectories(d)
    train_frames = norm.normalize(d.split("train").images).reshape(-1, 1, SIDE, SIDE)
    assert torch.allclose(run.model.autoencoder.encoder.background,
                          train_frames.median(0).values)


def test_the_study_reads_the_pose_from_moments_of_the_worlds_symmetry() -> None:
    from latent_sindy.worlds.push.config import PushEnvConfig
    from latent_sindy.worlds.push.study.catalogue import model_specs
    from latent_sindy.worlds.push.study.scales import SCALES

    for world, library, order in (("symmetric", "face", 4), ("marked", "push", 1)):
        w = PushEnvConfig.named(world)
        spec = {s.name: s for s in model_specs(SCALES["tiny"], angle_period=w.angle_period,
                                               push=w.push)}["sindy_moments"]
        assert spec.model.observation.encoder_kind == "moments"
        assert spec.model.observation.moment_order == order
        assert spec.model.dynamics.library == library
        assert spec.loss.lambda_pred_x == 0
        # fitted by sparse regression on its fixed latents, then kept as fitted
        assert spec.init_share > 0 and spec.loss.lambda_l1 == 0 and spec.prune_below == 0
        assert spec.model.observation.decoder_kind == "sprite"


def test_the_frame_library_on_moments_needs_the_cameras_angle_map(tmp_path: Path,
                                                                  capsys) -> None:
    """The frame library reads the face variables from the orientation features, so on the
    moments latent it must know how the camera shows the world's angles: left out, training
    takes them from the data's camera and the run's record states them; a mismatch is
    refused with the values that fit, which then train."""
    from latent_sindy.worlds.push.camera import moment_frame

    d = make_trajectories(n=6, steps=3)
    data = tmp_path / "d.h5"
    write_sequences(data, d)
    sense, offset = moment_frame(d.world_config)
    train = ["train", "--data", str(data), "--epochs", "1", "--batch-size", "4",
             "--no-progress"]
    sindy = ["sindy", "--order", "1", "--library", "frame", "--no-include-sine"]
    image = ["image", "--encoder", "moments", "--latent-dim", "4", "--decoder", "sprite"]
    assert main([*train, "--out", str(tmp_path / "bad"), *sindy, "--library-options",
                 f"sense={-sense}", *image]) == 2
    assert f"give --library-options sense={sense} offset=" in capsys.readouterr().err
    assert main([*train, "--out", str(tmp_path / "ok"), *sindy, "--library-options",
                 f"sense={sense}", f"offset={offset!r}", *image]) == 0
    assert main([*train, "--out", str(tmp_path / "auto"), *sindy, *image]) == 0
    options = RunDir(tmp_path / "auto").load().model.config.dynamics.options
    assert (options.sense, options.offset) == (sense, pytest.approx(offset))
