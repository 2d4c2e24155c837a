"""The continuous recipe's start: geodesic coordinates of frames, two latents turned apart."""

import numpy as np
import pytest
import torch

from latent_sindy.models.manifold import farthest_points, geodesic_coordinates
from latent_sindy.training.manifold_start import choose_rotation


def blob_frames(theta: np.ndarray, size: int = 24, width: float = 0.02) -> torch.Tensor:
    """A blob on a circle at angles ``theta``: frames flattened (N, size²)."""
    axis = np.linspace(-1, 1, size)
    X, Y = np.meshgrid(axis, axis[::-1])
    px, py = 0.6 * np.sin(theta), -0.6 * np.cos(theta)
    f = np.exp(-((X[None] - px[:, None, None]) ** 2 + (Y[None] - py[:, None, None]) ** 2) / width)
    return torch.from_numpy(f.reshape(len(theta), -1))


def r2_affine(x: torch.Tensor, t: np.ndarray) -> float:
    a = np.stack([t, np.ones_like(t)], 1)
    x = x.numpy().ravel()
    res = x - a @ np.linalg.lstsq(a, x, rcond=None)[0]
    return 1 - res.var() / x.var()


def test_farthest_points_spread_over_the_points():
    x = torch.linspace(0, 1, 101).unsqueeze(1).double()
    idx = farthest_points(x, 3, first=0)
    assert sorted(idx.tolist()) == [0, 50, 100]


def test_geodesic_coordinate_of_a_blob_on_an_arc_is_its_angle_up_to_an_affine_map():
    # the arc nearly closes (up to 2.9 rad each side): the height reads it twice, the
    # geodesic coordinate once
    theta = np.random.default_rng(0).uniform(-2.9, 2.9, 3000)
    frames = blob_frames(theta)
    m = geodesic_coordinates(frames, 1, landmarks=300, seed=0)
    z = m.transform(frames)
    assert r2_affine(z, theta) > 0.999
    assert m.eigenvalues[1] < 0.01 * m.eigenvalues[0]  # one-dimensional
    height = frames @ torch.from_numpy(np.linspace(-1, 1, 24).repeat(24)[::-1].copy())
    assert r2_affine(height.unsqueeze(1), theta) < 0.5  # what a PCA latent may settle on


def test_pixel_noise_does_not_stretch_the_coordinate_where_frames_are_many():
    """Noise lengthens every graph edge alike, so a stretch sampled densely (many short
    edges) came out longer than one sampled sparsely; the edges shortened by the noise's
    share keep the coordinate even, and noise-free frames are left as they were."""
    from latent_sindy.models.manifold import noise_floor, principal_front

    rng = np.random.default_rng(1)
    u = rng.uniform(-1, 1, 4000)
    theta = 2.5 * np.sign(u) * u ** 2  # many frames near the bottom, few near the ends
    clean = blob_frames(theta)

    def front(frames):
        mean, axes = principal_front(frames, 48, seed=0)
        return (frames - mean) @ axes

    def stretch(z):  # the coordinate's slope near the bottom over its slope near the ends
        z = z.numpy().ravel()
        slope = [abs(np.polyfit(theta[m], z[m], 1)[0])
                 for m in (np.abs(theta) < 0.3, np.abs(theta) > 1.5)]
        return slope[0] / slope[1]

    points = front(clean)
    assert noise_floor(points, 1) == 0.0
    torch.testing.assert_close(
        geodesic_coordinates(points, 1, landmarks=300, seed=0).coords,
        geodesic_coordinates(points, 1, landmarks=300, seed=0, denoise=False).coords)
    noisy = front(clean + 0.05 * torch.from_numpy(rng.standard_normal(clean.shape)))
    assert noise_floor(noisy, 1) > 0
    # frames repeated (as in overlapping windows) are the same frames: the same floor
    assert noise_floor(torch.cat([noisy, noisy]), 1) == pytest.approx(noise_floor(noisy, 1),
                                                                      rel=0.05)
    kept = geodesic_coordinates(noisy, 1, landmarks=300, seed=0)
    raw = geodesic_coordinates(noisy, 1, landmarks=300, seed=0, denoise=False)
    assert stretch(raw.project(noisy)) > 1.15
    assert abs(stretch(kept.project(noisy)) - 1) < 0.1


def test_choose_rotation_takes_two_independent_motions_apart():
    rng = np.random.default_rng(3)
    n = 4000
    th = rng.uniform(-2.5, 2.5, (n, 2))
    w = rng.uniform(-1.5, 1.5, (n, 2))
    acc = np.stack([-1.2 * np.sin(th[:, 0]), -2.5 * np.sin(th[:, 1]) - 0.3 * w[:, 1]], 1)
    turn = 0.6
    r = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    mix = lambda x: x @ r.T  # noqa: E731
    phase = torch.from_numpy(np.concatenate([mix(th), mix(w)], 1))
    phi = choose_rotation(phase, torch.from_numpy(mix(acc)))
    # turning back by φ undoes the mix up to a quarter turn (the latents' order and signs)
    back = (phi + turn) % (np.pi / 2)  # R(φ) R(turn) = 1
    assert min(back, np.pi / 2 - back) < 0.02


def test_project_moves_less_with_pixel_noise_than_interpolation():
    rng = np.random.default_rng(1)
    theta = rng.uniform(-2.0, 2.0, 3000)
    clean = blob_frames(theta, size=32)
    m = geodesic_coordinates(clean, 1, landmarks=400, seed=0)
    noisy = clean + 0.02 * torch.from_numpy(rng.standard_normal(clean.shape))
    moved = {how: float((getattr(m, how)(noisy) - getattr(m, how)(clean)).std())
             for how in ("project", "transform")}
    assert moved["project"] < 0.6 * moved["transform"]


def test_covers_tells_frames_beyond_the_landmarks_from_those_within():
    theta = np.random.default_rng(2).uniform(-1.0, 1.0, 2000)
    m = geodesic_coordinates(blob_frames(theta), 1, landmarks=200, seed=0)
    inside = m.covers(blob_frames(np.array([-0.5, 0.0, 0.9])))
    beyond = m.covers(blob_frames(np.array([2.0, -2.5])))
    assert inside.all() and not beyond.any()


@pytest.mark.slow  # about 110 s on 2 cores: two starts' encoder regressions (3000 steps each)
def test_the_default_writes_the_law_found_on_the_coordinates_without_a_main_fit():
    import warnings

    from latent_sindy import LatentSINDy
    from latent_sindy.worlds.pendulum.video_draws import VideoDraw

    d = VideoDraw(system="pendulum", omega2=(2.0,), damping=(0.1,), size=24, width=0.03,
                  radius=(0.6,), trajectories=40, frames=80, dt=0.05, exact=False, seed=3)
    est = LatentSINDy(latent_dim=1, time="continuous", derivative_order=2, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est.fit(d.video())
    # the true terms, their coefficients within 5 % (friction 10 %), and no other
    assert d.judge(est) == {"recovered": True, "why": ""}, est.equations()
    assert est.kept_["selection"] == "the law found on the coordinates at the start"
    assert est.kept_["start"]["settled"]


def test_held_out_training_sequences_stand_in_for_the_validation_ones_whole():
    from latent_sindy.training.manifold_start import HOLD_OUT_EVERY, _held_out_every

    sequence = np.repeat(np.arange(12), 7)
    phase = np.random.default_rng(0).normal(size=(len(sequence), 2))
    top = phase[:, :1] * 2.0
    split = _held_out_every((phase, top, sequence), HOLD_OUT_EVERY)
    kept, held = set(split["train"][2]), set(split["val"][2])
    assert held and kept and not kept & held  # whole sequences go one way or the other
    assert kept | held == set(range(12))
    assert len(held) == 12 // HOLD_OUT_EVERY
    # each sample keeps its own phase and z'' beside it
    for part in split.values():
        assert np.array_equal(part[1], part[0][:, :1] * 2.0)


def test_a_blurred_metric_measures_the_frames_blurred():
    from torch.nn import functional as F

    from latent_sindy.models.pca_front import blurred_metric

    gen = torch.Generator().manual_seed(0)
    columns = torch.randn(2 * 9 * 11, 6, generator=gen)
    r = blurred_metric(columns, (2, 9, 11), 1.5)
    step = torch.randn(6, generator=gen, dtype=torch.float64)
    x = torch.arange(-5, 6, dtype=torch.float64)
    g = torch.exp(-x.square() / (2 * 1.5 ** 2))
    g = g / g.sum()
    image = (columns.double() @ step).reshape(2, 1, 9, 11)
    blurred = F.conv2d(image, (g[:, None] * g[None, :])[None, None], padding=5)
    assert float((r @ step).norm()) == pytest.approx(float(blurred.norm()), rel=1e-9)
    assert float((r @ step).norm()) < float((columns.double() @ step).norm())


def _kicked_pendulum_video(seed: int, sigma: float) -> tuple[np.ndarray, torch.Tensor]:
    """16 sequences of 68 frames, 0.12 s apart, of a pendulum (ω² 1.12) kicked from the
    bottom, drawn as a blob ``sigma`` px wide 24 px from the middle of 60 px frames: the
    angles (16, 68) and the frames (16, 68, 3600)."""
    from scipy.integrate import solve_ivp

    rng = np.random.default_rng(seed)
    t = np.arange(68) * 0.12
    theta = np.stack([solve_ivp(lambda _t, y: [y[1], -1.12 * np.sin(y[0])], (0, t[-1]),
                                [0.0, v], t_eval=t, rtol=1e-9, atol=1e-9).y[0]
                      for v in rng.uniform(-1.95, 1.95, 16) * 1.12 ** 0.5])
    r = np.arange(60)[None, :, None]
    c = np.arange(60)[None, None, :]
    pr, pc = 29.5 + 24 * np.cos(theta).ravel(), 29.5 + 24 * np.sin(theta).ravel()
    f = np.exp(-((r - pr[:, None, None]) ** 2 + (c - pc[:, None, None]) ** 2) / (2 * sigma**2))
    return theta, torch.from_numpy(f.reshape(16, 68, -1))


def test_the_graph_blurs_frames_that_barely_overlap_and_finds_the_angle_again():
    """A blob 1.2 px wide that steps about its width a frame where it swings fastest: with
    16 sequences, the frames there overlap no other and the geodesic coordinate loses the
    swing's order; measured on the frames blurred as the data chooses, it holds the angle.
    A blob 3 px wide is left as it is."""
    from latent_sindy.models.pca_front import principal_components
    from latent_sindy.training.manifold_start import choose_blur

    def r2(manifold, c, theta):
        return np.corrcoef(manifold.project(c).numpy().ravel(), theta.ravel())[0, 1] ** 2

    for sigma, blurred in ((1.2, True), (3.0, False)):
        theta, frames = _kicked_pendulum_video(0, sigma)
        x = frames.flatten(0, 1)
        mean, basis, spread = principal_components(x.float(), 48)
        c = ((x - mean.double()) @ basis.double()) / spread
        width, metric, _ = choose_blur(list(c.reshape(16, 68, -1)), basis * spread, (1, 60, 60))
        plain = r2(geodesic_coordinates(c, 1, seed=0), c, theta)
        if not blurred:
            assert (width, metric) == (0.0, None) and plain > 0.999
            continue
        assert width > 0 and plain < 0.9
        assert r2(geodesic_coordinates(c, 1, seed=0, metric=metric), c, theta) > 0.999
