"""A hostile user's inputs: each gets one line on stderr, exit 2, and nothing on disk touched.

Every case runs the command in this process (``cli.main``), so the suite stays fast; the
subprocess behaviour (no traceback, exit status) is covered by tests/test_cli.py.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from latent_sindy.cli import main
from latent_sindy.training.runs import RunDir
from latent_sindy.worlds.push.collect import CollectionPlan, collect

pytestmark = pytest.mark.usefixtures("one_torch_thread")
TINY = ["--latent-dim", "3", "--encoder-hidden", "8", "--decoder-hidden", "16"]


def snapshot(root: Path) -> dict[str, str]:
    """Every file under ``root`` with its content hash (folders too, as "dir")."""
    out = {}
    for p in sorted(root.rglob("*")):
        out[str(p.relative_to(root))] = ("dir" if p.is_dir()
                                         else hashlib.sha256(p.read_bytes()).hexdigest())
    return out


def refused(capsys, argv: list[str], *needles: str) -> str:
    """Run the command; assert exit 2 with one error line (containing ``needles``)."""
    rc = main(argv)
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip() and "it/s" not in ln
             and "traj/s" not in ln]
    assert rc == 2, err
    assert len(lines) == 1 and lines[0].startswith("latent-sindy: error:"), err
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> Path:
    """A tiny data file and a finished tiny SINDy run beside it, with a control folder."""
    root = tmp_path_factory.mktemp("world")
    data = collect(root / "data.h5", CollectionPlan(trajectories=3, steps=2, val_fraction=0.34,
                                                    test_fraction=0.0), workers=1)
    code = main(["train", "sindy", "--data", str(data), "--out", str(root / "run"),
                 "--epochs", "1", "--no-progress", *TINY])
    assert code == 0
    assert main(["control", str(root / "run"), "--max-steps", "1", "--samples", "4",
                 "--horizon", "1", "--gif-episodes", "0", "--no-progress"]) == 0
    return root


@pytest.fixture
def scratch(world: Path, tmp_path: Path) -> Path:
    """A copy of the world for a test that may (wrongly) change it."""
    shutil.copytree(world, tmp_path / "w")
    return tmp_path / "w"


# ----------------------------------------------------------------------------- data files
@pytest.mark.parametrize("bad", [np.array([0, 1, -1]), np.array([0.0, 1.0, 0.5])])
def test_1_split_labels_outside_0_1_2_are_refused(scratch: Path, capsys, bad) -> None:
    path = scratch / "data.h5"
    with h5py.File(path, "r+") as f:
        del f["split"]
        f["split"] = bad
    refused(capsys, ["info", str(path)], str(path), "split labels")
    refused(capsys, ["train", "--data", str(path), "--out", str(scratch / "r2"), "--no-progress"],
            "split labels")
    assert not (scratch / "r2").exists()


def test_2_3_preview_never_writes_over_a_folder_or_its_input(scratch: Path, capsys) -> None:
    before = snapshot(scratch)
    refused(capsys, ["preview", str(scratch / "data.h5"), "--out", str(scratch / "run")],
            "is a folder")
    refused(capsys, ["preview", str(scratch / "data.h5"), "--out", str(scratch / "data.h5")],
            "is the input file")
    refused(capsys, ["preview", str(scratch / "data.h5"), "--out", str(scratch / "x.h5")],
            "must end in .png")
    assert snapshot(scratch) == before


# ----------------------------------------------------------------------------- the system
def test_4_operating_system_errors_are_one_line_naming_the_path(scratch: Path, capsys) -> None:
    before = snapshot(scratch)
    blocker = scratch / "data.h5"  # a file where a folder would have to be
    refused(capsys, ["collect", "--out", str(blocker / "new.h5"), "--trajectories", "1",
                     "--steps", "1", "--workers", "1", "--no-progress"], str(blocker))
    refused(capsys, ["preview", str(blocker), "--out", str(blocker / "p.png")], str(blocker))
    refused(capsys, ["train", "--data", str(blocker), "--out", str(blocker / "run"),
                     "--no-progress", *TINY], str(blocker))
    assert snapshot(scratch) == before


@pytest.mark.skipif(os.geteuid() == 0, reason="permissions do not bind root")
def test_4_a_read_only_folder_is_one_line(scratch: Path, capsys) -> None:
    ro = scratch / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        refused(capsys, ["preview", str(scratch / "data.h5"), "--out", str(ro / "p.png")],
                str(ro))
        refused(capsys, ["train", "--data", str(scratch / "data.h5"), "--out", str(ro / "run"),
                         "--no-progress", *TINY], str(ro))
    finally:
        ro.chmod(0o700)


def test_4_a_closed_pipe_ends_quietly(world: Path) -> None:
    r = subprocess.run(f"{sys.executable} -m latent_sindy.cli --help | head -c 10",
                       shell=True, capture_output=True, text=True, timeout=120)
    assert "Traceback" not in r.stderr and "BrokenPipe" not in r.stderr


def test_5_collection_that_cannot_fit_in_memory_is_refused_up_front(tmp_path: Path,
                                                                    capsys) -> None:
    refused(capsys, ["collect", "--out", str(tmp_path / "a.h5"), "--trajectories", "4",
                     "--steps", "1", "--image-size", "100000"], "--image-size 100000")
    refused(capsys, ["collect", "--out", str(tmp_path / "a.h5"), "--trajectories", "100000000",
                     "--steps", "1000", "--image-size", "512"], "GiB of memory")
    assert list(tmp_path.iterdir()) == []  # no .partial folder to block the next command


# ----------------------------------------------------------------------------- train
@pytest.mark.parametrize("flag", [["--lambda-l1", "nan"], ["--weight-decay", "inf"],
                                  ["--lr", "nan"], ["--prune-below", "-inf"],
                                  ["--action-dim", "5"]])
def test_6_7_bad_training_settings_touch_nothing_even_with_overwrite(scratch: Path, capsys,
                                                                     flag) -> None:
    before = snapshot(scratch)
    refused(capsys, ["train", "sindy", "--data", str(scratch / "data.h5"), "--out",
                     str(scratch / "run"), "--overwrite", "--epochs", "1", "--no-progress",
                     *TINY, *flag], flag[0])
    refused(capsys, ["train", "sindy", "--data", str(scratch / "data.h5"), "--out",
                     str(scratch / "new"), "--epochs", "1", "--no-progress", *TINY, *flag],
            flag[0])
    assert snapshot(scratch) == before


def test_d10_a_library_that_cannot_fit_is_refused_from_its_size(scratch: Path,
                                                                 capsys) -> None:
    """An order-2 library on 100000 latents has about 5e9 terms: refused before it is built."""
    before = snapshot(scratch)
    refused(capsys, ["train", "sindy", "--data", str(scratch / "data.h5"), "--out",
                     str(scratch / "big"), "--epochs", "1", "--no-progress", *TINY,
                     "--latent-dim", "100000"], "--latent-dim 100000", "GiB of memory")
    refused(capsys, ["train", "linear", "--data", str(scratch / "data.h5"), "--out",
                     str(scratch / "big"), "--epochs", "1", "--no-progress", *TINY,
                     "--latent-dim", "1000000"], "--latent-dim 1000000", "GiB of memory")
    assert snapshot(scratch) == before


@pytest.mark.parametrize("weight", ["1e308", "1e5"])
def test_d13_a_foreground_weight_beyond_its_bound_is_refused(scratch: Path, capsys,
                                                              weight: str) -> None:
    before = snapshot(scratch)
    refused(capsys, ["train", "sindy", "--data", str(scratch / "data.h5"), "--out",
                     str(scratch / "fg"), "--epochs", "1", "--no-progress", *TINY,
                     "--foreground-weight", weight], f"--foreground-weight {float(weight)}")
    assert snapshot(scratch) == before


def test_d19_a_foreground_weight_on_a_state_model_is_refused(scratch: Path, capsys) -> None:
    before = snapshot(scratch)
    refused(capsys, ["train", "sindy", "state", "--data", str(scratch / "data.h5"), "--out",
                     str(scratch / "st"), "--epochs", "1", "--no-progress",
                     "--foreground-weight", "3"], "--foreground-weight", "image")
    assert snapshot(scratch) == before


def test_overwrite_removes_the_whole_old_run(scratch: Path, capsys) -> None:
    run = RunDir(scratch / "run")
    (run / run.EVALUATION).write_text("{}")
    assert run.control_dirs()
    assert main(["train", "sindy", "--data", str(scratch / "data.h5"), "--out", str(run.path),
                 "--overwrite", "--epochs", "1", "--no-progress", *TINY]) == 0
    assert not run.control_dirs() and not (run / run.EVALUATION).exists() and run.finished


# ----------------------------------------------------------------------------- control
@pytest.mark.parametrize(("flags", "needle"), [
    (["--seed", "-1"], "--seed -1"),
    (["--threads", "2147483648"], "--threads 2147483648"),
    (["--samples", "1000000000"], "GiB of memory"),
    (["--samples", "0"], "samples"),
    (["--sigma", "nan"], "sigma"),
    (["--lambda", "inf"], "lambda"),
])
def test_8_9_bad_control_settings_touch_nothing(scratch: Path, capsys, flags, needle) -> None:
    before = snapshot(scratch)
    refused(capsys, ["control", str(scratch / "run"), "--task", "random", "--no-progress",
                     *flags], needle)
    assert snapshot(scratch) == before


def test_10_control_out_that_is_a_file_is_refused(scratch: Path, capsys) -> None:
    before = snapshot(scratch)
    refused(capsys, ["control", str(scratch / "run"), "--out", str(scratch / "data.h5")],
            "is a file")
    assert snapshot(scratch) == before


def test_11_an_edited_run_config_is_refused_before_any_output(scratch: Path, capsys) -> None:
    path = scratch / "run" / "config.json"
    record = json.loads(path.read_text())
    record["model"]["observation"]["image_size"] = 64
    path.write_text(json.dumps(record))
    before = snapshot(scratch)
    refused(capsys, ["control", str(scratch / "run"), "--task", "random", "--no-progress"],
            "config.json", "edited")
    assert snapshot(scratch) == before


def test_d4_d17_a_cost_the_model_cannot_compute_is_refused_leaving_no_folder(
        scratch: Path, capsys) -> None:
    """Image space needs a decoder of images (a state model decodes poses), pose space a
    pose head; either is refused before the control folder is made."""
    assert main(["train", "sindy", "state", "--data", str(scratch / "data.h5"), "--out",
                 str(scratch / "state"), "--epochs", "1", "--no-progress"]) == 0
    before = snapshot(scratch)
    refused(capsys, ["control", str(scratch / "state"), "--space", "image", "--max-steps", "1",
                     "--no-progress"], "--space image", "state")
    refused(capsys, ["control", str(scratch / "run"), "--space", "pose", "--max-steps", "1",
                     "--no-progress"], "--space pose", "pose head")
    assert snapshot(scratch) == before  # no empty control-paper-image/ or -pose/


def test_equations_of_a_file_says_it_is_a_file(world: Path, capsys) -> None:
    refused(capsys, ["equations", str(world / "data.h5")], "is a file, not a run folder")


# ----------------------------------------------------------------------------- reproduce
def test_12_reproduce_out_that_is_a_file_and_foreign_data(tmp_path: Path, capsys) -> None:
    (tmp_path / "f").write_text("x")
    (tmp_path / "foreign.h5").write_bytes(b"not hdf5")
    before = snapshot(tmp_path)
    refused(capsys, ["reproduce", "--scale", "tiny", "--out", str(tmp_path / "f")], "is a file")
    refused(capsys, ["reproduce", "--scale", "tiny", "--out", str(tmp_path / "out"), "--data",
                     str(tmp_path / "foreign.h5")], "not an HDF5 file")
    assert snapshot(tmp_path) == before  # no empty output folder left behind


def test_13_a_study_never_reuses_models_trained_on_other_data(world: Path, tmp_path: Path
                                                              ) -> None:
    """A finished run is reused only for the data it was trained on."""
    other = collect(tmp_path / "other.h5", CollectionPlan(trajectories=3, steps=2, seed=1,
                                                          val_fraction=0.34, test_fraction=0.0),
                    workers=1)
    run = RunDir(world / "run")
    cfg = run.train_config()
    from latent_sindy.worlds.push.study.jobs import ensure_trained

    assert ensure_trained(cfg) == "reused"
    with pytest.raises(Exception, match=r"other settings or data \(data\.fingerprint"):
        ensure_trained(dataclasses.replace(cfg, data=other))


@pytest.mark.slow
def test_13_reproduce_with_other_data_into_the_same_folder_is_refused(tmp_path: Path) -> None:
    from push_study import run_push

    run_push(tmp_path / "study", scale="tiny", workers=1)
    other = collect(tmp_path / "b.h5", CollectionPlan(trajectories=6, steps=3, seed=5),
                    workers=1)
    with pytest.raises(Exception, match="other settings or data"):
        run_push(tmp_path / "study", scale="tiny", workers=1, data=other)


# ----------------------------------------------------------------------------- properties
NUMBERS = st.one_of(st.integers(-10, 10**12), st.floats(allow_nan=True, allow_infinity=True),
                    st.sampled_from(["nan", "-inf", "1e400", "abc", ""]))
FLAGS = {
    "collect": ["--trajectories", "--steps", "--seed", "--val-fraction", "--test-fraction",
                "--image-size", "--channels", "--workers", "--block-mass", "--block-friction",
                "--success-distance"],
    "train": ["--epochs", "--window", "--batch-size", "--lr", "--weight-decay", "--prune-below",
              "--prune-every", "--checkpoint-every", "--seed", "--lambda-l1",
              "--lambda-pred-x", "--latent-dim", "--action-dim", "--image-size", "--threads",
              "--eval-every"],
    "control": ["--episodes", "--seed", "--max-steps", "--gif-episodes", "--samples",
                "--horizon", "--sigma", "--lambda", "--threads"],
    "reproduce": ["--seeds", "--workers", "--threads", "--data-seed"],
}


@settings(max_examples=40, deadline=None, derandomize=True,  # the same examples in every run
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(command=st.sampled_from(sorted(FLAGS)), values=st.data())
def test_random_settings_get_one_clean_line_and_touch_nothing(world: Path, tmp_path: Path,
                                                              capsys, command: str,
                                                              values) -> None:
    """Whatever the values, a command whose inputs are missing or whose output cannot be
    made answers with exit 2 and one line, and no file appears or changes."""
    flags = values.draw(st.lists(st.sampled_from(FLAGS[command]), min_size=1, max_size=4,
                                 unique=True))
    argv = [command, str(tmp_path / "no-run")] if command == "control" else [command]
    for f in flags:
        v = values.draw(NUMBERS)
        argv += [f, repr(v) if isinstance(v, float) and math.isfinite(v) else str(v)]
    blocker = world / "data.h5"  # a file: nothing can be created below it
    argv += {"collect": ["--out", str(blocker / "x.h5"), "--no-progress"],
             "train": ["--data", str(tmp_path / "missing.h5"), "--out", str(blocker / "r"),
                       "--no-progress"],
             "control": ["--no-progress"],
             "reproduce": ["--scale", "tiny", "--out", str(blocker / "s")]}[command]
    before = snapshot(world)
    try:
        rc = main(argv)
    except SystemExit as e:  # the parser's own exit on an unparsable value
        rc = e.code
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2, (argv, err)
    assert "Traceback" not in err, (argv, err)
    if lines[0].startswith("latent-sindy: error:"):
        assert len(lines) == 1, (argv, err)
    # otherwise it is the parser's own message on an unparsable value (tyro's box)
    assert snapshot(world) == before


def test_control_plans_with_the_worlds_planner_unless_told(world: Path, tmp_path: Path) -> None:
    """No planner option: the study's planner of the run's world (the symmetric push's here);
    any planner option: the user's settings, course defaults for the rest."""
    from latent_sindy.worlds.push.planner import PLANNERS

    base = ["control", str(world / "run"), "--max-steps", "1", "--gif-episodes", "0",
            "--no-progress"]
    assert main([*base, "--out", str(tmp_path / "a")]) == 0
    assert main([*base, "--horizon", "2", "--out", str(tmp_path / "b")]) == 0
    a = json.loads((tmp_path / "a" / "results.json").read_text())["settings"]["mppi"]
    b = json.loads((tmp_path / "b" / "results.json").read_text())["settings"]["mppi"]
    world_planner = PLANNERS["symmetric"]
    assert (a["samples"], a["horizon"], tuple(a["sigma"])) == (
        world_planner.samples, world_planner.horizon, world_planner.sigma)
    assert (b["samples"], b["horizon"]) == (100, 2)
