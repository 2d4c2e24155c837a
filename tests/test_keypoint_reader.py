"""The keypoint reader: keypoints learned by transporting features hold what moves."""

import numpy as np
import pytest
import torch

from latent_sindy.errors import UserError
from latent_sindy.models import keypoint_reader
from latent_sindy.models.keypoint_reader import KeypointReader

SIZE = 16
DT = 0.1


def squares(n: int, steps: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
    """Episodes of a bright 4×4 square moving on a grey floor along random Lissajous paths:
    observations (E, T+1, 1, S, S) float, actions (E, T, 1) and its pixel positions
    (E, T+1, 2) as (column, row)."""
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 6, (n, 2, 1))
    t = np.arange(steps + 1)[None]
    cols = np.round(SIZE / 2 + SIZE / 4 * np.sin(0.3 * t + phase[:, 0])).astype(int)
    rows = np.round(SIZE / 2 + SIZE / 4 * np.cos(0.2 * t + phase[:, 1])).astype(int)
    frames = np.full((n, steps + 1, 1, SIZE, SIZE), 0.3, np.float32)
    for e in range(n):
        for k in range(steps + 1):
            frames[e, k, 0, rows[e, k] - 2:rows[e, k] + 2, cols[e, k] - 2:cols[e, k] + 2] = 1
    actions = torch.from_numpy(rng.uniform(-1, 1, (n, steps, 1)))
    return torch.from_numpy(frames), actions, np.stack([cols, rows], -1).astype(float)


def probe_r2(z: np.ndarray, y: np.ndarray) -> np.ndarray:
    a = np.column_stack([z, np.ones(len(z))])
    coef = np.linalg.lstsq(a, y, rcond=None)[0]
    return 1 - (y - a @ coef).var(0) / y.var(0)


def positions(reader: KeypointReader, obs: torch.Tensor, actions: torch.Tensor) -> np.ndarray:
    kept = len(reader.names) // 2
    return torch.cat([reader.episode(obs[e], actions[e], DT)[0][:, :kept]
                      for e in range(len(obs))]).numpy()


@pytest.fixture(scope="module")
def fitted():
    torch.set_num_threads(1)
    obs, actions, where = squares(6, 20, 0)
    keypoint_reader._FITTED.clear()
    reader = KeypointReader(frames=1, parts=2, steps=300, batch=16, lr=3e-3, progress=False)
    reader.fit_episodes(obs)
    return reader, obs, actions, where


def quadratic(z: np.ndarray) -> np.ndarray:
    """z (N, m) and its monomials of degree 2: a keypoint's softmax over a coarse map bends
    its coordinate a little against the pixel position."""
    i, j = np.triu_indices(z.shape[1])
    return np.column_stack([z, z[:, i] * z[:, j]])


def test_the_keypoints_hold_the_square_that_moves_and_training_is_what_places_them(fitted):
    reader, obs, actions, where = fitted
    r2 = probe_r2(quadratic(positions(reader, obs, actions)), where.reshape(-1, 2))
    keypoint_reader._FITTED.clear()
    untrained = KeypointReader(frames=1, parts=2, steps=1, batch=16, progress=False)
    untrained.fit_episodes(obs)
    before = probe_r2(quadratic(positions(untrained, obs, actions)), where.reshape(-1, 2))
    assert (r2 >= 0.85).all(), r2
    # a spatial softmax of random features already leans to the bright square (R² about
    # 0.75 and 0.9); training moves the keypoints onto it
    assert r2.min() > before.min() + 0.1, (r2, before)


def test_the_record_says_which_keypoints_follow_something(fitted):
    import json

    reader = fitted[0]
    record = json.loads(json.dumps(reader.record()))
    assert record["reader"] == "keypoints" and record["parts"] == 2
    assert record["live"] == reader.live_.tolist() and len(record["typical_spread"]) == 2
    assert len(record["variance_shares"]) == len(reader.names) // 2
    assert record["summary"].startswith(f"{sum(record['live'])} of 2 keypoints follow")
    with pytest.raises(UserError, match="before fit_episodes"):
        KeypointReader().record()


def test_the_latent_is_positions_rates_and_the_action_held(fitted):
    reader, obs, actions, _ = fitted
    assert not reader.turns_ and reader.circle is None  # a path that fills its middle
    kept = len(reader.names) // 2
    assert 1 <= kept <= 2 * reader.parts
    z, seen = reader.episode(obs[0], actions[0], DT)
    assert z.shape == (obs.shape[1], 2 * kept + 1) and bool(seen.all())
    # the rate is the change of the positions per second since the frame before
    assert torch.allclose(z[1:, kept:2 * kept], (z[1:, :kept] - z[:-1, :kept]) / DT)
    assert torch.allclose(z[1:, -1], actions[0, :, 0])
    # one observation at a time reads as the episode does
    one, _ = reader.latent(obs[0, 3:4], actions[0, 2:3], DT)
    assert torch.allclose(one[0, :kept], z[3, :kept])


def test_a_frame_without_the_part_a_keypoint_follows_is_not_seen(fitted):
    reader, obs, _, _ = fitted
    assert bool(reader.read_seen(obs[:, 5])[1].all())  # the square in every frame
    blank = torch.full_like(obs[0, :4], 0.3)  # the floor alone
    assert not bool(reader.read_seen(blank)[1].any())


def test_a_refit_on_the_same_frames_is_the_same_reader_and_reuses_the_first(fitted):
    reader, obs, actions, _ = fitted
    again = KeypointReader(frames=1, parts=2, steps=300, batch=16, lr=3e-3, progress=False)
    again.fit_episodes(obs)
    assert np.array_equal(positions(again, obs, actions), positions(reader, obs, actions))
    keypoint_reader._FITTED.clear()
    fresh = KeypointReader(frames=1, parts=2, steps=20, batch=8, seed=3, progress=False)
    fresh.fit_episodes(obs)
    keypoint_reader._FITTED.clear()
    twice = KeypointReader(frames=1, parts=2, steps=20, batch=8, seed=3, progress=False)
    twice.fit_episodes(obs)
    assert np.array_equal(positions(fresh, obs, actions), positions(twice, obs, actions))


def test_bad_settings_and_frames_are_refused_with_the_fix(fitted):
    reader, obs, _, _ = fitted
    with pytest.raises(UserError, match="parts=0"):
        KeypointReader(parts=0)
    with pytest.raises(UserError, match=r"min_share=1\.5"):
        KeypointReader(min_share=1.5)
    with pytest.raises(UserError, match="spread=0"):
        KeypointReader(spread=0)
    with pytest.raises(UserError, match="before fit_episodes"):
        KeypointReader().read(obs[0])
    with pytest.raises(UserError, match="expected episodes"):
        KeypointReader().fit_episodes(obs[0])
    with pytest.raises(UserError, match="fitted on observations"):
        reader.read(torch.zeros(2, 1, SIZE + 4, SIZE + 4))


def small(store, **kw) -> KeypointReader:
    return KeypointReader(frames=1, parts=2, steps=12, batch=8, seed=5, progress=False,
                          store=store, **kw)


def test_a_stored_fit_is_loaded_by_a_later_process_instead_of_trained(fitted, tmp_path,
                                                                      monkeypatch):
    _, obs, actions, _ = fitted
    keypoint_reader._FITTED.clear()
    first = small(tmp_path / "readers").fit_episodes(obs)
    stored = list((tmp_path / "readers").glob("keypoints-*.pt"))
    assert len(stored) == 1 and not list((tmp_path / "readers").glob("*.partial.pt"))
    keypoint_reader._FITTED.clear()  # (as a new process would find it)

    def no_training(*args, **kwargs):
        raise AssertionError("trained again")

    monkeypatch.setattr(KeypointReader, "_train", no_training)
    again = small(tmp_path / "readers").fit_episodes(obs)
    assert np.array_equal(positions(again, obs, actions), positions(first, obs, actions))
    assert again.loss_ == first.loss_
    # other settings, or other frames, are another fit
    keypoint_reader._FITTED.clear()
    with pytest.raises(AssertionError, match="trained again"):
        small(tmp_path / "readers", lr=2e-3).fit_episodes(obs)
    with pytest.raises(AssertionError, match="trained again"):
        small(tmp_path / "readers", spread=0.05).fit_episodes(obs)
    # the default spread, given, is the stored fit's own
    keypoint_reader._FITTED.clear()
    small(tmp_path / "readers", spread=0.1).fit_episodes(obs)
    with pytest.raises(AssertionError, match="trained again"):
        small(tmp_path / "readers").fit_episodes(obs[:, :-1])


def test_a_stopped_fit_resumes_from_its_checkpoint_to_the_same_networks(fitted, tmp_path,
                                                                         monkeypatch):
    _, obs, actions, _ = fitted
    monkeypatch.setattr(keypoint_reader, "CHECKPOINT", 5)
    keypoint_reader._FITTED.clear()
    through = small(tmp_path / "through").fit_episodes(obs)

    keypoint_reader._FITTED.clear()
    step, updates = torch.optim.Adam.step, []

    def stopped(self, *args, **kwargs):
        if len(updates) == 7:  # after the checkpoint at 5 updates
            raise KeyboardInterrupt
        updates.append(1)
        return step(self, *args, **kwargs)

    monkeypatch.setattr(torch.optim.Adam, "step", stopped)
    with pytest.raises(KeyboardInterrupt):
        small(tmp_path / "stopped").fit_episodes(obs)
    monkeypatch.setattr(torch.optim.Adam, "step", step)
    assert list((tmp_path / "stopped").glob("*.partial.pt"))
    assert not [p for p in (tmp_path / "stopped").glob("keypoints-*.pt")
                if not p.name.endswith(".partial.pt")]

    counted = []

    def counting(self, *args, **kwargs):
        counted.append(1)
        return step(self, *args, **kwargs)

    monkeypatch.setattr(torch.optim.Adam, "step", counting)
    resumed = small(tmp_path / "stopped").fit_episodes(obs)
    assert len(counted) == 12 - 5  # from the checkpoint, not from the start
    assert np.array_equal(positions(resumed, obs, actions), positions(through, obs, actions))
    assert not list((tmp_path / "stopped").glob("*.partial.pt"))


def test_a_damaged_stored_fit_or_a_file_for_a_store_is_one_error_naming_it(fitted,
                                                                            tmp_path):
    _, obs, _, _ = fitted
    keypoint_reader._FITTED.clear()
    small(tmp_path / "readers").fit_episodes(obs)
    stored = next((tmp_path / "readers").glob("keypoints-*.pt"))
    stored.write_bytes(b"not a fit")
    keypoint_reader._FITTED.clear()
    with pytest.raises(UserError, match=f"{stored.name}.*delete it"):
        small(tmp_path / "readers").fit_episodes(obs)
    (tmp_path / "file").write_text("")
    with pytest.raises(UserError, match="is a file"):
        small(tmp_path / "file")


def turning(n: int, steps: int, seed: int, size: int = 32
            ) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
    """Episodes of a bright blob (σ 2 px) going round a circle of radius 9 px at its own
    speed (either way) on size × size frames (keypoint maps of a quarter of that: a finer
    circle than 16 px frames' 4 cells a side can show): observations (E, T+1, 1, S, S),
    actions (E, T, 1) and its angle (E, T+1)."""
    rng = np.random.default_rng(seed)
    speed = rng.choice([-1, 1], (n, 1)) * rng.uniform(0.3, 0.6, (n, 1))
    angle = rng.uniform(0, 2 * np.pi, (n, 1)) + speed * np.arange(steps + 1)[None]
    col = size / 2 - 0.5 + 9 * np.cos(angle)
    row = size / 2 - 0.5 + 9 * np.sin(angle)
    grid = np.arange(size, dtype=np.float64)
    d2 = ((grid[None, None, :, None] - row[..., None, None]) ** 2
          + (grid[None, None, None, :] - col[..., None, None]) ** 2)
    frames = (0.3 + 0.7 * np.exp(-d2 / (2 * 2.0 ** 2)))[:, :, None].astype(np.float32)
    return torch.from_numpy(frames), torch.zeros(n, steps, 1, dtype=torch.float64), angle


def test_a_part_going_round_a_pivot_is_read_as_its_angle_and_turn():
    obs, actions, angle = turning(8, 20, 1)
    keypoint_reader._FITTED.clear()
    reader = KeypointReader(frames=1, parts=2, steps=300, batch=16, lr=3e-3, progress=False)
    reader.fit_episodes(obs)
    assert reader.turns_ and reader.circle == (0, 1)
    assert reader.names == ("cos φ", "sin φ", "φ'")
    z = [reader.episode(obs[e], actions[e], DT)[0] for e in range(len(obs))]
    assert all(zi.shape == (obs.shape[1], 4) for zi in z)
    phi = torch.cat([torch.atan2(zi[:, 1], zi[:, 0]) for zi in z]).numpy()
    # the angle about the pivot, up to where it starts and which way it counts
    agree = max(abs(np.exp(1j * (sign * phi - angle.reshape(-1))).mean()) for sign in (1, -1))
    assert agree > 0.95, agree
    # the turn per second from the frame before: the blob's speed, either way (a frame's
    # angle is a few hundredths of a radian off, a tenth of a step's turn)
    rate = np.concatenate([zi[1:, 2].numpy() for zi in z])
    true = np.diff(angle, axis=1).reshape(-1) / DT
    sign = np.sign(np.mean(rate * true))
    assert np.median(np.abs(sign * rate - true)) < 0.3 * np.abs(true).mean()
    # (angle is read after the fit: the same keypoints, reused, read as positions)
    plain = KeypointReader(frames=1, parts=2, steps=300, batch=16, lr=3e-3, progress=False,
                           angle=False).fit_episodes(obs)
    assert not plain.turns_ and plain.circle is None and len(plain.names) == 4
    assert all(torch.equal(a, b) for a, b in zip(reader.net_.state_dict().values(),
                                                 plain.net_.state_dict().values(), strict=True))
    with pytest.raises(UserError, match="angle='yes'"):
        KeypointReader(angle="yes")
