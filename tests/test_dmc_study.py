"""The DeepMind Control study (``latent-sindy reproduce --world dmc``): its scales, the tiny
scale end to end through the CLI in the common format, resumed after an interruption to the
uninterrupted study's returns, and the task chosen through --world-config."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from latent_sindy.cli import main
from latent_sindy.plugins import get_world

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_the_scales_and_the_benchmark_setting():
    from latent_sindy.worlds.dmc.study import SCALES

    assert set(get_world("dmc").scales) == {"tiny", "small", "demo", "benchmark", "read-tiny",
                                            "read-demo", "read-100k", "keypoints-demo",
                                            "keypoints-100k", "keypoints8-demo",
                                            "keypoints8-100k", "keypoints8-sparse-100k"}
    for name in ("benchmark", "read-100k", "keypoints-100k", "keypoints8-100k",
                 "keypoints8-sparse-100k"):
        b = SCALES[name]
        episodes = b.seed_episodes + b.iterations * b.episodes_per_iteration
        assert episodes * b.episode_steps * 8 == 100_000, name  # repeat 8
    # the sparse scale is the 8 keypoints' loop but for SINDy's choice of fit
    assert dataclasses.replace(SCALES["keypoints8-sparse-100k"], sparsest_within=None,
                               about="") == dataclasses.replace(SCALES["keypoints8-100k"],
                                                                about="")


def test_a_keypoints_scale_plans_on_keypoints_learned_from_the_frames():
    from latent_sindy.models.keypoint_reader import KeypointReader
    from latent_sindy.study.model_based import scale_reader
    from latent_sindy.worlds.dmc.study import SCALES

    for name in ("keypoints-demo", "keypoints-100k", "keypoints8-demo", "keypoints8-100k"):
        s = SCALES[name]
        # the read-* scale's loop, with the world's hand-made reader never asked for
        read = SCALES[name.replace("keypoints8", "read").replace("keypoints", "read")]
        assert (s.seed_episodes, s.iterations, s.episodes_per_iteration) == (
            read.seed_episodes, read.iterations, read.episodes_per_iteration)
        reader = scale_reader(s, 2, hand_made=lambda: pytest.fail("hand-made reader made"),
                              out=Path("study"))()
        assert isinstance(reader, KeypointReader)
        assert (reader.frames, reader.parts) == (2, 8 if "keypoints8" in name else 4)
        # its fit is kept in the study's folder: every model's loop of a seed shares it
        assert reader.store == Path("study") / "readers"


@pytest.mark.slow  # about a minute on 2 cores (the tiny study's end-to-end test stays)
def test_the_read_latents_study_end_to_end(tmp_path, capfd):
    """The cart-pole's pose read from the frames, three dynamics on it, through the CLI:
    SINDy's equations in the report, each fit from scratch (no warm start to continue)."""
    pytest.importorskip("dm_control")
    out = tmp_path / "read"
    assert main(["reproduce", "--world", "dmc", "--scale", "read-tiny", "--out", str(out)]) == 0
    assert "seed 0 linear: iteration 1, return" in capfd.readouterr().err
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["results"]["runs"]) == {"sindy/seed0", "linear/seed0", "mlp/seed0"}
    its = json.loads((out / "seed0" / "sindy" / "log.json").read_text())["iterations"]
    assert its[0]["updates"] is None and its[0]["active_terms"] > 0
    assert "z0[t+1] = z0" in (out / "equations_sindy_seed0.txt").read_text()
    mlp = json.loads((out / "seed0" / "mlp" / "log.json").read_text())["iterations"]
    assert mlp[0]["equations"] is None and len(mlp[0]["evaluation"]) == 1


def test_world_config_is_for_a_world_with_a_study_of_its_own(tmp_path, capsys):
    assert main(["reproduce", "--scale", "tiny", "--out", str(tmp_path / "p"),
                 "--world-config", "task=reacher-easy"]) == 2
    assert "--world-config" in capsys.readouterr().err
    assert main(["reproduce", "--world", "pendulum", "--scale", "tiny", "--out",
                 str(tmp_path / "q"), "--world-config", "nothing=1"]) == 2
    assert "nothing" in capsys.readouterr().err


def _returns(out):
    summary = json.loads((out / "summary.json").read_text())
    return {k: v["returns"] for k, v in summary["results"]["runs"].items()}


def test_workers_is_a_setting_of_the_worlds_whose_study_takes_it():
    from latent_sindy.errors import UserError
    from latent_sindy.plugins import get_world
    from latent_sindy.study.runner import study_options
    from latent_sindy.study.settings import StudySettings

    settings = StudySettings(scale="tiny", workers=3)
    assert study_options("dmc", get_world("dmc"), settings, {})["workers"] == 3
    with pytest.raises(UserError, match="--workers: the pendulum world's study does not take"):
        study_options("pendulum", get_world("pendulum"), settings, {})


def test_the_tiny_study_end_to_end_resumes_and_refuses_another_task(tmp_path, capfd):
    """Two loops at a time in worker processes (the CLI's default), their numbers those of
    loops run in this process; an interrupted study resumed to the same numbers."""
    pytest.importorskip("dm_control")
    from latent_sindy.worlds.dmc.config import DmcConfig
    from latent_sindy.worlds.dmc.study import run_dmc_study

    whole = tmp_path / "whole"
    assert main(["reproduce", "--world", "dmc", "--scale", "tiny", "--out", str(whole)]) == 0
    err = capfd.readouterr().err
    assert "seed 0 sindy: iteration 2" in err and "2 loop(s) at a time" in err  # progress
    # every fit in the scale's batches of 8 windows; SINDy pruned by its warm refit
    its = json.loads((whole / "seed0" / "sindy" / "log.json").read_text())["iterations"]
    assert [it["batch_size"] for it in its] == [8, 8]
    assert its[1]["pruned"] > 0 and its[1]["active_terms"] < its[0]["active_terms"]
    summary = json.loads((whole / "summary.json").read_text())
    assert summary["world"] == "dmc" and summary["study"]["world"]["task"] == "cartpole-swingup"
    assert {"table.md", "report.html", "equations_sindy_seed0.txt",
            "returns.png"} <= set(summary["files"])
    table = (whole / "table.md").read_text()
    assert "| CURL | 100,000 | 582 ± 146 |" in table and "| DrQ | 100,000 | 759 ± 92 |" in table
    assert "z0[t+1] = z0" in (whole / "equations_sindy_seed0.txt").read_text()
    runs = summary["results"]["runs"]
    assert set(runs) == {"sindy/seed0", "linear/seed0", "mlp/seed0"}
    assert all(len(r["returns"]) == 4 for r in runs.values())  # 2 seed + 2 planned episodes
    # one test episode after each fit, without noise, reported beside the collected ones
    assert [len(it["evaluation"]) for it in its] == [1, 1]
    tests = summary["results"]["tests"]["sindy"]
    assert [t["env_steps"] for t in tests] == [2 * 8 * 8, 3 * 8 * 8]
    assert [t["mean"] for t in tests] == [it["evaluation"][0] for it in its]
    assert "Test episodes, without exploration noise" in table
    # a loop's wall time counts its test episodes as well as its fits and collected ones
    log = json.loads((whole / "seed0" / "sindy" / "log.json").read_text())
    collected = sum(e["seconds"] for e in log["episodes"])
    assert summary["results"]["runs"]["sindy/seed0"]["wall_s"] == pytest.approx(
        collected + sum(it["fit_seconds"] + it["eval_seconds"] for it in its), abs=1e-6)
    assert f"mean over 1 seed(s): sindy {tests[-1]['mean']:.1f}, " in table  # the headline

    # interrupted while the linear model's loop runs: then run again to the end
    part = tmp_path / "part"

    def stop(line: str) -> None:
        if line.startswith("seed 0 linear: iteration 2:"):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_dmc_study(DmcConfig(), "tiny", part, None, "cpu", 1, stop)
    sindy_log = (part / "seed0" / "sindy" / "log.json").read_text()
    assert main(["reproduce", "--world", "dmc", "--scale", "tiny", "--out", str(part)]) == 0
    err = capfd.readouterr().err
    assert "seed 0 sindy: 2 of 2 iterations done before, reused" in err
    assert "seed 0 linear: 1 of 2 iterations done before, reused" in err
    assert (part / "seed0" / "sindy" / "log.json").read_text() == sindy_log
    assert _returns(part) == _returns(whole)

    # another task into the same folder is refused; the task is the world's setting
    assert main(["reproduce", "--world", "dmc", "--scale", "tiny", "--out", str(part),
                 "--world-config", "task=pendulum-swingup"]) == 2
    assert "other settings (world)" in capfd.readouterr().err


def test_the_tiny_study_of_the_pendulum_swingup(tmp_path):
    pytest.importorskip("dm_control")
    from latent_sindy.worlds.dmc.config import DmcConfig
    from latent_sindy.worlds.dmc.study import run_dmc_study

    lines: list[str] = []
    result = run_dmc_study(DmcConfig(task="pendulum-swingup"), "tiny", tmp_path, None, "cpu",
                           1, lines.append)
    assert result["settings"]["world"]["action_repeat"] == 4
    for model, by_seed in result["runs"].items():
        episodes = by_seed[0]["log"]["episodes"]
        assert [e["kind"] for e in episodes] == ["random"] * 2 + ["planned"] * 2, model
        # (a sparse reward: 1 a control step within 8 degrees of upright, 4 steps an action)
        assert all(0 <= e["return"] <= 8 * 4 for e in episodes), model
    assert any("sindy: iteration 2" in line and "active terms" in line for line in lines)
