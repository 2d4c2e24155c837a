"""Collection is deterministic, parallel, resumable, and never leaves a broken file."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from latent_sindy.data import read_sequences, write_sequences
from latent_sindy.errors import UserError
from latent_sindy.worlds.push.collect import CollectionPlan, collect

PLAN = CollectionPlan(trajectories=6, steps=2, seed=3, val_fraction=1 / 3, test_fraction=1 / 6)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted single-process collection of PLAN."""
    path = tmp_path_factory.mktemp("ref") / "ref.h5"
    collect(path, PLAN, workers=1)
    return read_sequences(path)


def same_data(a, b) -> bool:
    return all(np.array_equal(getattr(a, k), getattr(b, k))
               for k in ("images", "actions", "poses", "split_ids"))


def test_collected_file_is_valid_and_shows_motion(reference):
    assert reference.images.shape == (6, 3, 1, 32, 32)
    assert reference.split_counts() == {"train": 3, "val": 2, "test": 1}
    assert reference.seed == 3
    moved = np.linalg.norm(np.diff(reference.poses[..., :2], axis=1), axis=-1) > 0.005
    changed = np.abs(np.diff(reference.images.astype(int), axis=1)).sum(axis=(2, 3, 4)) > 0
    assert moved.mean() > 0.5
    assert np.array_equal(moved, moved & changed)  # every real move shows in the image


def test_same_seed_same_data_with_two_workers(tmp_path, reference):
    path = tmp_path / "par.h5"
    collect(path, PLAN, workers=2)
    assert same_data(read_sequences(path), reference)


def test_other_seed_other_data(tmp_path, reference):
    path = tmp_path / "other.h5"
    collect(path, CollectionPlan(6, 2, seed=4, val_fraction=1 / 3, test_fraction=1 / 6), 1)
    assert not np.array_equal(read_sequences(path).actions, reference.actions)


def test_resume_after_kill(tmp_path, reference):
    out = tmp_path / "killed.h5"
    partial = tmp_path / "killed.h5.partial"
    cmd = [sys.executable, "-m", "latent_sindy.cli", "collect", "--out", str(out),
           "--trajectories", "6", "--steps", "2", "--seed", "3", "--workers", "1",
           "--val-fraction", str(1 / 3), "--test-fraction", str(1 / 6), "--no-progress"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 120
        while len(list(partial.glob("traj_*.npz"))) < 2:
            assert proc.poll() is None, "collection ended before it could be killed"
            assert time.time() < deadline
            time.sleep(0.02)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait()
    assert not out.exists()  # nothing half-done under the final name
    done = len(list(partial.glob("traj_*.npz")))
    assert 2 <= done < 6
    collect(out, PLAN, workers=1)  # the same command again finishes the job
    assert same_data(read_sequences(out), reference)
    assert not partial.exists()


def test_damaged_journal_entry_is_redone(tmp_path, reference, monkeypatch):
    out = tmp_path / "d.h5"

    def fail_at_assembly(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr("latent_sindy.worlds.push.collect.write_sequences", fail_at_assembly)
    with pytest.raises(OSError):
        collect(out, PLAN, workers=1)
    assert not out.exists()
    entries = sorted((tmp_path / "d.h5.partial").glob("traj_*.npz"))
    assert len(entries) == 6
    entries[2].write_bytes(entries[2].read_bytes()[:100])  # a torn file, as after a crash
    monkeypatch.setattr("latent_sindy.worlds.push.collect.write_sequences", write_sequences)
    collect(out, PLAN, workers=1)
    assert same_data(read_sequences(out), reference)


def test_complete_file_is_kept_and_other_settings_refused(tmp_path, reference):
    out = tmp_path / "d.h5"
    collect(out, PLAN, workers=1)
    stamp = out.stat().st_mtime_ns
    collect(out, PLAN, workers=1)  # nothing to do
    assert out.stat().st_mtime_ns == stamp
    with pytest.raises(UserError, match="other collection settings"):
        collect(out, CollectionPlan(7, 2, seed=3), workers=1)
    assert out.stat().st_mtime_ns == stamp


def test_interrupted_run_with_other_settings_is_refused(tmp_path):
    out = tmp_path / "d.h5"
    partial = Path(str(out) + ".partial")
    partial.mkdir()
    (partial / "plan.json").write_text('{"trajectories": 99}')
    with pytest.raises(UserError, match="other settings"):
        collect(out, PLAN, workers=1)
    assert (partial / "plan.json").read_text() == '{"trajectories": 99}'


def test_foreign_file_at_out_is_not_touched(tmp_path):
    out = tmp_path / "d.h5"
    out.write_bytes(b"somebody's notes")
    with pytest.raises(UserError, match="not a usable trajectory file"):
        collect(out, PLAN, workers=1)
    assert out.read_bytes() == b"somebody's notes"


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"trajectories": 0}, "--trajectories 0"),
        ({"steps": 0}, "--steps 0"),
        ({"seed": -1}, "--seed -1"),
        ({"val_fraction": 1.5}, "--val-fraction 1.5"),
        ({"trajectories": 2, "val_fraction": 0.5, "test_fraction": 0.5}, "no training"),
    ],
)
def test_impossible_plans(kwargs, match):
    with pytest.raises(UserError, match=match):
        CollectionPlan(**kwargs)


def test_negative_workers(tmp_path):
    with pytest.raises(UserError, match="--workers -1"):
        collect(tmp_path / "d.h5", PLAN, workers=-1)
    assert not any(tmp_path.iterdir())


class _RecordingEnv:
    """Stands in for PandaPushEnv: records the actions it is given, simulates nothing."""

    def __init__(self) -> None:
        self.actions: list[np.ndarray] = []

    def reset(self, seed=None):
        return np.zeros((1, 32, 32), np.uint8), {"pose": np.zeros(3)}

    def step(self, a):
        self.actions.append(np.asarray(a))
        info = {"pose": np.zeros(3), "push_executed": True}
        return np.zeros((1, 32, 32), np.uint8), 0.0, False, False, info


@pytest.mark.parametrize("world", ["symmetric", "paper"])
def test_actions_are_drawn_from_the_worlds_own_box(world):
    from latent_sindy.worlds.push.collect import collect_one
    from latent_sindy.worlds.push.config import PushEnvConfig

    cfg = PushEnvConfig.named(world)
    plan = CollectionPlan(trajectories=1, steps=200, seed=0, val_fraction=0, test_fraction=0,
                          env=cfg)
    env = _RecordingEnv()
    item = collect_one(env, 0, plan)
    a = item["actions"]
    assert a.shape == (200, cfg.action_dim) and a.dtype == np.float32
    assert np.array_equal(np.stack(env.actions), a)
    low, high = np.array(cfg.action_low), np.array(cfg.action_high)
    assert np.all(a >= low - 1e-6) and np.all(a <= high + 1e-6)
    # uniform over the whole box: the samples reach near both ends of every component
    span = (a.max(axis=0) - a.min(axis=0)) / (high - low)
    assert np.all(span > 0.9)
