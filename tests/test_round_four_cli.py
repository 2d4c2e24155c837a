"""Round four of a hostile user, on the command line and the studies: world settings that
reach their study (or are refused), seeds out of range, a missing optional dependency, the
benchmark scripts' arguments, and advice and limits of `equations`, `--threads` and
`collect --workers`. Every refusal is one line, exit 2, and leaves nothing on disk."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from latent_sindy.cli import main
from latent_sindy.worlds.pendulum import study as study_module

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _refused(capsys, *args: str) -> str:
    """Run the command; assert exit 2 with one error line, and return that line."""
    code = main(list(args))
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("latent-sindy: error:"), lines
    return lines[0]


# ------------------------------------------------------------------ 1: --world-config
def _fake_study(seen: list):
    """A stand-in for the pendulum study: records the settings it was run on."""
    from latent_sindy.control.world import Task
    from latent_sindy.worlds.pendulum.swing_up import SwingUp

    def run(cfg, report=print):
        seen.append(cfg)
        episode = SwingUp(Task(np.zeros(2), np.zeros(2)), np.zeros((2, 2)), np.zeros((1, 1)),
                          1.0, True)
        row = study_module.ModelRow("state SINDy (true state)", [episode], ["x' = 0"])
        return study_module.StudyResult(cfg, rows=[row])

    return run


def test_1_pendulum_world_config_reaches_the_study_and_its_identity(tmp_path, monkeypatch):
    """`reproduce --world pendulum --world-config ...`: the camera and the tasks' starts are
    the study's (recorded so), and another value is another study, not a reused one."""
    seen: list = []
    monkeypatch.setattr(study_module, "compare_swing_ups", _fake_study(seen))
    out = tmp_path / "study"

    def run(*pairs: str) -> dict:
        assert main(["reproduce", "--world", "pendulum", "--scale", "tiny", "--out", str(out),
                     "--device", "cpu", "--world-config", *pairs]) == 0
        return json.loads((out / "summary.json").read_text())["study"]["study"]

    recorded = run("image_size=24", "start=hanging", "perturbation=0.2")
    assert (seen[-1].image_size, seen[-1].start, seen[-1].perturbation) == (24, "hanging", 0.2)
    assert seen[-1].world_config().perturbation == 0.2  # the tasks' world
    assert (recorded["image_size"], recorded["start"], recorded["perturbation"]) == (
        24, "hanging", 0.2)
    run("image_size=32", "start=hanging", "perturbation=0.2")
    assert len(seen) == 2 and seen[-1].image_size == 32  # not reused as "same settings"
    run("image_size=32", "start=hanging", "perturbation=0.2")
    assert len(seen) == 2  # the same settings are reused
    run("image_size=48")  # the world's default value, given, still replaces the scale's 16
    assert len(seen) == 3 and seen[-1].image_size == 48 and seen[-1].start == "random"


class _Stop(Exception):
    """Raised by a stand-in study once it has seen its world's settings."""


@pytest.mark.parametrize("world", ["gym", "dmc"])
def test_1_model_based_worlds_take_a_given_size_even_the_default(tmp_path, monkeypatch, world):
    """`--world-config size=64 frames=2` (the world's defaults) replace the tiny scale's 16
    and 1: given is given, whatever its value; sizes not given stay the scale's."""
    seen: list = []

    def stand_in(env_world, *args, **kwargs):
        seen.append(env_world.config)
        raise _Stop

    if world == "gym":
        import gym_blob  # noqa: F401  (registers the blob environment)
        import latent_sindy.worlds.gym.study as module

        pairs = ["id=gym_blob:BlobTest-v0"]
    else:
        import latent_sindy.worlds.dmc.study as module
        import latent_sindy.worlds.dmc.suite as suite

        monkeypatch.setattr(suite, "check_task", lambda config: None)  # (no dm-control here)
        pairs = []
    monkeypatch.setattr(module.study if world == "dmc" else module, "run_loops", stand_in)
    out = tmp_path / "study"
    for given, expected in ((["size=64", "frames=2"], (64, 2)), (["frames=2"], (16, 2))):
        with pytest.raises(_Stop):
            main(["reproduce", "--world", world, "--scale", "tiny", "--out", str(out),
                  "--world-config", *pairs, *given])
        assert (seen[-1].size, seen[-1].frames) == expected
    assert not out.exists()


@pytest.mark.parametrize("command", [
    ["reproduce", "--world", "pendulum", "--scale", "tiny"],
    ["collect", "--world", "pendulum", "--trajectories", "2", "--steps", "1"],
])
def test_1_a_world_setting_given_twice_is_refused(tmp_path, capsys, command):
    out = tmp_path / ("study" if command[0] == "reproduce" else "p.h5")
    line = _refused(capsys, *command, "--out", str(out), "--world-config", "image_size=24",
                    "image_size=32")
    assert "image_size is given twice" in line and not out.exists()


# ------------------------------------------------------------------ 7: a missing dependency
def test_7_dmc_without_the_suite_writes_nothing(tmp_path, capsys, monkeypatch):
    """Without dm-control the install line, and no folder: a run at another scale gets the
    same line (not "holds a dmc study of other settings"), and another study takes it."""
    monkeypatch.setitem(sys.modules, "dm_control", None)  # (import dm_control fails)
    out = tmp_path / "study"
    for scale in ("tiny", "demo"):
        line = _refused(capsys, "reproduce", "--world", "dmc", "--scale", scale, "--out",
                        str(out))
        assert "install latent-sindy[dmc]" in line and not out.exists()


# ------------------------------------------------------------------ 4: seeds out of range
@pytest.mark.parametrize(("args", "flag"), [
    (["train", "--data", "x.h5", "--out", "OUT", "--seed", "99999999999999999999"], "--seed"),
    (["collect", "--out", "OUT.h5", "--trajectories", "2", "--steps", "1", "--workers", "1",
      "--seed", "99999999999999999999"], "--seed"),
    (["collect", "--world", "pendulum", "--out", "OUT.h5", "--seed", "4294967296"], "--seed"),
    (["reproduce", "--scale", "tiny", "--out", "OUT", "--seeds", "99999999999999999999"],
     "--seeds"),
    (["reproduce", "--world", "pendulum", "--scale", "tiny", "--out", "OUT", "--seeds", "0",
      "4294967296"], "--seeds"),
    (["reproduce", "--scale", "tiny", "--out", "OUT", "--data-seed", "4294967296"],
     "--data-seed"),
    (["control", "RUN", "--seed", "4294967296"], "--seed"),
])
def test_4_a_seed_beyond_the_range_is_refused_before_any_work(tmp_path, capsys, monkeypatch,
                                                               args, flag):
    monkeypatch.chdir(tmp_path)
    line = _refused(capsys, *args)
    assert f"{flag} " in line and "seeds are integers from 0 to 4294967295" in line
    assert list(tmp_path.iterdir()) == []  # no OUT, no OUT.h5.partial/


def test_4_the_largest_seed_collects(tmp_path):
    from latent_sindy.data import read_sequences
    from latent_sindy.errors import MAX_SEED

    out = tmp_path / "p.h5"
    assert main(["collect", "--world", "pendulum", "--out", str(out), "--trajectories", "2",
                 "--steps", "1", "--seed", str(MAX_SEED)]) == 0
    assert read_sequences(out).seed == MAX_SEED


# ------------------------------------------------------------------ 8: the benchmark scripts
def _script(name: str, monkeypatch):
    """The benchmark script ``benchmarks/NAME.py`` as a module."""
    import importlib.util
    from pathlib import Path

    folder = Path(__file__).resolve().parents[1] / "benchmarks"
    spec = importlib.util.spec_from_file_location(f"bench_{name}", folder / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)  # (its dataclasses look it up)
    spec.loader.exec_module(module)
    return module


def _usage_error(capsys, module, argv: list[str]) -> str:
    """argparse's refusal: exit status 2 and one error line after the usage."""
    with pytest.raises(SystemExit) as stop:
        module.main(argv)
    err = capsys.readouterr().err
    errors = [ln for ln in err.splitlines() if ": error: " in ln]
    assert stop.value.code == 2 and len(errors) == 1 and "Traceback" not in err, err
    return errors[0]


@pytest.mark.parametrize(("argv", "needle"), [
    (["--seeds", "abc"], "give seeds as integers"),
    (["--seeds", "5..2"], "the range 5..2 holds no seed"),
    (["--seeds", "0", "99999999999999999999"], "seeds are integers from 0 to"),
    (["--workers", "0"], "--workers: 0: use 1 or more"),
    (["--set", "bogus=1"], "bogus"),
    (["--set", "epochs=0"], "--epochs 0"),
    (["--set", "seed=3"], "seed is set by LatentSINDy"),
    (["--set", "lr=1e-3", "lr=1e-4"], "given twice"),
    (["--set", "lr"], "not KEY=VALUE"),
    (["--omega2", "-1"], "--omega2: -1: use a finite number > 0"),
    (["--json", "FOLDER"], "is a folder"),
    (["--json", "FILE/rows.json"], "is not an existing folder"),
])
def test_8_suite_refuses_bad_arguments_before_any_fit(tmp_path, capsys, monkeypatch, argv,
                                                      needle):
    suite = _script("suite", monkeypatch)

    def no_fit(*args, **kwargs):
        raise AssertionError("a fit ran")

    monkeypatch.setattr(suite, "run_row", no_fit)
    (tmp_path / "FILE").write_text("x")
    argv = [a.replace("FOLDER", str(tmp_path)).replace("FILE", str(tmp_path / "FILE"))
            for a in argv]
    line = _usage_error(capsys, suite, ["--systems", "disc", *argv])
    assert needle in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["FILE"]


# ------------------------------------------------------------------ 9: advice and limits
TINY = ["--latent-dim", "3", "--encoder-hidden", "8", "--decoder-hidden", "16"]


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    from latent_sindy.worlds.push.collect import CollectionPlan, collect

    root = tmp_path_factory.mktemp("data")
    return collect(root / "data.h5", CollectionPlan(trajectories=3, steps=2, val_fraction=0.34,
                                                    test_fraction=0.0), workers=1)


def test_9_equations_of_a_run_in_training_does_not_advise_resume(tiny_data, tmp_path, capsys):
    """A run another process is training has a checkpoint and no model.pt yet: the advice
    is to wait (--resume would be refused by its lock); once free, to resume it."""
    from latent_sindy.locks import exclusive

    run = tmp_path / "run"
    assert main(["train", "sindy", "--data", str(tiny_data), "--out", str(run), "--epochs",
                 "1", "--no-progress", "--threads", "1", *TINY]) == 0
    capsys.readouterr()
    (run / "model.pt").unlink()  # as it is while its training runs
    with exclusive(run, "run folder"):
        line = _refused(capsys, "equations", str(run))
    assert "is training it now: wait for it to finish" in line and "--resume" not in line
    line = _refused(capsys, "equations", str(run))  # nobody trains it: it was interrupted
    assert "resume it with --resume" in line


@pytest.mark.parametrize("command", [
    ["train", "--data", "missing.h5", "--out", "run"],
    ["control", "no-run"],
    ["reproduce", "--scale", "tiny", "--data", "missing.h5", "--out", "study"],
])
def test_9_threads_beyond_the_cores_are_refused(tmp_path, capsys, monkeypatch, command):
    import os

    monkeypatch.chdir(tmp_path)
    cores = len(os.sched_getaffinity(0))
    line = _refused(capsys, *command, "--threads", str(cores + 1))
    assert f"--threads {cores + 1}: this process may run on {cores} core(s)" in line
    assert list(tmp_path.iterdir()) == []


def test_9_collect_workers_beyond_the_trajectories_are_cut_with_a_note(tmp_path, capsys,
                                                                        monkeypatch):
    import latent_sindy.cli as cli
    from latent_sindy.plugins import Command

    used: list[int] = []
    real = cli.COMMAND_OF["collect"]
    monkeypatch.setitem(cli.COMMAND_OF, "collect", Command(
        real.settings, lambda plan, out, workers, progress: used.append(workers)))
    assert main(["collect", "--out", str(tmp_path / "c.h5"), "--trajectories", "2",
                 "--steps", "1", "--workers", "1000", "--no-progress"]) == 0
    assert used == [2]
    assert "note: --workers 1000 for 2 trajectories: using 2 worker processes" in (
        capsys.readouterr().err)
    assert main(["collect", "--out", str(tmp_path / "d.h5"), "--trajectories", "3",
                 "--workers", "2", "--no-progress"]) == 0
    assert used == [2, 2] and "note" not in capsys.readouterr().err
