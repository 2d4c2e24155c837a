"""What the latent knows: the camera geometry, reading the block's position from images, the
linear and kernel probes and the position error of predictions, on rendered images with known
poses."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from latent_sindy.data import SequenceData
from latent_sindy.data.windows import Normalizer, pose_features
from latent_sindy.errors import UserError
from latent_sindy.worlds.push.config import PushEnvConfig
from latent_sindy.worlds.push.data import push_data
from latent_sindy.worlds.push.scene import CameraView
from latent_sindy.worlds.push.study.probe import (
    KernelProbe,
    block_position,
    kernel_probe,
    latent_probe,
    latent_probes,
    position_errors,
    state_position_errors,
)

HALF_DIAGONAL = 0.0708  # m: the 0.1 m block's corners from its centre


@pytest.fixture(scope="module")
def world():
    w = CameraView(PushEnvConfig())
    yield w
    w.close()


def in_view(world: CameraView, pose) -> bool:
    """Is the whole block (every corner, top and bottom) inside the image?"""
    corners = [(pose[0] + dx, pose[1] + dy, z) for dx in (-HALF_DIAGONAL, HALF_DIAGONAL)
               for dy in (-HALF_DIAGONAL, HALF_DIAGONAL) for z in (0.0, 0.05)]
    rc = world.camera.world_to_pixel(np.array(corners))
    return bool(rc.min() >= 0 and rc.max() <= world.cfg.image_size - 1)


def random_poses(world: CameraView, n: int, seed: int) -> np.ndarray:
    cfg, rng, out = world.cfg, np.random.default_rng(seed), []
    while len(out) < n:
        p = rng.uniform(cfg.workspace_low, cfg.workspace_high)
        if in_view(world, p):
            out.append(p)
    return np.array(out)


def test_world_to_pixel_is_where_the_renderer_draws_the_block():
    """The block's top face (its own gray level) is centred where the camera projects the
    top's centre, to a tenth of a pixel at 128 pixels (the pixel-centre convention was half
    a pixel off in both axes)."""
    w = CameraView(PushEnvConfig(image_size=128))
    try:
        offsets = []
        for pose in random_poses(w, 12, seed=3):
            img = w.observe(pose)[0]
            values, counts = np.unique(img, return_counts=True)
            top = img == values[np.argsort(counts)[-2]]  # the table's, then the top face's
            rows, cols = np.nonzero(top)
            offsets.append([rows.mean(), cols.mean()]
                           - w.camera.world_to_pixel((pose[0], pose[1], 0.05)))
    finally:
        w.close()
    assert np.abs(np.mean(offsets, axis=0)).max() < 0.15
    assert np.abs(np.median(offsets, axis=0)).max() < 0.15


def test_pixel_to_world_inverts_world_to_pixel(world):
    pts = np.array([[0.5, 0.1, 0.0], [0.7, -0.3, 0.025], [0.3, 0.35, 0.05]])
    for p in pts:
        back = world.camera.pixel_to_world(world.camera.world_to_pixel(p), height=p[2])
        np.testing.assert_allclose(back, p[:2], atol=1e-9)


def test_block_position_reads_true_images_to_a_few_millimetres(world):
    poses = random_poses(world, 60, seed=0)
    images = np.stack([world.observe(p) for p in poses])  # (60, 1, 32, 32)
    err_cm = 100 * np.linalg.norm(block_position(images, world.cfg) - poses[:, :2], axis=1)
    assert err_cm.mean() < 0.5  # measured 0.38 cm at 32x32 (a pixel is about 2.5 cm)
    assert err_cm.max() < 1.5


def test_block_position_reads_rgb_images_alike(world):
    rgb = CameraView(PushEnvConfig(channels=3))
    try:
        poses = random_poses(world, 10, seed=1)
        xy_rgb = block_position(np.stack([rgb.observe(p) for p in poses]), rgb.cfg)
    finally:
        rgb.close()
    xy = block_position(np.stack([world.observe(p) for p in poses]), world.cfg)
    np.testing.assert_allclose(xy_rgb, xy, atol=1e-3)


def test_a_faint_blurred_block_is_still_found(world):
    """Predicted images fade: a block at a fifth of its contrast, blurred, reads near where
    it is; the position follows the blob, not the image's centre."""
    pose = np.array([0.45, -0.2, 0.3])
    img = world.observe(pose)[0].astype(float)
    table = np.median(img)
    faint = table - 0.2 * (table - img)
    blurred = faint.copy()
    for axis in (0, 1):  # a 3-tap box blur
        blurred = (np.roll(blurred, 1, axis) + blurred + np.roll(blurred, -1, axis)) / 3
    xy = block_position(blurred[None, None], world.cfg)[0]
    assert np.linalg.norm(xy - pose[:2]) < 0.015


def test_block_position_refuses_images_of_another_size(world):
    with pytest.raises(UserError, match="16x16 pixels, but the world renders 32x32"):
        block_position(np.zeros((2, 1, 16, 16), np.uint8), world.cfg)


# ------------------------------------------------------------------ probe and predictions
class LookupModel(torch.nn.Module):
    """A stand-in latent model: frame k of the data (its pixels (0, 0) and (0, 2) hold k mod
    256 and k // 256) encodes to ``latents[k]``."""

    def __init__(self, latents: np.ndarray) -> None:
        super().__init__()
        self.latents = torch.as_tensor(latents, dtype=torch.float32)

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        return self.latents[(x[..., 0, 0, 0] + 256 * x[..., 0, 0, 2]).round().long()]


def indexed_trajectories(n: int = 30, steps: int = 4, seed: int = 0) -> SequenceData:
    """Frames numbered in pixels (0, 0) and (0, 2), random poses; splits train / val / test
    in turn."""
    rng = np.random.default_rng(seed)
    images = np.zeros((n, steps + 1, 1, 32, 32), np.uint8)
    frame = np.arange(n * (steps + 1)).reshape(n, steps + 1)
    images[..., 0, 0, 0], images[..., 0, 0, 2] = frame % 256, frame // 256
    images[..., 0, 1, 1] = 1  # a non-constant image for the pixel statistics
    poses = rng.uniform((0.35, -0.35, -np.pi), (0.7, 0.35, np.pi), (n, steps + 1, 3))
    actions = np.zeros((n, steps, 3), np.float32)
    return push_data(images, actions, poses.astype(np.float32),
                        (np.arange(n) % 3).astype(np.uint8), PushEnvConfig(), seed=seed)


@pytest.mark.parametrize("noise", [0.0, 0.05])
def test_probe_finds_a_latent_that_holds_the_pose(noise):
    data = indexed_trajectories()
    frames = data.n * (data.steps + 1)
    features = pose_features(data.poses, data.world_config.angle_period).numpy().reshape(frames, 4)
    rng = np.random.default_rng(1)
    mixing = rng.normal(size=(4, 16))  # the pose, linearly mixed into 16 latent coordinates
    z = features @ mixing + noise * rng.normal(size=(frames, 16))
    r2 = latent_probe(LookupModel(z), data, Normalizer(0.0, 1.0))
    assert set(r2) == {"x", "y", "cos", "sin"}
    assert min(r2.values()) > (0.999 if noise == 0 else 0.9)


def test_probe_gives_no_credit_to_a_latent_without_the_angle():
    data = indexed_trajectories(n=48)  # 240 frames: numbered below 256
    frames = data.n * (data.steps + 1)
    rng = np.random.default_rng(2)
    xy = data.poses.reshape(frames, 3)[:, :2]
    z = np.column_stack([xy, rng.normal(size=(frames, 14))])  # position, then noise
    r2 = latent_probe(LookupModel(z), data, Normalizer(0.0, 1.0))
    assert r2["x"] > 0.99 and r2["y"] > 0.99
    assert r2["cos"] < 0.2 and r2["sin"] < 0.2


def corner_latents(data: SequenceData, mixed: bool, seed: int = 3) -> np.ndarray:
    """The block's x, y and its four corners about its centre: the angle features
    cos 4θ, sin 4θ are no linear function of these (they are of cos θ, sin θ), but a smooth
    one. ``mixed``: the 10 coordinates mixed into 16 by a random matrix, plus noise."""
    poses = data.poses.reshape(-1, 3)
    turn = poses[:, 2:] + np.pi / 4 + np.arange(4) * np.pi / 2  # (M, 4) corner directions
    z = np.column_stack([poses[:, :2], HALF_DIAGONAL * np.cos(turn),
                         HALF_DIAGONAL * np.sin(turn)])  # (M, 10)
    if mixed:
        rng = np.random.default_rng(seed)
        z = z / z.std(0) @ rng.normal(size=(10, 16)) + 0.05 * rng.normal(size=(len(z), 16))
    return z


@pytest.fixture(scope="module")
def many() -> SequenceData:
    return indexed_trajectories(n=300)  # 500 training and 500 test frames


@pytest.mark.parametrize("mixed", [False, True])
def test_kernel_probe_reads_an_angle_the_latent_holds_nonlinearly(many, mixed):
    """Corner positions hold the orientation: the linear probe reads x and y but not the
    angle features, the kernel probe reads all four."""
    model = LookupModel(corner_latents(many, mixed))
    linear = latent_probe(model, many, Normalizer(0.0, 1.0))
    kernel = kernel_probe(model, many, Normalizer(0.0, 1.0))
    assert min(linear["x"], linear["y"], kernel["x"], kernel["y"]) > 0.95
    assert max(linear["cos"], linear["sin"]) < 0.1
    assert min(kernel["cos"], kernel["sin"]) >= 0.9, kernel


def test_kernel_probe_gives_no_credit_to_noise(many):
    """A latent that carries nothing: held-out choice of the ridge keeps the kernel probe
    from fitting the noise (R² about 0 on the test images)."""
    z = np.random.default_rng(4).normal(size=(many.n * (many.steps + 1), 16))
    r2 = kernel_probe(LookupModel(z), many, Normalizer(0.0, 1.0))
    assert max(r2.values()) <= 0.1, r2
    assert min(r2.values()) > -0.2, r2  # measured -0.10 to 0.00: no wild fit to the noise


def test_kernel_probe_same_seed_same_result(many):
    model = LookupModel(corner_latents(many, mixed=True))
    a, b = (kernel_probe(model, many, Normalizer(0.0, 1.0), seed=7) for _ in range(2))
    assert a == b


def test_latent_probes_keep_the_linear_figures_and_add_the_kernel_ones(many):
    model, norm = LookupModel(corner_latents(many, mixed=True)), Normalizer(0.0, 1.0)
    both = latent_probes(model, many, norm, seed=1)
    kernel = kernel_probe(model, many, norm, seed=1)
    assert {k: both[k] for k in ("x", "y", "cos", "sin")} == latent_probe(model, many, norm)
    assert {k: both[f"kernel/{k}"] for k in kernel} == kernel
    assert both["kernel/angle"] == pytest.approx((kernel["cos"] + kernel["sin"]) / 2)
    assert len(both) == 9


def test_kernel_probe_is_kernel_ridge_regression():
    """With one width and one ridge, the prediction is the closed form
    K(z', z) (K(z, z) + λ M I)⁻¹ y on standardised latents and targets."""
    rng = np.random.default_rng(5)
    z, y, zt = rng.normal(size=(40, 3)), rng.normal(size=(40, 2)), rng.normal(size=(7, 3))
    got = KernelProbe(gammas=(0.5,), ridges=(1e-2,)).fit(z, y).predict(zt)
    mu, sd, ym, ys = z.mean(0), z.std(0), y.mean(0), y.std(0)
    a, b = (z - mu) / sd, (zt - mu) / sd

    def k(p, q):
        return np.exp(-0.5 / 3 * ((p[:, None] - q[None]) ** 2).sum(-1))

    want = k(b, a) @ np.linalg.solve(k(a, a) + 1e-2 * 40 * np.eye(40), (y - ym) / ys) * ys + ym
    np.testing.assert_allclose(got, want, rtol=1e-8, atol=1e-10)


def test_kernel_probe_of_a_diverged_latent_is_nan(many):
    z = corner_latents(many, mixed=False)
    z[3, 0] = np.nan
    r2 = latent_probes(LookupModel(z), many, Normalizer(0.0, 1.0))
    assert all(np.isnan(r2[f"kernel/{k}"]) for k in ("x", "y", "cos", "sin"))


@pytest.mark.parametrize(("settings", "match"), [
    ({"gammas": ()}, "must be non-empty and positive"),
    ({"ridges": (0.0,)}, "must be non-empty and positive"),
    ({"held_out": 1.0}, "must be a fraction in"),
])
def test_kernel_probe_refuses_bad_settings(settings, match):
    with pytest.raises(UserError, match=match):
        KernelProbe(**settings)


def test_kernel_probe_refuses_mismatched_data():
    with pytest.raises(UserError, match=r"latents \(5, 2\) and targets \(4, 1\)"):
        KernelProbe().fit(np.zeros((5, 2)), np.zeros((4, 1)))


class ReplayModel(torch.nn.Module):
    """A stand-in image model: its "prediction" from x_t is the true images x_t.. (perfect),
    or x_t repeated (nothing moves); its reconstruction is the image itself."""

    def __init__(self, truth: torch.Tensor, still: bool) -> None:
        super().__init__()
        self.truth, self.still = truth, still

    def encode(self, x):
        return x

    def decode(self, z):
        return z

    def predict(self, x0: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        h = u.shape[1]
        if self.still:
            return x0[:, None].expand(-1, h + 1, *x0.shape[1:])
        t = self.truth.shape[1] - 1 - h
        return self.truth[:, t:]


@pytest.fixture(scope="module")
def moving(world) -> SequenceData:
    """Three blocks, each pushed 3 cm along x per step for 4 steps, rendered."""
    poses = np.array([[(0.4 + 0.03 * t, y, 0.2 * t) for t in range(5)]
                      for y in (-0.2, 0.0, 0.2)], np.float32)
    images = np.stack([[world.observe(p) for p in traj] for traj in poses])
    return push_data(images, np.zeros((3, 4, 3), np.float32), poses,
                        np.array([0, 2, 2], np.uint8), world.cfg, seed=0)


def test_position_errors_of_a_perfect_and_a_still_predictor(moving):
    norm = Normalizer(0.0, 1.0)
    truth = norm.normalize(moving.images)
    perfect = position_errors(ReplayModel(truth, still=False), moving, norm)
    still = position_errors(ReplayModel(truth, still=True), moving, norm)
    steps = moving.steps
    assert len(perfect["model"]) == len(perfect["still"]) == steps
    assert perfect["reader"] < 0.5 and perfect["recon"] == pytest.approx(perfect["reader"])
    assert max(perfect["model"]) < 1.0  # reading true images, a few millimetres
    # "nothing moves" is off by the distance travelled: 3 cm per push, give or take reading
    for h, e in enumerate(perfect["still"], start=1):
        assert abs(e - 3.0 * h) < 1.0
    np.testing.assert_allclose(still["model"], perfect["still"], rtol=1e-9)


class DivergingModel(ReplayModel):
    """Perfect, except that one trajectory's predictions blow up to NaN after one push."""

    def predict(self, x0: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        out = super().predict(x0, u).clone()
        out[0, 2:] = float("nan")
        return out


def test_a_diverged_prediction_counts_as_infinitely_far(moving):
    """Left out, the NaN predictions would leave a small mean of the survivors."""
    norm = Normalizer(0.0, 1.0)
    errors = position_errors(DivergingModel(norm.normalize(moving.images), still=False),
                             moving, norm)
    assert errors["model"][0] < 1.0  # one push: every prediction finite
    assert all(e == float("inf") for e in errors["model"][1:])


def test_state_position_errors_of_a_perfect_and_a_still_predictor(moving):
    """A state model's predictions are poses: exact ones are 0 cm off, "nothing moves" ones
    are off by the distance travelled, and a diverged one counts as infinitely far."""
    from latent_sindy.data.windows import pose_features

    s = pose_features(moving.poses, moving.world_config.angle_period)  # (N, T+1, 4)
    steps = moving.steps
    perfect = [s[:, t:] for t in range(steps)]
    still = [s[:, t:t + 1].expand(-1, steps - t + 1, -1) for t in range(steps)]
    got = state_position_errors(moving, perfect)
    assert got["recon"] == 0.0 and max(got["model"]) < 1e-5
    for h, e in enumerate(got["still"], start=1):
        assert e == pytest.approx(3.0 * h, rel=1e-5)  # 3 cm per push
    np.testing.assert_allclose(state_position_errors(moving, still)["model"], got["still"],
                               rtol=1e-5)
    diverged = [p.clone() for p in perfect]
    diverged[0][1, 2:] = float("nan")
    errors = state_position_errors(moving, diverged)["model"]
    assert errors[0] < 1e-5 and errors[1] == float("inf")


def test_the_moment_frame_turns_the_images_angle_into_the_worlds(world):
    """On rendered images, the moments latent's orientation features mapped through the
    camera's frame (:func:`moment_frame`) give the frame library the face
    variables of the true pose: the push's angle from the pushed face's normal to a few
    degrees (the moments read the orientation to about 4°, modulo the face's 90°)."""
    import math

    from latent_sindy.models.autoencoder import MomentEncoder
    from latent_sindy.models.autoencoder_parts import MomentEncoderConfig
    from latent_sindy.worlds.push.camera import moment_frame
    from latent_sindy.worlds.push.library import face_variables

    poses = random_poses(world, 40, seed=5)
    images = torch.tensor(np.stack([world.observe(p) for p in poses]), dtype=torch.float32)
    side = world.cfg.image_size
    enc = MomentEncoder(MomentEncoderConfig(order=4), (1, side, side))
    x = (images - 180.0) / 17.0
    enc.fit_statistics(torch.cat([x, x.roll(1, 0)]))  # the median is the empty table's
    z = enc(x).double()
    sense, offset = moment_frame(world.cfg)
    psi = torch.linspace(-math.pi, math.pi, len(poses), dtype=torch.float64)
    a, _ = face_variables(psi, z[:, 2], z[:, 3], (0, 0, 0, 4.0, sense, offset))
    theta = torch.as_tensor(poses[:, 2])
    true_a, _ = face_variables(psi, torch.cos(4 * theta), torch.sin(4 * theta),
                               (0, 0, 0, 4.0, 1, 0.0))
    gap = torch.remainder(a - true_a + math.pi / 4, math.pi / 2) - math.pi / 4
    assert float(gap.abs().median()) < math.radians(6), gap
