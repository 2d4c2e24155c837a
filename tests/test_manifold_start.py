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
