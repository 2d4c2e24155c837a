"""The trajectory file round-trips and refuses every kind of bad file with one clear line."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from latent_sindy.data import read_sequences, write_sequences
from latent_sindy.data.store import FORMAT
from latent_sindy.errors import UserError
from latent_sindy.worlds.push.config import PushEnvConfig
from latent_sindy.worlds.push.data import push_data
from synthetic import make_trajectories


@pytest.mark.parametrize("channels", [1, 3])
def test_round_trip(tmp_path, channels):
    data = make_trajectories(channels=channels)
    path = tmp_path / "d.h5"
    write_sequences(path, data)
    back = read_sequences(path)
    for name in ("images", "actions", "poses", "split_ids"):
        assert np.array_equal(getattr(back, name), getattr(data, name)), name
    assert back.images.dtype == np.uint8 and back.actions.dtype == np.float32
    assert back.world_config == data.world_config and back.seed == data.seed
    with h5py.File(path) as f:
        assert f.attrs["format"] == FORMAT
        assert f.attrs["pixel_mean"] == pytest.approx(data.pixel_stats()[0])
        assert "package_version" in f.attrs and "created" in f.attrs


def test_splits_and_training_statistics(trajectories):
    assert trajectories.split_counts() == {"train": 2, "val": 2, "test": 2}
    train = trajectories.split("train")
    assert train.n == 2 and np.all(train.split_ids == 0)
    # statistics come from the training split only
    mean, std = trajectories.pixel_stats()
    assert mean == pytest.approx(train.images.astype(float).mean(), rel=1e-12)
    assert std == pytest.approx(train.images.astype(float).std(), rel=1e-12)
    trajectories.images[trajectories.split_ids == 1] = 0
    assert trajectories.pixel_stats()[0] == pytest.approx(mean)
    with pytest.raises(UserError, match="split 'dev'"):
        trajectories.split("dev")


def test_write_is_atomic_and_leaves_no_temporary(tmp_path, trajectories, monkeypatch):
    path = tmp_path / "d.h5"
    path.write_bytes(b"previous content")

    def disk_full(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(h5py.Group, "create_dataset", disk_full)
    with pytest.raises(OSError, match="disk full"):
        write_sequences(path, trajectories)
    assert path.read_bytes() == b"previous content"
    assert [p.name for p in tmp_path.iterdir()] == ["d.h5"]


def _error(path) -> str:
    with pytest.raises(UserError) as e:
        read_sequences(path)
    msg = str(e.value)
    assert "\n" not in msg and str(path) in msg
    return msg


def test_missing_file(tmp_path):
    assert "does not exist" in _error(tmp_path / "nope.h5")


def test_foreign_and_truncated_files(tmp_path, trajectories):
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"\x00not hdf5 at all" * 100)
    assert "not an HDF5 file" in _error(junk)

    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as f:
        f["x"] = np.zeros(3)
    assert "lacks the dataset 'images'" in _error(foreign)

    good = tmp_path / "good.h5"
    write_sequences(good, trajectories)
    cut = tmp_path / "cut.h5"
    raw = good.read_bytes()
    cut.write_bytes(raw[: len(raw) // 2])
    msg = _error(cut)
    assert "re-collect" in msg or "not an HDF5" in msg


def write_version_1(path, t) -> None:
    """A pushing-world file as version 1 wrote it: block poses in /poses, the world's
    settings in the attribute env_config."""
    import json

    from latent_sindy.configs import to_json

    with h5py.File(path, "w") as f:
        f["images"], f["actions"], f["poses"] = t.images, t.actions, t.poses
        f["split"] = t.split_ids
        f.attrs.update(format="latent-sindy-trajectories", format_version=1, seed=0,
                       env_config=json.dumps(to_json(t.world_config)), collection="{}")


def test_version_1_files_are_refused_with_one_line_to_re_collect(tmp_path, trajectories):
    """The pushing world's files of format version 1 (earlier versions read them as the
    same data) get one line naming the file: re-collect it."""
    path = tmp_path / "v1.h5"
    write_version_1(path, trajectories)
    msg = _error(path)
    assert msg == (f"{path} was written by another version of latent-sindy "
                   "(latent-sindy-trajectories version 1; this one reads "
                   "latent-sindy-sequences version 3): re-collect it")


def _tamper(path, **datasets):
    with h5py.File(path, "a") as f:
        for name, value in datasets.items():
            del f[name]
            f[name] = value


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (lambda t: {"actions": t.actions[:, :-1]}, "actions have shape"),
        (lambda t: {"images": t.images.astype(np.float32)}, "must lie in [0, 1]"),
        (lambda t: {"images": t.images.astype(np.float32) / 255}, "images are uint8"),
        (lambda t: {"states": t.poses[:-1]}, "states have shape"),
        (lambda t: {"actions": np.where(np.arange(3) == 1, np.nan, t.actions)}, "NaN"),
        (lambda t: {"actions": t.actions + np.array([0, 0, 2.0], np.float32)}, "outside"),
        (lambda t: {"split": np.full(t.n, 7, np.uint8)}, "split labels"),
    ],
)
def test_wrong_contents(tmp_path, trajectories, change, expected):
    path = tmp_path / "d.h5"
    write_sequences(path, trajectories)
    _tamper(path, **change(trajectories))
    assert expected in _error(path)


def test_missing_dataset_and_version(tmp_path, trajectories):
    path = tmp_path / "d.h5"
    write_sequences(path, trajectories)
    with h5py.File(path, "a") as f:
        del f["states"]
    assert "state_names or state_periods given without states" in _error(path)
    write_sequences(path, trajectories)
    with h5py.File(path, "a") as f:
        f.attrs["format_version"] = 99
    assert "latent-sindy-sequences version 99" in _error(path)
    assert _error(path).endswith("re-collect it")


def test_channels_must_match_recorded_environment():
    t = make_trajectories(channels=1)
    with pytest.raises(UserError, match="recorded environment"):
        push_data(t.images, t.actions, t.poses, t.split_ids, PushEnvConfig(channels=3))


# ---------------------------------------------------------------- the world owns the action box
def test_a_world_record_with_an_unknown_setting_is_refused(tmp_path, trajectories):
    import json

    path = tmp_path / "edited.h5"
    write_sequences(path, trajectories)
    assert read_sequences(path).world_config == trajectories.world_config
    with h5py.File(path, "a") as f:
        record = json.loads(f.attrs["world_record"])
        record["env_config"]["gravity"] = 3
        f.attrs["world_record"] = json.dumps(record)
    assert "env_config: unknown settings ['gravity']" in _error(path)


def test_actions_are_checked_against_the_recorded_worlds_box(tmp_path):
    t = make_trajectories()
    t.actions[0, 1, 1] = 2.0  # a push direction beyond +-pi/2: any direction is fine ...
    push_data(t.images, t.actions, t.poses, t.split_ids, PushEnvConfig())
    with pytest.raises(UserError, match=r"action 1 \(phi\) of step 1 of trajectory 0 is 2") as e:
        # ... but not in the paper's world, where phi is relative to the block within +-pi/2
        push_data(t.images, t.actions, t.poses, t.split_ids, PushEnvConfig.named("paper"))
    assert "'paper' world" in str(e.value)


def test_actions_must_have_the_worlds_size():
    t = make_trajectories()
    wide = np.concatenate([t.actions, np.zeros((*t.actions.shape[:2], 1), np.float32)], axis=2)
    with pytest.raises(UserError, match=r"expected \(6, 4, 3\) \(p, psi, ell"):
        push_data(t.images, wide, t.poses, t.split_ids, PushEnvConfig())
