"""The study pipeline end to end at the tiny scale: every output, a report that renders, re-runs
that reuse the finished pieces, and the mean ± std aggregation over seeds."""

from __future__ import annotations

import csv
import json
import math
import os
import shutil
from dataclasses import replace

import numpy as np
import pytest

from latent_sindy.data.windows import Normalizer
from latent_sindy.errors import UserError
from latent_sindy.executors import Inline
from latent_sindy.study.evaluation import Stat, aggregate, baseline_errors, mean_std
from latent_sindy.study.settings import StudySettings
from latent_sindy.training import RunDir
from latent_sindy.worlds.push.study.catalogue import model_specs
from latent_sindy.worlds.push.study.config import PushStudyConfig, StudyPlan
from latent_sindy.worlds.push.study.jobs import ensure_trained
from latent_sindy.worlds.push.study.outputs import model_figures, submit_model_figures
from latent_sindy.worlds.push.study.scales import SCALES
from latent_sindy.worlds.push.study.stages import run_stage
from latent_sindy.worlds.push.study.table import PAPER, ROWS, format_stat
from push_study import run_push
from test_report import CHECK, _chromium, _render_title

SPECS = model_specs(SCALES["tiny"])
MODELS = [s.name for s in SPECS]
CONDITIONS = {s.name: SCALES["tiny"].conditions(s) for s in SPECS}
N_CONDITIONS = sum(len(c) for c in CONDITIONS.values())


@pytest.fixture(scope="module")
def study(tmp_path_factory) -> dict:
    """The tiny study run twice in one folder: progress lines and file mtimes."""
    out = tmp_path_factory.mktemp("study")
    settings = {"scale": "tiny", "workers": 1}
    lines: list[str] = []
    report = run_push(out, lines.append, **settings)
    reused = [*out.glob("data.h5"), *out.glob("runs/seed0/*/model.pt"),
              *out.glob("runs/seed0/*/evaluation.json"),
              *out.glob("runs/seed0/*/control-*/results.json")]
    mtimes = {p: p.stat().st_mtime_ns for p in reused}
    drawn = [*out.glob("figures/coefficients_*.png"), *out.glob("figures/rollouts.png")]
    figure_mtimes = {p: p.stat().st_mtime_ns for p in drawn}
    again = run_push(out, lines.append, **settings)
    return {"out": out, "settings": settings, "report": report, "again": again, "mtimes": mtimes,
            "figure_mtimes": figure_mtimes, "lines": lines}


def test_pipeline_writes_the_report_and_says_so(study):
    assert study["report"] == study["out"] / "report.html" == study["again"]
    assert any(line.startswith("report: ") for line in study["lines"])


def test_rerun_reuses_data_runs_evaluations_and_episodes(study):
    mtimes = study["mtimes"]
    assert len(mtimes) == 1 + 2 * len(MODELS) + N_CONDITIONS  # data; model, evaluation; episodes
    changed = [str(p) for p, t in mtimes.items() if p.stat().st_mtime_ns != t]
    assert not changed
    assert "reused" in " ".join(study["lines"]) and "reusing" in " ".join(study["lines"])


def test_rerun_reuses_the_figures_of_models_it_did_not_train_again(study, tmp_path):
    from latent_sindy.worlds.push.study.outputs import coefficient_job

    figure_mtimes = study["figure_mtimes"]
    assert any(p.name == "rollouts.png" for p in figure_mtimes)
    assert any(p.name.startswith("coefficients_") for p in figure_mtimes)
    assert [p for p, t in figure_mtimes.items() if p.stat().st_mtime_ns != t] == []
    # a model written after its map (trained again) has its map drawn anew
    drawn = next(p for p in figure_mtimes if p.name.startswith("coefficients_"))
    run = shutil.copytree(study["out"] / "runs" / "seed0" / drawn.stem.removeprefix(
        "coefficients_"), tmp_path / "run")
    figure = shutil.copy2(drawn, tmp_path / drawn.name)
    assert coefficient_job(run, "kept", figure, 1) == figure
    assert figure.stat().st_mtime_ns == drawn.stat().st_mtime_ns
    later = drawn.stat().st_mtime_ns + 10**9
    os.utime(run / "model.pt", ns=(later, later))
    assert coefficient_job(run, "again", figure, 1) == figure
    assert figure.stat().st_mtime_ns != drawn.stat().st_mtime_ns


def test_table1_has_paper_values_and_ours_for_every_model(study):
    out = study["out"]
    md = (out / "table1.md").read_text()
    for value in ("0.0232", "0.2212", "98.3%", "94.6%"):
        assert value in md
    with (out / "table1.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(ROWS) * len(MODELS)
    by = {(r["metric"], r["model"]): r for r in rows}
    for row in ROWS:
        for m in MODELS:
            r = by[(row.label, m)]
            if row.in_paper and m in PAPER and PAPER[m].get(row.key) is not None:
                assert float(r["paper"]) == PAPER[m][row.key]
            planned = {f"control/{c.name}/" for c in CONDITIONS[m]}
            measured = row.key.startswith("loss/") or any(row.key.startswith(p)
                                                              for p in planned)
            if measured and "steps" not in row.key:
                assert math.isfinite(float(r["ours_mean"])), (row.label, m)
            if row.key.startswith("control/") and "/image/" in row.key and not any(
                    c.space == "image" for c in CONDITIONS[m]):
                assert r["ours"] == "n/a", (row.label, m)  # not planned in image space
            if row.key.startswith("pred_err/") and not m.startswith("state"):
                # inf would be a diverged rollout
                assert not math.isnan(float(r["ours_mean"])), (row.label, m)
            if row.key.startswith(("probe/", "pos_err/")):  # what the latent knows
                if m.startswith("state") and row.key.startswith("probe/"):
                    assert r["ours"] == "n/a", (row.label, m)  # its latent is the pose
                elif row.key.rsplit("/h", 1)[-1] in ("5", "10"):
                    assert r["ours"] == "n/a", (row.label, m)  # tiny trajectories: 3 pushes
                else:
                    assert math.isfinite(float(r["ours_mean"])), (row.label, m)
    assert {r["model"] for r in rows} == set(MODELS)


def test_every_figure_equation_and_summary_is_written(study):
    out = study["out"]
    fig = out / "figures"
    expected = ["loss_histories.png", "prediction_error.png", "position_error.png",
                "rollouts.png", "control.png",
                *(f"coefficients_{m}.png" for m in MODELS if "sindy" in m)]
    for name in expected:
        assert (fig / name).stat().st_size > 1000, name
    gifs = {p.name for p in (fig / "gifs").glob("*.gif")}
    assert gifs == {f"{m}_{c.task}-{c.space}.gif" for m, conds in CONDITIONS.items()
                    for c in conds}
    assert {c.space for c in CONDITIONS["state_sindy"]} == {"latent"}
    assert {c.space for c in CONDITIONS["sindy2"]} == {"latent", "image"}
    for m in MODELS:
        assert (out / f"equations_{m}.txt").read_text().startswith("# seed 0")
    summary = json.loads((out / "summary.json").read_text(),
                         parse_constant=lambda c: pytest.fail(f"non-standard JSON {c}"))
    assert summary["seeds"] == [0] and summary["world"] == "push"
    assert {"python", "torch", "pybullet", "latent-sindy"} <= set(summary["versions"])
    results = summary["results"]
    assert set(results["aggregate"]) == set(MODELS)
    assert results["aggregate"]["sindy4"]["control/discarded_total"]["mean"] == 0
    assert set(results["baselines"]["pred_err"]) == {"still", "mean_image"}
    position = results["baselines"]["position_cm"]
    assert len(position["still"]) == SCALES["tiny"].steps and 0 < position["reader"] < 2
    report = (out / "report.html").read_text()
    assert "nothing moves scores" in report and "What the latent knows" in report
    record = json.loads((out / "runs/seed0/sindy2/evaluation.json").read_text())
    assert set(record["probe"]) == {"x", "y", "cos", "sin", *(f"kernel/{k}" for k in (
        "x", "y", "cos", "sin", "angle"))}
    assert len(record["position"]["model"]) == SCALES["tiny"].steps
    assert json.loads((out / "runs/seed0/state_mlp/evaluation.json").read_text())["probe"] is None


def test_baseline_errors_equal_the_definitions_by_hand(trajectories):
    norm = Normalizer.from_trajectories(trajectories)
    train, test = trajectories.split("train"), trajectories.split("test")
    got = baseline_errors(train, test, norm)
    x = norm.normalize(test.images).double().numpy()  # (N, T+1, C, S, S)
    mean = norm.normalize(train.images).double().numpy().reshape(-1, *x.shape[2:]).mean(0)
    steps = x.shape[1] - 1
    for h in range(1, steps + 1):
        starts = range(steps - h + 1)
        still = np.mean([((x[:, t + h] - x[:, t]) ** 2).mean() for t in starts])
        mean_img = np.mean([((x[:, t + h] - mean) ** 2).mean() for t in starts])
        assert got["still"][h - 1] == pytest.approx(still, rel=1e-5)
        assert got["mean_image"][h - 1] == pytest.approx(mean_img, rel=1e-5)
    # A world where nothing moves is predicted perfectly by "nothing moves".
    frozen = replace(test, images=np.repeat(test.images[:, :1], steps + 1, axis=1))
    assert baseline_errors(train, frozen, norm)["still"] == [0.0] * steps


def test_report_renders_every_table_and_image(study, tmp_path):
    browser = _chromium()
    text = study["report"].read_text()
    n_img, n_cells = text.count("<img "), text.count("<td>")
    assert n_img >= 4 + 5 + N_CONDITIONS and "Table I" in text
    page = tmp_path / "checked.html"
    page.write_text(text.replace("</body>", CHECK + "</body>"))
    title = _render_title(browser, page, tmp_path)
    assert title == f"RENDER images {n_img}/{n_img} cells {n_cells}"


def test_a_finished_run_with_other_settings_is_refused(study):
    same = RunDir(study["out"] / "runs" / "seed0" / "sindy1").train_config()
    assert ensure_trained(same) == "reused"
    with pytest.raises(UserError, match="epochs"):
        ensure_trained(replace(same, epochs=same.epochs + 1))


def test_a_run_recorded_before_a_setting_existed_is_reused(study, tmp_path):
    """A setting added since a run was recorded takes its default, which keeps the old
    behaviour: the run is reused, not refused; a different value is still refused."""
    src = study["out"] / "runs" / "seed0" / "sindy1"
    run = tmp_path / "sindy1"
    shutil.copytree(src, run)
    record = json.loads((run / "config.json").read_text())
    for key in ("encoder", "pca_components"):  # the encoder part and the front: defaults
        del record["train"]["model"]["observation"][key]
    (run / "config.json").write_text(json.dumps(record))
    cfg = replace(RunDir(src).train_config(), out=run)
    assert ensure_trained(cfg) == "reused"
    keypoints = replace(cfg.model.observation, encoder_kind="keypoints")
    with pytest.raises(UserError, match=r"observation\.encoder\.kind"):
        ensure_trained(replace(cfg, model=replace(cfg.model, observation=keypoints)))


def test_mean_std_over_seeds():
    s = mean_std([1.0, 3.0])
    assert s.mean == 2.0 and s.std == pytest.approx(math.sqrt(2.0)) and s.n == 2  # ddof = 1
    assert mean_std([5.0]) == Stat(5.0, 0.0, 1)
    assert mean_std([None, None]) == Stat(None, None, 0)  # does not apply
    nan = mean_std([math.nan, math.nan])
    assert math.isnan(nan.mean) and nan.n == 0  # applies, but no result
    assert mean_std([2.0, math.nan, 4.0]) == Stat(3.0, pytest.approx(math.sqrt(2.0)), 2)
    agg = aggregate([{"loss": 0.1, "steps": 12.0, "sparsity": None},
                     {"loss": 0.3, "steps": math.nan, "sparsity": None, "extra": 1.0}])
    assert agg["loss"].mean == pytest.approx(0.2) and agg["loss"].std == pytest.approx(0.1414, 1e-3)
    assert agg["steps"] == Stat(12.0, 0.0, 1) and agg["sparsity"].mean is None
    assert agg["extra"] == Stat(1.0, 0.0, 1) and list(agg) == ["loss", "steps", "sparsity", "extra"]
    assert format_stat(agg["loss"], "loss", seeds=2) == "0.2000 ± 0.1414"
    assert format_stat(agg["steps"], "num", seeds=2) == "12.0 ± 0.0 (1/2 seeds)"
    assert format_stat(agg["sparsity"], "pct100", seeds=2) == "n/a"


@pytest.mark.parametrize(("value", "shown"), [(96.34, "96.3%"), (99.957, "99.96%"),
                                              (99.9996, "99.9996%"), (100.0, "100.0%")])
def test_sparsity_never_rounds_up_to_100_percent(value: float, shown: str) -> None:
    assert format_stat(Stat(value, 0.0, 1), "pct100", seeds=1) == shown


def test_config_is_validated(tmp_path):
    for bad in ({"seeds": ()}, {"scale": "huge"}, {"world": "moon"}, {"models": ("moon",)}):
        with pytest.raises(UserError):
            PushStudyConfig(out=tmp_path, **bad)
    for bad in ({"seeds": ()}, {"seeds": (0, 0)}, {"seeds": (-1,)}, {"workers": 0}):
        with pytest.raises(UserError):
            StudySettings(out=tmp_path, **bad)


def test_image_size_sets_the_collected_world_and_must_match_given_data(study, tmp_path):
    """--image-size is the camera resolution of the data the study collects; a size the world
    cannot render, or a reused file of another size, is one clear error."""
    assert PushStudyConfig(out=tmp_path, image_size=64).env_config().image_size == 64
    assert PushStudyConfig(out=tmp_path).env_config().image_size == 32
    with pytest.raises(UserError, match="--image-size 7"):
        PushStudyConfig(out=tmp_path, image_size=7)
    with pytest.raises(UserError, match="already exists with other collection settings"):
        run_push(study["out"], **study["settings"], image_size=16)
    with pytest.raises(UserError, match="holds 32x32 images"):
        run_push(tmp_path / "other", **study["settings"], data=study["out"] / "data.h5",
                 image_size=16)
    assert not (tmp_path / "other").exists()


def test_reused_study_data_must_match_the_collection_plan(study):
    """OUT/data.h5 is reused only if it was collected to the study's plan: another data seed
    or world is refused, not silently used."""
    for other in ({"data_seed": 7}, {"world": "paper"}):
        with pytest.raises(UserError, match="already exists with other collection settings"):
            run_push(study["out"], **{**study["settings"], **other})


@pytest.mark.parametrize("name", ["sindy2", "sindy_moments", "state_sindy_frame"])
def test_a_run_recorded_before_settings_were_derived_is_reused(study, tmp_path, name):
    """Runs recorded when the sprite's side was a plain default (11 in the asked settings)
    are compared on what their model was built with, so they are reused; a model built
    otherwise is still refused."""
    src = study["out"] / "runs" / "seed0" / name
    run = tmp_path / name
    shutil.copytree(src, run)
    record = json.loads((run / "config.json").read_text())
    asked = record["train"]["model"]
    for settings, key, before in ((asked["observation"].get("decoder", {}), "size", 11),):
        if key in settings:
            settings[key] = before
    (run / "config.json").write_text(json.dumps(record))
    cfg = replace(RunDir(src).train_config(), out=run)
    assert ensure_trained(cfg) == "reused"
    built = record["model"]["observation"].get("decoder", {})
    if built.get("kind") == "sprite":
        built["size"] = 23
        (run / "config.json").write_text(json.dumps(record))
        with pytest.raises(UserError, match=r"observation\.decoder\.size"):
            ensure_trained(cfg)


@pytest.mark.slow  # about 15 s on 2 cores: every figure drawn again on a pool
def test_figures_drawn_on_an_executor_are_the_pipelines(study, tmp_path):
    """The figures of trained models, queued on an executor (as the study does with two or
    more workers), are the files the pipeline drew itself, byte for byte; one not queued is
    drawn in this process."""
    out = study["out"]
    shutil.copytree(out / "runs", tmp_path / "runs")
    plan = StudyPlan.of(PushStudyConfig(**study["settings"], out=tmp_path, verbose=False))
    pool = Inline()
    queued = set(MODELS) - {"state_sindy"}  # drawn here instead (not in the rollouts)
    started = submit_model_figures(plan, queued, out / "data.h5", pool)
    assert set(started) == {"rollouts", *queued} and not any(f.done() for f in started.values())
    drawn = model_figures(plan, set(MODELS), out / "data.h5", started, pool)
    assert all(f.done() for f in started.values())
    for name in ("rollouts", *(f"coefficients_{m}" for m in MODELS if "sindy" in m)):
        mine = tmp_path / "figures" / f"{name}.png"
        assert mine.read_bytes() == (out / "figures" / f"{name}.png").read_bytes(), name
    assert drawn["state_sindy"] == tmp_path / "figures" / "coefficients_state_sindy.png"
    assert drawn["mlp"] is None  # not a sparse model: no map


def test_the_trained_hook_runs_once_after_the_last_training(study):
    """run_stage tells once, after every training and before the last evaluation, which of
    the first seed's models trained."""
    plan = StudyPlan.of(PushStudyConfig(**study["settings"], out=study["out"], verbose=False))
    lines: list[str] = []
    calls: list[tuple[set[str], int, int]] = []

    def trained(names: set[str]) -> None:
        said = " ".join(lines)
        calls.append((names, said.count("reused "), said.count("evaluated ")))

    run_stage(plan, study["out"] / "data.h5", Inline(), lines.append, trained)
    assert len(calls) == 1
    names, reused, evaluated = calls[0]
    assert names == set(MODELS) and reused == len(MODELS) and evaluated < len(MODELS)
