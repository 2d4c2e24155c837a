"""The geodesic reader: a latent learned from frames alone holds the state of what moves."""

import numpy as np
import pytest
import torch

from latent_sindy.errors import UserError
from latent_sindy.models.geodesic_reader import GeodesicReader, winds_round

SIZE = 20
DT = 0.1


def blob(theta: np.ndarray, radius: float = 0.6, width: float = 0.03) -> np.ndarray:
    """A bright blob on a circle at angles ``theta`` (...,): uint8 frames (..., 1, S, S)."""
    axis = np.linspace(-1, 1, SIZE)
    x, y = np.meshgrid(axis, axis[::-1])
    px, py = radius * np.sin(theta), -radius * np.cos(theta)
    f = np.exp(-((x - px[..., None, None]) ** 2 + (y - py[..., None, None]) ** 2) / width)
    return (255 * f[..., None, :, :]).astype(np.uint8)


def episodes(n: int, steps: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
    """Episodes of a blob turning at random constant rates from random angles: stacked
    observations (E, T+1, 2, S, S) (the frame before and the frame now), actions (E, T, 1)
    and the angles (E, T+1)."""
    rng = np.random.default_rng(seed)
    start = rng.uniform(-np.pi, np.pi, (n, 1))
    rate = rng.uniform(-2.0, 2.0, (n, 1))
    theta = start + rate * DT * np.arange(-1, steps + 1)[None]  # one frame before the first
    frames = blob(theta)  # (E, T+2, 1, S, S)
    obs = np.concatenate([frames[:, :-1], frames[:, 1:]], axis=2)
    actions = torch.from_numpy(rng.uniform(-1, 1, (n, steps, 1)))
    return torch.from_numpy(obs), actions, theta[:, 1:]


def probe_r2(z: np.ndarray, y: np.ndarray) -> np.ndarray:
    """R² of an affine least-squares probe of ``y`` (N, k) from ``z`` (N, m)."""
    a = np.column_stack([z, np.ones(len(z))])
    coef = np.linalg.lstsq(a, y, rcond=None)[0]
    return 1 - (y - a @ coef).var(0) / y.var(0)


@pytest.fixture(scope="module")
def fitted():
    obs, _, _ = episodes(40, 30, seed=0)
    return GeodesicReader(frames=2, dim=2, landmarks=300, seed=0).fit_episodes(obs)


def _true_rate(theta: np.ndarray) -> np.ndarray:
    """Each frame's turn since the frame before it, per second (E·(T+1),)."""
    before = np.concatenate([2 * theta[:, :1] - theta[:, 1:2], theta[:, :-1]], axis=1)
    return ((theta - before) / DT).ravel()


def test_a_turning_thing_is_read_as_its_angle_and_turn_rate(fitted):
    obs, actions, theta = episodes(10, 30, seed=1)
    assert fitted.circle == (0, 1)  # the coordinates wind round: an angle
    z = torch.cat([fitted.episode(obs[e], actions[e], DT)[0] for e in range(len(obs))]).numpy()
    assert z.shape[1] == 3 + 1
    np.testing.assert_allclose(np.hypot(z[:, 0], z[:, 1]), 1.0, atol=1e-9)
    angle = np.column_stack([np.cos(theta.ravel()), np.sin(theta.ravel())])
    assert probe_r2(z[:, :2], angle).min() > 0.97
    assert probe_r2(z[:, 2:3], _true_rate(theta)[:, None])[0] > 0.95
    np.testing.assert_allclose(z[:, 3:], np.concatenate(
        [np.vstack([[0.0], a.numpy()]) for a in actions]))


def test_without_the_angle_the_coordinates_and_their_rates_hold_the_state():
    obs, actions, theta = episodes(40, 30, seed=0)
    reader = GeodesicReader(landmarks=300, angle=False).fit_episodes(obs[:30])
    assert reader.circle is None
    z = torch.cat([reader.episode(obs[e], actions[e], DT)[0] for e in range(30, 40)]).numpy()
    assert z.shape[1] == 2 * 2 + 1
    th = theta[30:]
    angle = np.column_stack([np.cos(th.ravel()), np.sin(th.ravel())])
    assert probe_r2(z[:, :2], angle).min() > 0.97
    # a turn's rate is the cross product of position and velocity on the circle
    g, v = z[:, :2] - z[:, :2].mean(0), z[:, 2:4]
    cross = g[:, :1] * v[:, 1:] - g[:, 1:] * v[:, :1]
    assert probe_r2(cross, _true_rate(th)[:, None])[0] > 0.9


def test_only_coordinates_that_wind_round_their_centre_are_an_angle():
    turn = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    ring = torch.from_numpy(np.column_stack([np.cos(turn), 2 * np.sin(turn)]))
    assert winds_round(ring)
    assert not winds_round(ring[:150])  # an arc: a quarter of the turn holds nothing
    disc = torch.from_numpy(np.random.default_rng(0).uniform(-1, 1, (500, 2)))
    assert not winds_round(disc)  # frames near the centre: no angle about it


def test_one_observation_reads_as_in_its_episode(fitted):
    obs, actions, _ = episodes(1, 12, seed=2)
    z, seen = fitted.episode(obs[0], actions[0], DT)
    one, one_seen = fitted.latent(obs[0, 5:6], actions[0, 4:5], DT)
    torch.testing.assert_close(one[0], z[5])
    assert bool(seen.all()) and bool(one_seen.all())


def test_same_seed_same_coordinates_and_another_seed_still_a_circle():
    obs, _, theta = episodes(30, 20, seed=3)
    a = GeodesicReader(landmarks=200, seed=4).fit_episodes(obs)
    b = GeodesicReader(landmarks=200, seed=4).fit_episodes(obs)
    frames = obs[:, :, 1:].flatten(0, 1)
    torch.testing.assert_close(a.read(frames), b.read(frames))
    other = GeodesicReader(landmarks=200, seed=5).fit_episodes(obs).read(frames).numpy()
    angle = np.column_stack([np.cos(theta.ravel()), np.sin(theta.ravel())])
    assert probe_r2(other, angle).min() > 0.97


def test_bad_settings_and_shapes_are_refused_in_words(fitted):
    with pytest.raises(UserError, match="dim=0"):
        GeodesicReader(dim=0)
    with pytest.raises(UserError, match="angle=True"):
        GeodesicReader(dim=3, angle=True)
    with pytest.raises(UserError, match="before fit_episodes"):
        GeodesicReader().read(torch.zeros(1, 1, SIZE, SIZE))
    with pytest.raises(UserError, match="multiple of 2"):
        fitted.latent(torch.zeros(1, 3, SIZE, SIZE), torch.zeros(1, 1), DT)
    with pytest.raises(UserError, match="fitted on"):
        fitted.read(torch.zeros(1, 1, SIZE + 1, SIZE + 1))
    with pytest.raises(UserError, match="too few"):
        GeodesicReader(dim=2).fit_episodes(torch.zeros(1, 2, 2, SIZE, SIZE, dtype=torch.uint8))
