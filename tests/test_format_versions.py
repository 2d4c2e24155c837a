"""Files of another format version (docs/compatibility.md): a run folder (config.json,
model.pt, checkpoint.pt) or a data file written by an earlier latent-sindy is refused with
one line naming the file and saying to retrain or re-collect; nothing reads it as something
else. What latent-sindy writes now carries the current versions."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from latent_sindy import LatentSINDy, SequenceData
from latent_sindy.cli import main
from latent_sindy.data import read_sequences
from latent_sindy.data.store import FORMAT, FORMAT_VERSION, write_sequences
from latent_sindy.errors import UserError
from latent_sindy.training import RunDir, load_run
from latent_sindy.training.record import RUN_FORMAT_VERSION

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _data() -> SequenceData:
    images = np.random.default_rng(0).integers(0, 256, (6, 4, 1, 8, 8), dtype=np.uint8)
    actions = np.random.default_rng(1).uniform(-1, 1, (6, 3, 2)).astype(np.float32)
    return SequenceData(images, actions, [-1, -1], [1, 1])


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """A finished run folder of one epoch, with its checkpoint."""
    out = tmp_path_factory.mktemp("run") / "run"
    LatentSINDy(2, seed=0, encoder="mlp", decoder="mlp", order=1, include_sine=False).fit(
        _data(), epochs=1, out=out)
    return out


def _one_line(capsys, argv: list[str]) -> str:
    """The CLI's error for ``argv``: exit status 2 and exactly one line on stderr."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("latent-sindy: error: "), err
    return err


def test_what_is_written_now_carries_the_current_versions(run: Path, tmp_path: Path) -> None:
    assert RUN_FORMAT_VERSION == 3 and FORMAT_VERSION == 3
    assert json.loads((run / RunDir.CONFIG).read_text())["format_version"] == RUN_FORMAT_VERSION
    for name in (RunDir.MODEL, RunDir.CHECKPOINT):
        payload = torch.load(run / name, weights_only=True)
        assert payload["format_version"] == RUN_FORMAT_VERSION, name
    write_sequences(tmp_path / "d.h5", _data())
    with h5py.File(tmp_path / "d.h5") as f:
        assert (f.attrs["format"], f.attrs["format_version"]) == (FORMAT, FORMAT_VERSION)
    assert read_sequences(tmp_path / "d.h5").n == 6


def _copy_run(run: Path, old: Path) -> Path:
    """A copy of the run folder's files in ``old``."""
    old.mkdir()
    for name in RunDir.FILES:
        if (run / name).is_file():
            (old / name).write_bytes((run / name).read_bytes())
    return old


@pytest.mark.parametrize("version", [1, 2, 4, None])
def test_a_run_config_of_another_version_gets_one_line_to_retrain(run: Path, tmp_path: Path,
                                                                  capsys, version) -> None:
    old = _copy_run(run, tmp_path / "old")
    record = json.loads((old / RunDir.CONFIG).read_text())
    record["format_version"] = version
    if version == 1:  # what version 1 held besides: a flat model, no description
        record["env"] = record.pop("description")
    (old / RunDir.CONFIG).write_text(json.dumps(record))
    want = (rf"{old / RunDir.CONFIG} was written by another version of latent-sindy \(run "
            rf"format version {version}; this one reads version 3\): retrain the run")
    for load in (load_run, LatentSINDy.load):
        with pytest.raises(UserError, match=want):
            load(old)
    assert issubclass(UserError, ValueError)
    err = _one_line(capsys, ["equations", str(old)])
    assert str(old / RunDir.CONFIG) in err and "retrain the run" in err


@pytest.mark.parametrize("name", [RunDir.MODEL, RunDir.CHECKPOINT])
def test_a_weights_file_of_another_version_gets_one_line_to_retrain(run: Path, tmp_path: Path,
                                                                    capsys, name) -> None:
    old = _copy_run(run, tmp_path / "old")
    payload = torch.load(old / name, weights_only=True)
    del payload["format_version"]  # as version 2 wrote it
    torch.save(payload, old / name)
    with pytest.raises(UserError, match=rf"{old / name} was written by another version of "
                                        r"latent-sindy \(run format version None; this one "
                                        r"reads version 3\): retrain the run"):
        load_run(old, checkpoint=name == RunDir.CHECKPOINT)
    if name == RunDir.MODEL:
        err = _one_line(capsys, ["equations", str(old)])
        assert str(old / name) in err and "retrain the run" in err


@pytest.mark.parametrize(("fmt", "version"), [(FORMAT, 2), (FORMAT, 4),
                                              ("latent-sindy-trajectories", 1)])
def test_a_data_file_of_another_version_gets_one_line_to_re_collect(tmp_path: Path, capsys,
                                                                    fmt, version) -> None:
    """Version 2 of the sequences, and the pushing world's first format (block poses in
    /poses), which earlier versions read as the same data."""
    path = tmp_path / "old.h5"
    write_sequences(path, _data())
    with h5py.File(path, "a") as f:
        f.attrs["format"] = fmt
        f.attrs["format_version"] = version
    want = (rf"{path} was written by another version of latent-sindy \({fmt} version "
            rf"{version}; this one reads {FORMAT} version 3\): re-collect it")
    with pytest.raises(UserError, match=want):
        read_sequences(path)
    err = _one_line(capsys, ["info", str(path)])
    assert str(path) in err and "re-collect it" in err


def test_a_data_file_of_no_format_is_the_generic_layout(tmp_path: Path) -> None:
    """Files written with h5py alone (no ``format`` attribute) are read by their layout."""
    path = tmp_path / "own.h5"
    data = _data()
    with h5py.File(path, "w") as f:
        f["images"] = data.images
        f["actions"] = data.actions
        f.attrs["action_low"] = [-1.0, -1.0]
        f.attrs["action_high"] = [1.0, 1.0]
    assert read_sequences(path).fingerprint() == data.fingerprint()
