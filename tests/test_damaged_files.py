"""Damaged, deleted or oversized files a user (or a crash) leaves behind: each is recomputed
from what the run still holds, or named in one line with the fix, never a traceback; and the
study's outputs reach their names by a rename, so a crash never leaves half of one.

    pytest -q -m "not slow" tests/test_damaged_files.py
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
from pathlib import Path
from types import SimpleNamespace

import h5py
import pytest

from latent_sindy.cli import main
from latent_sindy.control.mppi import MPPIConfig
from latent_sindy.errors import UserError
from latent_sindy.training import TrainConfig
from latent_sindy.training.runs import RunDir
from latent_sindy.worlds.push.collect import CollectionPlan, collect
from latent_sindy.worlds.push.episodes import ControlConfig
from latent_sindy.worlds.push.study.jobs import EvalJob, ensure_trained, eval_job
from latent_sindy.worlds.push.study.scales import Condition
from test_bad_input import TINY, refused, snapshot

pytestmark = pytest.mark.usefixtures("one_torch_thread")

#: The closed-loop condition the tests evaluate: one paper-task episode of one push.
CONDITION = Condition(task="paper", space="latent", episodes=1, max_steps=1)
SETTINGS = ControlConfig(task="paper", episodes=1, max_steps=1, gif_episodes=0,
                         mppi=MPPIConfig(samples=4, horizon=1))


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> Path:
    """A tiny data file, a finished tiny SINDy run on its images (evaluated once, with its
    closed loop) and one on its states."""
    root = tmp_path_factory.mktemp("damaged")
    data = collect(root / "data.h5", CollectionPlan(trajectories=3, steps=2, val_fraction=0.34,
                                                    test_fraction=0.0), workers=1)
    for name, observation in (("run", []), ("state", ["state"])):
        assert main(["train", "sindy", *observation, "--data", str(data), "--out",
                     str(root / name), "--epochs", "2", "--checkpoint-every", "1",
                     "--no-progress", *([] if observation else TINY)]) == 0
    eval_job(job(root))
    return root


@pytest.fixture
def scratch(world: Path, tmp_path: Path) -> Path:
    """A copy of the world for a test that damages it."""
    shutil.copytree(world, tmp_path / "w")
    return tmp_path / "w"


def job(root: Path, controls: bool = True) -> EvalJob:
    return EvalJob(run=root / "run", data=root / "data.h5", name="sindy", seed=0,
                   controls=((CONDITION, SETTINGS),) if controls else (), threads=1)


def config(run: RunDir) -> TrainConfig:
    """The run's settings, pointed at this copy of the run and its data."""
    return dataclasses.replace(run.train_config(), out=run.path,
                               data=run.path.parent / "data.h5")


def damage(path: Path, how: str) -> None:
    """Truncate ``path`` (a JSON object) or give one of its parts the wrong type."""
    text = path.read_text()
    if how == "truncated":
        path.write_text(text[: len(text) // 2])
    elif how == "a list":
        path.write_text("[]")
    elif how == "not text":
        path.write_bytes(b"\xff\xfe\x00garbage")
    else:  # "<key>=<json>": that key's value replaced
        key, value = how.split("=", 1)
        record = json.loads(text)
        record[key] = json.loads(value)
        path.write_text(json.dumps(record))


# ----------------------------------------------------------------------------- D5, D6
@pytest.mark.parametrize("how", ["truncated", "a list", "not text", "losses=[]",
                                 "horizon={}", "stats=3", "probe=[1]"])
def test_d5_a_damaged_evaluation_json_is_recomputed(world: Path, scratch: Path,
                                                    how: str) -> None:
    good = eval_job(job(scratch, controls=False))
    cache = RunDir(scratch / "run") / RunDir.EVALUATION
    damage(cache, how)
    again = eval_job(job(scratch, controls=False))
    assert (again.losses, again.horizon, again.stats, again.probe) == (
        good.losses, good.horizon, good.stats, good.probe)
    assert json.loads(cache.read_text())["losses"] == good.losses  # the cache is whole again


@pytest.mark.parametrize("how", ["truncated", "a list", "not text", "summary=[]",
                                 "episodes={}", 'episodes=[{"actions": "x"}]',
                                 'episodes=[{"actions": [["a"]]}]'])
def test_d6_a_damaged_control_results_json_is_run_again(world: Path, scratch: Path,
                                                         how: str) -> None:
    good = eval_job(job(scratch)).control[CONDITION.name]
    results = RunDir(scratch / "run").control_dir("paper", "latent") / "results.json"
    damage(results, how)
    again = eval_job(job(scratch)).control[CONDITION.name]
    same = ("success_rate", "strict_success_rate", "final_distance_mean", "episodes")
    assert {k: again[k] for k in same} == {k: good[k] for k in same}
    assert json.loads(results.read_text())["summary"]["episodes"] == 1


# ----------------------------------------------------------------------------- D7, D14
@pytest.mark.parametrize(("how", "line"), [("abc", 3), ("missing", 3), ("extra", 2)])
def test_d7_a_damaged_metrics_csv_names_the_file_and_line(scratch: Path, how: str,
                                                          line: int) -> None:
    run = RunDir(scratch / "run")
    path = run / run.METRICS
    rows = path.read_text().splitlines()
    cells = rows[line - 1].split(",")
    if how == "abc":
        cells[1] = "abc"
    elif how == "missing":
        cells = cells[:3]
    else:
        cells.append("1.0")
    rows[line - 1] = ",".join(cells)
    path.write_text("\n".join(rows) + "\n")
    with pytest.raises(UserError, match=rf"{re.escape(str(path))}.* line {line}\b") as e:
        run.read_metrics()
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("damaged", ["deleted", "abc", "truncated"])
def test_d7_d14_a_study_restores_a_finished_runs_metrics_from_its_checkpoint(
        scratch: Path, damaged: str) -> None:
    run = RunDir(scratch / "run")
    path = run / run.METRICS
    good = run.read_metrics()
    if damaged == "deleted":
        path.unlink()
    elif damaged == "abc":
        path.write_text(path.read_text().replace("\n2,", "\nabc,"))
    else:  # cut at a line's end: the last epoch's row is gone
        path.write_text("\n".join(path.read_text().splitlines()[:-1]) + "\n")
    assert ensure_trained(config(run)) == "reused"
    assert run.read_metrics() == good
    assert eval_job(job(scratch, controls=False)).train_seconds == sum(
        r["time_s"] for r in good)


def test_d14_deleted_metrics_without_a_checkpoint_are_refused_naming_the_fix(
        scratch: Path) -> None:
    run = RunDir(scratch / "run")
    (run / run.METRICS).unlink()
    (run / run.CHECKPOINT).unlink()
    where, fix = re.escape(str(run / run.METRICS)), re.escape(f"delete {run.path}")
    with pytest.raises(UserError, match=rf"{where}.*{fix}"):
        ensure_trained(config(run))


# ----------------------------------------------------------------------------- D21
def test_d21_a_finished_run_missing_its_loss_plot_gets_it_back(scratch: Path) -> None:
    run = RunDir(scratch / "run")
    (run / run.PLOT).unlink()
    assert ensure_trained(config(run)) == "reused"
    assert (run / run.PLOT).stat().st_size > 0


def test_d21_the_loss_plot_is_written_before_the_model(world: Path, tmp_path: Path,
                                                       monkeypatch) -> None:
    """A kill right after model.pt (which marks the run finished) leaves loss.png there."""

    class Killed(BaseException):
        pass

    save = RunDir.save_torch

    def save_then_die(self: RunDir, name: str, payload: dict) -> None:
        save(self, name, payload)
        if name == RunDir.MODEL:
            raise Killed

    monkeypatch.setattr(RunDir, "save_torch", save_then_die)
    with pytest.raises(Killed):
        main(["train", "sindy", "--data", str(world / "data.h5"), "--out",
              str(tmp_path / "r"), "--epochs", "1", "--no-progress", *TINY])
    run = RunDir(tmp_path / "r")
    assert run.finished and (run / run.PLOT).is_file()


# ----------------------------------------------------------------------------- D8
def test_d8_images_declared_huge_but_never_written_are_refused_from_their_shapes(
        tmp_path: Path, capsys, monkeypatch) -> None:
    """A 13 KB file whose chunked `images` claim 76 GiB: refused before a byte is read."""
    monkeypatch.setattr("latent_sindy.atomic.available_memory", lambda: 16 * 2**30)
    path = tmp_path / "huge.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("images", shape=(8, 10**7, 1, 32, 32), dtype="uint8",
                         chunks=(1, 1, 1, 32, 32))
    assert path.stat().st_size < 10**6
    before = snapshot(tmp_path)
    refused(capsys, ["info", str(path)], str(path), "GiB of memory", "(8, 10000000, 1, 32, 32)")
    refused(capsys, ["preview", str(path)], str(path), "GiB of memory")
    assert snapshot(tmp_path) == before


# ----------------------------------------------------------------------------- atomic outputs
@pytest.fixture
def renamed(monkeypatch) -> list[str]:
    """The names files are renamed onto (os.replace) while the test runs."""
    names: list[str] = []
    replace = os.replace

    def record(src, dst, *args, **kwargs):
        names.append(Path(dst).name)
        return replace(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", record)
    return names


def test_table1_and_the_sweep_table_are_written_by_rename(tmp_path: Path,
                                                          renamed: list[str]) -> None:
    from latent_sindy.worlds.push.study.table import write_sweep_table, write_table1

    write_table1(tmp_path, ["m"], {"m": "a model"}, {}, 1)
    write_sweep_table(tmp_path / "sweep.md", ["m"], {"m": "a model"}, {0: {"m": {}}}, [0])
    assert {"table1.md", "table1.csv", "sweep.md"} <= set(renamed)
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_equations_files_are_written_by_rename(world: Path, tmp_path: Path,
                                               renamed: list[str]) -> None:
    from latent_sindy.worlds.push.study.outputs import write_equations

    run = tmp_path / "run"
    shutil.copytree(world / "run", run)
    study = SimpleNamespace(models=["sindy"], config=SimpleNamespace(seeds=(0,), out=tmp_path),
                            runs={0: {"sindy": run}}, results={0: {"sindy": object()}})
    files = write_equations(study)
    assert files == {"sindy": tmp_path / "equations_sindy.txt"}
    assert "equations_sindy.txt" in renamed
    assert files["sindy"].read_text().startswith("# seed 0\n")


def test_the_report_is_written_by_rename(tmp_path: Path, renamed: list[str]) -> None:
    from latent_sindy.study.report import Report

    Report("t").paragraph("p").write(tmp_path / "report.html")
    assert renamed == ["report.html"]
