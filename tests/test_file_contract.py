"""What a data file, a study folder and an interrupted command promise a hostile user: a
group of the user's own in a data file is left alone, every channel count previews, an
`executed` flag is a boolean, a study never writes over another study's results, and Ctrl-C
says how to continue in words the same command accepts."""

from __future__ import annotations

import json
import math
from pathlib import Path

import h5py
import numpy as np
import pytest

from latent_sindy.data import SequenceData
from latent_sindy.data.preview import save_preview
from latent_sindy.data.store import read_sequences, write_sequences
from latent_sindy.errors import UserError


def _data(n: int = 4, channels: int = 1, h: int = 6, w: int = 6) -> SequenceData:
    rng = np.random.default_rng(0)
    images = rng.integers(0, 256, (n, 3, channels, h, w), dtype=np.uint8)
    actions = rng.uniform(-1, 1, (n, 2, 2)).astype(np.float32)
    return SequenceData(images, actions, [-1, -1], [1, 1])


def test_a_group_of_the_users_own_in_a_data_file_is_left_alone(tmp_path: Path) -> None:
    path = tmp_path / "d.h5"
    write_sequences(path, _data())
    with h5py.File(path, "a") as f:
        f.create_group("meta").attrs["who"] = "me"
    assert read_sequences(path).n == 4


def test_a_group_under_a_datasets_name_is_refused_naming_it(tmp_path: Path) -> None:
    path = tmp_path / "d.h5"
    write_sequences(path, _data())
    with h5py.File(path, "a") as f:
        if "states" in f:
            del f["states"]
        f.create_group("states")
    with pytest.raises(UserError, match="/states is an HDF5 group"):
        read_sequences(path)


@pytest.mark.parametrize("channels", [1, 2, 3, 5])
def test_every_channel_count_previews(tmp_path: Path, channels: int) -> None:
    out = save_preview(_data(channels=channels), tmp_path / "p.png")
    assert out.stat().st_size > 0


def test_a_file_without_pixels_or_sequences_is_refused() -> None:
    with pytest.raises(UserError, match="at least one pixel"):
        _data(h=0)
    empty = SequenceData(np.zeros((0, 3, 1, 4, 4), np.uint8), np.zeros((0, 2, 1), np.float32),
                         [-1], [1])
    with pytest.raises(UserError, match="nothing to preview"):
        save_preview(empty, "unused.png")


@pytest.mark.parametrize("stored", [np.array([[1, 0], [0, 1], [1, 1], [0, 0]], np.int64),
                                    np.ones((4, 2), bool)])
def test_executed_flags_stored_as_booleans_or_0_1_are_read(tmp_path: Path, stored) -> None:
    path = tmp_path / "d.h5"
    write_sequences(path, _data())
    with h5py.File(path, "a") as f:
        f["executed"] = stored
    assert read_sequences(path).executed.dtype == np.bool_


def test_an_executed_flag_of_7_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "d.h5"
    write_sequences(path, _data())
    with h5py.File(path, "a") as f:
        f["executed"] = np.full((4, 2), 7, np.int64)
    with pytest.raises(UserError, match="executed must hold booleans"):
        read_sequences(path)


@pytest.mark.parametrize("period", [math.inf, -1.0, 0.0])
def test_a_state_period_must_be_finite_and_positive(period: float) -> None:
    images = np.zeros((2, 3, 1, 4, 4), np.uint8)
    with pytest.raises(UserError, match="state_periods"):
        SequenceData(images, np.zeros((2, 2, 1), np.float32), [-1], [1],
                     states=np.zeros((2, 3, 1), np.float32), state_periods=[period])


def test_a_study_refuses_a_folder_that_holds_another_study(tmp_path: Path) -> None:
    from latent_sindy.study.runner import run_study
    from latent_sindy.study.settings import StudySettings

    out = tmp_path / "study"
    out.mkdir()
    (out / "summary.json").write_text(json.dumps({"world": "pendulum", "rows": []}))
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    with pytest.raises(UserError, match="holds the pendulum study"):
        run_study(StudySettings(world="pendulum-video", scale="tiny", out=out),
                  say=lambda *a, **k: None)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_the_push_study_enters_through_its_reproduce_hook_as_every_world_s(
        tmp_path: Path, monkeypatch) -> None:
    """`latent-sindy reproduce` runs the default world's study as any other: its plug-in's
    ``reproduce(scale, out, seeds, device, threads, say, **options)``, the push study's flags
    (and the common options it takes) passed by name, what it returns written by the runner."""
    from latent_sindy.cli import main
    from latent_sindy.plugins import get_world
    from latent_sindy.world_study import Table, WorldStudy

    calls = []

    def spy(scale, out, seeds, device, threads, say, **options):
        calls.append((scale, out, seeds, device, threads, options))
        return WorldStudy(title="t", settings={}, seeds=[0], numbers={}, findings=[],
                          tables=[Table("h", ["a"], [["1"]])])

    monkeypatch.setattr(type(get_world("push")), "reproduce",  # (named worlds: new instances)
                        lambda self, *args, **options: spy(*args, **options))
    out = tmp_path / "study"
    assert main(["reproduce", "--scale", "tiny", "--out", str(out), "--models", "sindy2",
                 "--workers", "1", "--seeds", "3"]) == 0
    assert calls == [("tiny", out, (3,), "auto", 1, {
        "workers": 1, "executor": "local", "ray_address": None, "gpus": 0.0,
        "models": ("sindy2",)})]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["world"] == "push" and (out / "table.md").exists()
    assert main(["reproduce", "--world", "paper", "--scale", "tiny", "--out",
                 str(tmp_path / "paper")]) == 0  # a named world of push: push's study
    assert len(calls) == 2


@pytest.mark.parametrize("argv, says", [
    (["train", "--out", "r"], "with --resume added"),
    (["train", "--out", "r", "--resume"], "re-run the same command to resume"),
    (["train", "--out", "r", "--overwrite"], "--resume in place of --overwrite"),
    (["reproduce"], "re-run the same command to resume"),
])
def test_ctrl_c_says_how_to_continue_in_words_the_command_accepts(argv, says: str) -> None:
    from latent_sindy.cli import _how_to_continue

    assert says in _how_to_continue(argv)
