"""The tracked result files and the RESULTS.md made from them: rows written by key and read
back, each with its provenance; every world's figures summarised as the page says; the page
in the repository is the one its files give (a stale page fails here); the studies' rows."""

from __future__ import annotations

import dataclasses
import datetime
import json
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from latent_sindy.errors import UserError
from latent_sindy.result_files import (
    KEY,
    PROVENANCE,
    command_line,
    read_rows,
    record_rows,
    result_path,
    write_rows,
)
from latent_sindy.results_page import cell, main, render
from latent_sindy.stats import wilson_interval
from latent_sindy.world_study import Table, WorldStudy

ROOT = Path(__file__).resolve().parents[1]


def test_rows_are_written_by_key_and_read_back_as_they_were(tmp_path):
    path = tmp_path / "w" / "b.csv"
    write_rows(path, [{"model": "sindy", "seed": 0, "return": 801.5, "held": True,
                       "equation": "z'' = -1 sin(z)"},
                      {"model": "mlp", "seed": 0, "return": 790.25, "held": False}])
    rows = write_rows(path, [{"model": "sindy", "seed": 0, "return": 812.0, "terms": 37},
                             {"model": "sindy", "seed": 1, "return": 799.0}])
    assert [(r["model"], r["seed"]) for r in rows] == [("sindy", 0), ("mlp", 0), ("sindy", 1)]
    back = read_rows(path)
    assert back[0]["return"] == 812.0 and back[0]["terms"] == 37 and back[0]["held"] is None
    assert back[1] == {**dict.fromkeys([*KEY, *PROVENANCE], ""), "model": "mlp", "seed": 0,
                       "return": 790.25, "terms": None, "held": False, "equation": None}
    header = path.read_text().splitlines()[0].split(",")
    assert header == [*KEY, *PROVENANCE, "return", "terms", "held", "equation"]
    assert read_rows(tmp_path / "none.csv") == []


def test_numpy_scalars_are_written_as_plain_numbers(tmp_path):
    import numpy as np

    path = tmp_path / "n.csv"
    write_rows(path, [{"model": "m", "seed": np.int64(3), "x": np.float64(0.25),
                       "k": np.int32(7), "ok": np.bool_(True)}])
    assert "np." not in path.read_text()
    row = read_rows(path)[0]
    assert (row["seed"], row["x"], row["k"], row["ok"]) == (3, 0.25, 7, True)


def test_a_case_keeps_rows_of_one_model_and_seed_apart(tmp_path):
    path = tmp_path / "draws.csv"
    write_rows(path, [{"model": "default", "seed": 0, "case": f"draw {i}", "recovered": i == 1}
                      for i in range(3)])
    write_rows(path, [{"model": "default", "seed": 0, "case": "draw 2", "recovered": True}])
    assert [r["recovered"] for r in read_rows(path)] == [False, True, True]


def test_record_rows_stamps_each_row_with_where_it_ran(tmp_path):
    path = record_rows(tmp_path, "pendulum", "demo", [{"model": "sindy", "seed": 2, "x": 1.5}],
                       command="latent-sindy reproduce --world pendulum", device="cpu")
    assert path == tmp_path / "pendulum" / "demo.csv"
    row = read_rows(path)[0]
    assert row["date"] == datetime.datetime.now(datetime.UTC).date().isoformat()
    assert row["command"] == "latent-sindy reproduce --world pendulum" and row["device"] == "cpu"
    assert "cores" in row["machine"] and row["source"] == "measured" and row["x"] == 1.5
    if (ROOT / ".git").exists() and shutil.which("git"):
        assert row["commit"], "a checkout's commit is recorded"
    assert command_line(["/x/cli.py", "reproduce", "--out", "a b"]) == \
        "latent-sindy reproduce --out 'a b'"


@pytest.mark.parametrize(("world", "benchmark"), [("../etc", "x"), ("push", "a/b"), ("", "x")])
def test_names_that_are_not_plain_file_names_are_refused(tmp_path, world, benchmark):
    with pytest.raises(UserError, match="plain file name"):
        result_path(tmp_path, world, benchmark)


def test_a_file_that_is_not_a_result_file_is_refused(tmp_path):
    (tmp_path / "x.csv").write_text("a,b\n1,2\n")
    with pytest.raises(UserError, match="not a result file"):
        read_rows(tmp_path / "x.csv")
    with pytest.raises(UserError, match="needs a model"):
        write_rows(tmp_path / "y.csv", [{"seed": 0, "x": 1}])


def test_a_cell_summarises_a_models_rows_as_the_page_says():
    assert cell([{"ok": True}, {"ok": False}, {"ok": True}], "ok", "") == "2 of 3"
    lo, hi = wilson_interval(49 + 50, 100)
    pooled = cell([{"k": 49, "n": 50}, {"k": 50, "n": 50}], "k/n", ".1%")
    assert pooled == f"99 of 100: 99.0% ({100 * lo:.1f}%–{100 * hi:.1f}%)"
    assert cell([{"r": 0.96, "r_low": 0.8, "r_high": 0.99}], "r", ".0%") == "96% (80%–99%)"
    assert cell([{"r": 186.1, "r_sd": 24.1}], "r", ".1f") == "186.1 (sd 24.1)"
    assert cell([{"r": 800.0}, {"r": 810.0}, {"r": 790.0}], "r", ".1f") == "800.0 (790.0–810.0)"
    assert cell([{"c": -1.01}, {"c": -1.0}], "c", ".2f") == "-1.00 (-1.01 to -1.00)"
    assert cell([{"t": 10}, {"t": 10}], "t", "d") == "10"
    assert cell([{"t": "37–38"}, {"t": "36–42"}, {"t": None}], "t", "") == "37–38 / 36–42"
    assert cell([{"t": None}], "t", "") == ""


def _world(root: Path) -> Path:
    folder = root / "toy"
    write_rows(folder / "loop.csv", [
        {"model": "sindy", "seed": s, "commit": "abc1234", "date": "2026-12-06",
         "machine": "2 cores", "device": "cpu", "command": "toy --seed", "source": "measured",
         "return": v, "wins": k, "games": 10} for s, (v, k) in enumerate([(800, 9), (820, 10)])])
    (folder / "world.json").write_text(json.dumps({
        "title": "A toy world", "intro": "What it is.", "history": ["docs/notes/toy.md"],
        "limits": ["It is a toy."],
        "benchmarks": [{"file": "loop", "title": "The loop", "command": "toy",
                        "latent": "hand-made reader: the toy's position",
                        "columns": [["return", "return", ".1f"], ["wins/games", "wins", ".0%"]],
                        "models": {"sindy": {"label": "SINDy"}},
                        "baselines": [{"model": "published: someone", "latent": "learned",
                                       "values": {"return": "700 ± 10"}}]}]}))
    return folder


def test_the_page_has_a_current_table_a_world_with_its_limits(tmp_path):
    _world(tmp_path)
    text = render(tmp_path)
    lo, hi = wilson_interval(19, 20)
    assert "## A toy world" in text and "### Current" in text and "#### The loop" in text
    assert (f"| SINDy | hand-made reader: the toy's position | 0, 1 | 810.0 (800.0–820.0) | "
            f"19 of 20: 95% ({100 * lo:.0f}%–{100 * hi:.0f}%) |") in text
    assert "| published: someone | learned |  | 700 ± 10 |  |" in text
    assert "To run it again: `toy`." in text and "As run: `toy --seed`." in text
    assert "Commit (date): abc1234 (2026-12-06)." in text
    assert "### Known limits\n\n- It is a toy." in text
    assert "[toy](docs/notes/toy.md)" in text


def test_a_benchmark_named_without_its_file_is_an_error(tmp_path):
    folder = _world(tmp_path)
    (folder / "loop.csv").unlink()
    with pytest.raises(UserError, match="missing or empty"):
        render(tmp_path)


def test_check_fails_on_a_stale_page_and_passes_on_a_fresh_one(tmp_path, capsys):
    _world(tmp_path / "results")
    page = tmp_path / "RESULTS.md"
    args = ["--results", str(tmp_path / "results"), "--out", str(page)]
    assert main([*args, "--check"]) == 1  # no page yet
    assert main(args) == 0 and main([*args, "--check"]) == 0
    write_rows(tmp_path / "results" / "toy" / "loop.csv",
               [{"model": "sindy", "seed": 2, "return": 500.0}])
    assert main([*args, "--check"]) == 1
    assert "is stale" in capsys.readouterr().err
    assert main(["--results", str(tmp_path / "none"), "--out", str(page)]) == 2


def test_the_command_has_help():
    done = subprocess.run([sys.executable, "-m", "latent_sindy.results_page", "--help"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and "--check" in done.stdout


def test_results_md_is_what_the_tracked_result_files_give():
    """RESULTS.md is generated: after changing results/, run
    `python -m latent_sindy.results_page`."""
    text = render(ROOT / "results")
    assert (ROOT / "RESULTS.md").read_text(encoding="utf-8") == text, \
        "RESULTS.md is stale: run `python -m latent_sindy.results_page`"
    assert len(text.splitlines()) <= 400


def test_every_result_file_is_named_by_its_worlds_description():
    for folder in (p for p in (ROOT / "results").iterdir() if p.is_dir()):
        meta = json.loads((folder / "world.json").read_text(encoding="utf-8"))
        named = {b["file"] for b in meta["benchmarks"]}
        assert named == {p.stem for p in folder.glob("*.csv")}, folder.name
        for link in meta.get("history", []):
            assert (ROOT / link).exists(), link
        for row in (r for name in named for r in read_rows(folder / f"{name}.csv")):
            assert all(row[k] for k in ("model", "commit", "date", "machine", "device",
                                        "command", "source")), (folder.name, row)


@pytest.mark.skipif(not (ROOT / ".git").exists() or shutil.which("git") is None,
                    reason="not a git checkout")
def test_git_keeps_the_result_files_and_ignores_what_studies_write_under_results():
    ignored = ["results/demo/summary.json", "results/demo/table1.csv", "results/demo/data.h5",
               "results/demo/runs/seed0/sindy2/metrics.csv", "results/summary.json",
               "results/runs/seed0/x/coefficients.csv", "results/pendulum/table.md"]
    kept = ["results/push/demo.csv", "results/push/world.json", "results/new/bench.csv"]
    done = subprocess.run(["git", "check-ignore", "--no-index", *ignored, *kept], cwd=ROOT,
                          capture_output=True, text=True, timeout=30)
    assert done.stdout.split() == ignored


def test_a_world_study_records_its_rows_when_asked(tmp_path):
    from latent_sindy.plugins import CONFIG_GIVEN
    from latent_sindy.study.runner import write_world_study

    class Toy:
        config = SimpleNamespace(omega2=1.44)

        def reproduce(self, scale, out, seeds, device, threads, say):
            return WorldStudy(title="toy", settings={}, seeds=list(seeds), numbers={},
                              findings=[], tables=[Table("t", ["a"], [["1"]])],
                              rows=[{"model": "m", "seed": s, "x": float(s)} for s in seeds])

    @dataclasses.dataclass
    class Settings:
        out: Path
        record: Path | None
        scale: str = "tiny"
        seeds: tuple[int, ...] = (0, 1)
        device: str = "cpu"
        threads: int = 1
        world: str = "toy"

    world = Toy()
    setattr(world, CONFIG_GIVEN, ("omega2",))
    settings = Settings(out=tmp_path / "study", record=tmp_path / "results")
    write_world_study(world, settings, lambda _: None)
    rows = read_rows(tmp_path / "results" / "toy" / "tiny_omega2=1.44.csv")
    assert [(r["model"], r["seed"], r["x"], r["device"]) for r in rows] == [
        ("m", 0, 0.0, "cpu"), ("m", 1, 1.0, "cpu")]
    write_world_study(world, Settings(out=tmp_path / "again", record=None), lambda _: None)
    assert len(list((tmp_path / "results").rglob("*.csv"))) == 1  # without --record: nothing


def test_the_push_study_records_table_one_headline_figures(tmp_path):
    from dataclasses import replace

    from fake_study import fake_study
    from latent_sindy.worlds.push.study.pipeline import record_name, record_of

    study, _, _ = fake_study(tmp_path, seeds=(0, 1))
    rows = record_of(study)
    assert [(r["seed"], r["model"]) for r in rows] == [
        (s, spec.name) for s in (0, 1) for spec in study.specs]
    for row in rows:
        m = study.per_seed[row["seed"]][row["model"]]
        n = m["control/random/latent/episodes"]
        assert row["strict_episodes"] == row["course_episodes"] == n
        assert row["strict_successes"] == round(m["control/random/latent/strict_success_rate"] * n)
        assert row["active_terms"] == m["sindy/active"]
    assert record_name(study.config) == "tiny"
    assert record_name(replace(study.config, world="textured", image_size=64)) == \
        "tiny_textured_64px"


def test_the_model_based_study_rows_are_each_loops_last_test():
    from latent_sindy.study.model_based_report import _rows

    log = {"iterations": [{"evaluation": [100.0, 200.0], "fit_env_steps": 10, "active_terms": 40},
                          {"evaluation": [300.0, 500.0], "fit_env_steps": 20, "active_terms": 30},
                          {"evaluation": None, "fit_env_steps": 30, "active_terms": 20}],
           "episodes": [{"kind": "random", "return": -10.0}, {"kind": "random", "return": -30.0},
                        {"kind": "planned", "return": 50.0}]}
    rows = _rows({"sindy": {1: {"log": log, "wall_s": 5.0}},
                  "mlp": {0: {"log": {"iterations": [], "episodes": []}, "wall_s": 1.0}}})
    assert rows == [{"model": "sindy", "seed": 1, "test_return": 400.0, "random_return": -20.0,
                     "env_steps": 20, "active_terms": 30, "wall_s": 5.0},
                    {"model": "mlp", "seed": 0, "test_return": None, "random_return": None,
                     "env_steps": None, "active_terms": None, "wall_s": 1.0}]
