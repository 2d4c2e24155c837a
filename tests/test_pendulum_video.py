"""The pendulum video (Champion et al. 2019): the starts' rejection rule, the dynamics, the
image layout, exact image derivatives against finite differences, and same seed, same data."""

from __future__ import annotations

import math

import numpy as np
import pytest

from latent_sindy.data import read_sequences, write_sequences
from latent_sindy.errors import UserError
from latent_sindy.plugins import get_world
from latent_sindy.worlds.pendulum.video import (
    ENERGY_LIMIT,
    blob_images,
    integrate,
    pendulum_video,
    sample_starts,
)


def energy(states: np.ndarray) -> np.ndarray:
    return states[..., 1] ** 2 / 2 - np.cos(states[..., 0])


def test_starts_are_uniform_draws_with_full_turns_rejected():
    starts = sample_starts(500, np.random.default_rng(3))
    assert starts.shape == (500, 2)
    assert np.all(np.abs(energy(starts)) <= ENERGY_LIMIT)
    assert np.all(np.abs(starts[:, 0]) <= math.pi) and np.all(np.abs(starts[:, 1]) <= 2.1)
    # the accepted starts are the first draws that pass the rule, in the order drawn
    rng = np.random.default_rng(3)
    theta, rate = rng.uniform(-np.pi, np.pi, 1000), rng.uniform(-2.1, 2.1, 1000)
    ok = np.abs(rate ** 2 / 2 - np.cos(theta)) <= ENERGY_LIMIT
    assert 0.1 < 1 - ok.mean() < 0.9  # the rule rejects a real share of the draws
    np.testing.assert_array_equal(starts, np.stack([theta[ok], rate[ok]], 1)[:500])


def test_trajectories_follow_the_pendulum_and_never_turn_over():
    scipy = pytest.importorskip("scipy.integrate")
    starts = sample_starts(5, np.random.default_rng(0))
    states = integrate(starts, 500, 0.02)  # (5, 500, 2), t in [0, 10)
    assert np.abs(energy(states) - energy(starts)[:, None]).max() < 1e-10
    assert np.all(np.abs(states[..., 0]) < math.pi)
    t = np.arange(500) * 0.02
    for start, ours in zip(starts, states, strict=True):
        ref = scipy.solve_ivp(lambda _, x: [x[1], -np.sin(x[0])], (0, t[-1]), start,
                              t_eval=t, rtol=1e-12, atol=1e-12, method="DOP853")
        np.testing.assert_allclose(ours, ref.y.T, atol=1e-8)


def test_the_image_is_the_blob_on_the_grid():
    """X runs left to right and Y from 1.5 (top) to −1.5 (bottom); the blob sits at
    (cos(θ − π/2), sin(θ − π/2)): hanging (θ = 0) bottom centre, θ = π/2 right middle."""
    x, _, _ = blob_images(np.array([0.0, math.pi / 2]), np.zeros(2), size=51)
    assert x.shape == (2, 51, 51) and x.dtype == np.float32
    assert np.unravel_index(np.argmax(x[0]), x[0].shape) == (42, 25)  # y = −1.02
    assert np.unravel_index(np.argmax(x[1]), x[1].shape) == (25, 42)  # x = 1.02
    axis = np.linspace(-1.5, 1.5, 51)
    y = axis[::-1]
    np.testing.assert_allclose(x[0, 40, 27], np.exp(-(axis[27] ** 2 + (y[40] + 1) ** 2)
                                                    / 0.05), rtol=1e-6)


def test_image_derivatives_match_finite_differences():
    """Central differences of the images at dt = 1e-3 agree with the exact ẋ and ẍ to
    0.1 % of their largest values (a sign or chain-rule slip is off by 100 %)."""
    data = pendulum_video(n_train=3, n_val=0, n_test=0, steps=201, dt=1e-3, size=31,
                          seed=5, dtype=np.float64)
    x, xd, xdd = data.images, data.images_dot, data.images_ddot
    h = data.dt
    fd1 = (x[:, 2:] - x[:, :-2]) / (2 * h)
    fd2 = (x[:, 2:] - 2 * x[:, 1:-1] + x[:, :-2]) / h ** 2
    assert np.abs(fd1 - xd[:, 1:-1]).max() < 1e-3 * np.abs(xd).max()
    assert np.abs(fd2 - xdd[:, 1:-1]).max() < 1e-3 * np.abs(xdd).max()
    assert np.abs(xdd).max() > 1  # the check is not vacuous: the pendulum moves


def test_the_data_set_as_the_benchmark_defines_it():
    data = pendulum_video(n_train=3, n_val=2, n_test=1, steps=30, size=21, seed=1)
    assert data.images.shape == (6, 30, 1, 21, 21) and data.images.dtype == np.float32
    assert data.images_dot.shape == data.images.shape == data.images_ddot.shape
    assert 0 <= data.images.min() and data.images.max() <= 1 and data.nu == 0
    assert data.split_ids.tolist() == [0, 0, 0, 1, 1, 2]
    assert data.state_names == ("θ", "θ_dot") and data.state_periods == (2 * math.pi, None)
    assert data.dt == 0.02 and data.world == "pendulum-video"
    # the states are the integrated ones, the images drawn from them
    np.testing.assert_allclose(data.states[:, 0], sample_starts(6, np.random.default_rng(1)),
                               rtol=1e-6)
    x, _, _ = blob_images(data.states[2, 7, 0], data.states[2, 7, 1], size=21)
    np.testing.assert_allclose(data.images[2, 7, 0], x, atol=1e-6)


def test_subsampled_frames_are_every_kth_sample():
    full = pendulum_video(n_train=2, n_val=0, n_test=0, steps=20, size=15, seed=2)
    sub = pendulum_video(n_train=2, n_val=0, n_test=0, steps=20, size=15, seed=2,
                         frames_every=5)
    assert sub.images.shape[1] == 4 and sub.dt == pytest.approx(0.1)
    np.testing.assert_array_equal(sub.images, full.images[:, ::5])
    np.testing.assert_array_equal(sub.images_ddot, full.images_ddot[:, ::5])


def test_same_seed_same_data_and_another_seed_other_data():
    a = pendulum_video(n_train=2, n_val=1, n_test=1, steps=10, size=15, seed=7)
    b = pendulum_video(n_train=2, n_val=1, n_test=1, steps=10, size=15, seed=7)
    c = pendulum_video(n_train=2, n_val=1, n_test=1, steps=10, size=15, seed=8)
    assert a.fingerprint() == b.fingerprint() != c.fingerprint()
    np.testing.assert_array_equal(a.images_ddot, b.images_ddot)


def test_the_data_round_trip_through_a_file_and_name_their_plugin(tmp_path):
    data = pendulum_video(n_train=2, n_val=1, n_test=1, steps=6, size=11, seed=0)
    write_sequences(tmp_path / "video.h5", data)
    back = read_sequences(tmp_path / "video.h5")
    np.testing.assert_array_equal(back.images_ddot, data.images_ddot)
    assert back.world == "pendulum-video" and back.world_config["steps"] == 6


@pytest.mark.parametrize("bad", [dict(n_train=0, n_val=0, n_test=0), dict(steps=1),
                                 dict(steps=10, frames_every=10), dict(frames_every=0),
                                 dict(dt=-1.0), dict(size=1), dict(dtype=np.uint8)])
def test_bad_settings_are_refused_in_one_line(bad):
    with pytest.raises(UserError) as err:
        pendulum_video(**{"n_train": 1, "n_val": 0, "n_test": 0, "steps": 10, "size": 9, **bad})
    assert "\n" not in str(err.value)


def test_the_video_plugin_is_found_by_name():
    assert get_world("pendulum-video").config_from_record(
        {"video": {"steps": 500}}, "here") == {"steps": 500}
    with pytest.raises(UserError, match="lacks"):
        get_world("pendulum-video").config_from_record({}, "here")


@pytest.mark.parametrize("omega2", [0.49, 1.44, 4.0])
def test_another_frequency_is_the_same_pendulum_in_its_own_time(omega2: float) -> None:
    """θ̈ = −ω² sin θ: the states and the images' derivatives follow it, no start turns full
    circles, and the starts are the benchmark's with the rates scaled by ω."""
    dt = 0.002
    data = pendulum_video(n_train=3, n_val=1, n_test=1, steps=400, dt=dt, size=21,
                          omega2=omega2, dtype=np.float64)
    th, rate = data.states[..., 0], data.states[..., 1]
    e = rate ** 2 / 2 - omega2 * np.cos(th)
    assert np.abs(e - e[:, :1]).max() < 1e-8 and np.abs(e).max() <= ENERGY_LIMIT * omega2
    # the rate's central difference is θ̈ = −ω² sin θ
    acc = (rate[:, 2:] - rate[:, :-2]) / (2 * dt)
    np.testing.assert_allclose(acc, -omega2 * np.sin(th[:, 1:-1]), atol=1e-4 * omega2)
    # the images' ẍ is the central difference of their ẋ
    ddx = (data.images_dot[:, 2:] - data.images_dot[:, :-2]) / (2 * dt)
    scale = np.abs(data.images_ddot).max()
    assert np.abs(ddx - data.images_ddot[:, 1:-1]).max() < 5e-3 * scale
    ref = sample_starts(5, np.random.default_rng(0))
    np.testing.assert_allclose(data.states[:, 0], ref * [1, math.sqrt(omega2)], rtol=1e-12)
    assert data.record["video"]["omega2"] == omega2


def test_a_frequency_that_is_no_number_is_refused() -> None:
    with pytest.raises(UserError, match="omega2"):
        pendulum_video(n_train=1, n_val=0, n_test=0, steps=10, omega2=-1.0)


def test_the_video_study_keys_its_rows_and_cache_by_the_frequency() -> None:
    from latent_sindy.worlds.pendulum.video_pca import cache_name
    from latent_sindy.worlds.pendulum.video_study import VideoStudyConfig

    one, other = VideoStudyConfig(seeds=(0,)), VideoStudyConfig(seeds=(0,), omega2=1.44)
    assert "omega2" not in one.key()  # rows of the benchmark's video kept before stay valid
    assert other.key()["omega2"] == 1.44
    assert cache_name(48, 5, "exact") != cache_name(48, 5, "exact", omega2=1.44)
    with pytest.raises(UserError, match="omega2"):
        VideoStudyConfig(seeds=(0,), omega2=0.0)


def test_the_benchmarks_own_starts_at_another_frequency() -> None:
    """starts="benchmark": the starts drawn as for ω² = 1 whatever ω² (relatively smaller
    swings above 1); refused below 1, where some would turn full circles."""
    ours = pendulum_video(n_train=3, n_val=1, n_test=1, steps=20, size=11, omega2=1.44,
                          starts="benchmark")
    bench = pendulum_video(n_train=3, n_val=1, n_test=1, steps=20, size=11)
    np.testing.assert_array_equal(ours.states[:, 0], bench.states[:, 0])
    assert not np.array_equal(ours.states[:, 1], bench.states[:, 1])  # another pendulum
    with pytest.raises(UserError, match="full circles"):
        pendulum_video(n_train=1, n_val=0, n_test=0, steps=10, omega2=0.5, starts="benchmark")
