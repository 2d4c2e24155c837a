"""`latent-sindy reproduce --world pendulum-video | pendulum`: the tiny scales through the
command, their files agreeing with what the study returned, a video study that resumes from
its finished seeds, and the push study's settings refused with a pendulum world."""

from __future__ import annotations

import json
import re
import shutil
import statistics

import pytest

from latent_sindy.cli import main
from latent_sindy.locks import exclusive
from latent_sindy.stats import wilson_interval
from latent_sindy.worlds.pendulum import VIDEO, WORLD, video_pca, video_study
from latent_sindy.worlds.pendulum import study as study_module

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _spy(monkeypatch, world) -> list:
    """Record what ``world.reproduce`` returns while the command runs."""
    returned, real = [], world.reproduce

    def spy(*args, **kwargs):
        returned.append(real(*args, **kwargs))
        return returned[-1]

    monkeypatch.setattr(world, "reproduce", spy)
    return returned


def _error(capsys, *args: str) -> str:
    code = main(list(args))
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("latent-sindy: error:"), lines
    return lines[0]


@pytest.fixture(scope="module")
def video_run(tmp_path_factory, one_torch_thread):
    """The tiny video study run once through the command: (folder, what the study returned)."""
    out = tmp_path_factory.mktemp("video") / "study"
    mp = pytest.MonkeyPatch()
    returned = _spy(mp, VIDEO)
    try:
        assert main(["reproduce", "--world", "pendulum-video", "--scale", "tiny", "--out",
                     str(out), "--device", "cpu"]) == 0
    finally:
        mp.undo()
    return out, returned[0]


def test_the_tiny_video_study_writes_what_it_found(video_run):
    out, study = video_run
    summary = json.loads((out / "summary.json").read_text())
    rows = summary["results"]["rows"]
    assert rows == json.loads(json.dumps(study.numbers["rows"]))  # every number, as returned
    assert summary["seeds"] == [0] and [r["seed"] for r in rows] == [0]
    assert summary["study"]["schedule"] == "uncalibrated" and summary["study"]["device"] == "cpu"
    assert summary["versions"]["torch"] and summary["timings_s"]["total"] > 0
    got = summary["results"]["summary"]
    assert got["recovered"] == sum(r["recovered"] for r in rows)
    assert got["median"]["fvu_ddz"] == pytest.approx(statistics.median(r["fvu_ddz"]
                                                                       for r in rows))
    assert got["published"] == {"fvu_x": 8e-4, "fvu_ddx": 3e-4, "fvu_ddz": 2e-2}
    assert got["replicated"]["fvu_ddz"] == {"mean": 0.5, "std": 0.4}
    r = rows[0]
    assert set(r["coefficients"]) >= {"sin(z0)", "z0"} and r["epochs"] == 3
    assert r["recovered"] == (r["exact_sin"] and abs(r["coefficient"] + 1) <= 0.02)
    table = (out / "table.md").read_text()
    line = next(ln for ln in table.splitlines() if ln.startswith("| 0 |"))
    assert f"{r['fvu_ddz']:.1e}" in line and f"{r['fvu_x']:.1e}" in line
    assert "| published (best of 10) | - | 8.0e-04 | 3.0e-04 | 2.0e-02 |" in table
    html = (out / "report.html").read_text()
    assert f"{r['fvu_ddz']:.1e}" in html and html.count('src="data:image/png;base64,') >= 1
    assert "http" not in html.replace("http-equiv", "")  # self-contained
    eqs = (out / "equations_pendulum-video.txt").read_text()
    assert eqs == f"seed 0: {r['equation']}\n" and r["equation"].startswith("z0'' =")
    # the compressed data is cached in the study's folder, and one JSON line per seed kept
    assert (out / video_pca.cache_name(8, 5, "exact", (4, 2, 2), 50)).exists()
    kept = [json.loads(ln) for ln in (out / "seeds.jsonl").read_text().splitlines()]
    assert [{k: v for k, v in k_.items() if k != "key"} for k_ in kept] == rows


def test_a_rerun_reuses_finished_seeds_and_trains_only_new_ones(video_run, tmp_path,
                                                                monkeypatch):
    first, _ = video_run
    out = tmp_path / "study"
    shutil.copytree(first, out)
    before = json.loads((out / "summary.json").read_text())["results"]["rows"]
    trained: list[int] = []
    real = video_study.train_seed

    def counting(seed, *args, **kwargs):
        trained.append(seed)
        return real(seed, *args, **kwargs)

    def no_remaking(*args, **kwargs):
        raise AssertionError("the cached compression was made again")

    monkeypatch.setattr(video_study, "train_seed", counting)
    monkeypatch.setattr(video_pca, "compressed_video", no_remaking)
    argv = ["reproduce", "--world", "pendulum-video", "--scale", "tiny", "--out", str(out),
            "--device", "cpu"]
    stamp = (out / "seeds.jsonl").stat().st_mtime_ns
    assert main(argv) == 0
    assert trained == []  # nothing trained again: the file is untouched, the row the same
    assert (out / "seeds.jsonl").stat().st_mtime_ns == stamp
    summary = json.loads((out / "summary.json").read_text())
    assert summary["results"]["rows"] == before and summary["results"]["reused_seeds"] == [0]

    assert main([*argv, "--seeds", "0", "1"]) == 0
    assert trained == [1]  # only the new seed, on the cached data
    rows = json.loads((out / "summary.json").read_text())["results"]["rows"]
    assert rows[0] == before[0] and [r["seed"] for r in rows] == [0, 1]
    assert len((out / "seeds.jsonl").read_text().splitlines()) == 2


def test_a_seed_of_other_settings_or_a_damaged_line_is_trained_again(tmp_path, monkeypatch):
    """Reuse needs the same settings: a line of another schedule, or a broken one, is not a
    finished seed of this study."""
    cfg = video_study.VideoStudyConfig(seeds=(0, 1), components=8, epochs=3, splits=(4, 2, 2),
                                       steps=50)
    other = {"key": {**cfg.key(), "components": 9}, "seed": 0}
    (tmp_path / "seeds.jsonl").write_text(json.dumps(other) + "\n{not json\n")
    trained: list[int] = []

    def fake(seed, *args, **kwargs):
        trained.append(seed)
        return {"seed": seed, "equation": "z0'' = -1 sin(z0)", "exact_sin": True,
                "coefficient": -1.0, "coefficients": {"sin(z0)": -1.0}, "fvu_x": 0.1,
                "fvu_ddx": 0.2, "fvu_ddz": 0.3, "time_s": 1.0, "recovered": True}

    monkeypatch.setattr(video_study, "train_seed", fake)
    result = video_study.run_video_study(cfg, tmp_path, say=lambda _: None)
    assert trained == [0, 1] and result.reused == []
    assert result.summary()["recovered"] == 2
    again = video_study.run_video_study(cfg, tmp_path, say=lambda _: None)
    assert trained == [0, 1] and again.reused == [0, 1] and again.rows == result.rows


def test_the_tiny_pendulum_study_writes_what_it_found(tmp_path, monkeypatch):
    out = tmp_path / "study"
    returned = _spy(monkeypatch, WORLD)
    assert main(["reproduce", "--world", "pendulum", "--scale", "tiny", "--out", str(out),
                 "--device", "cpu"]) == 0
    study = returned[0]
    summary = json.loads((out / "summary.json").read_text())
    rows = summary["results"]["per_seed"]["0"]
    assert rows == json.loads(json.dumps(study.numbers["per_seed"]["0"]))
    assert [r["model"] for r in rows] == ["state SINDy (true state)", "sindy (images)",
                                          "mlp (images)", "linear (images)"]
    assert summary["study"]["study"]["device"] == "cpu"
    assert summary["study"]["study"]["episodes"] == 2
    table = (out / "table.md").read_text()
    for r in rows:
        assert r["episodes"] == 2 == len(r["episode_success"])
        assert r["successes"] == sum(r["episode_success"])
        lo, hi = wilson_interval(r["successes"], r["episodes"])
        assert r["success_wilson95"] == pytest.approx([lo, hi])
        assert (f"| {r['model']} | {r['successes']} of 2 | {100 * lo:.0f}–{100 * hi:.0f} % |"
                in table)
    assert "Δθ_dot" in (out / "equations_state_sindy.txt").read_text()
    assert re.search(r"z0\[t\+1\] = ", (out / "equations_sindy.txt").read_text())
    assert {p.name for p in out.glob("equations_*.txt")} == {
        "equations_state_sindy.txt", "equations_sindy.txt", "equations_mlp.txt",
        "equations_linear.txt"}
    html = (out / "report.html").read_text()
    assert 'src="data:image/png;base64,' in html and "Wilson" in html
    assert (out / "figures" / "pendulum_success.png").stat().st_size > 1000

    def no_rerun(*args, **kwargs):
        raise AssertionError("a finished seed was run again")

    monkeypatch.setattr(study_module, "compare_swing_ups", no_rerun)  # a re-run reads seed 0 back
    assert main(["reproduce", "--world", "pendulum", "--scale", "tiny", "--out", str(out),
                 "--device", "cpu"]) == 0
    again = json.loads((out / "summary.json").read_text())["results"]["per_seed"]["0"]
    assert again == rows and (out / "table.md").read_text() == table


@pytest.mark.parametrize(("args", "needle"), [
    (["--models", "sindy2"], "--models: the pendulum-video world's study does not take this"),
    (["--sweep", "lambda_l1=1e-3,1e-2"], "--sweep: the pendulum-video world's study"),
    (["--image-size", "64"], "--image-size: the pendulum-video world's study"),
    (["--data", "x.h5", "--workers", "1"], "--workers, --data: the pendulum-video world's "
                                           "study does not take these options"),
    (["--executor", "ray"], "--executor: the pendulum-video world's study does not take"),
    (["--scale", "paper"], "the pendulum-video world's scales are tiny, demo, recovery, "
                           "recovery-frames, published"),
])
def test_push_settings_are_refused_with_a_pendulum_world(tmp_path, capsys, args, needle):
    out = tmp_path / "study"
    line = _error(capsys, "reproduce", "--world", "pendulum-video", "--scale", "tiny",
                  "--out", str(out), *args)
    assert needle in line and not out.exists()


@pytest.mark.parametrize(("args", "needle"), [
    (["--scale", "published"], "the push world's scales are"),
    (["--world", "moon"], "--world moon: use a world with a study of its own (dmc, gym, "),
    (["--world", "moon"], "or a named world of one (symmetric, paper, marked"),
    (["--world", "pendulum", "--scale", "large"], "pendulum world's scales are tiny, demo"),
])
def test_settings_of_the_other_kind_of_study_are_refused(tmp_path, capsys, args, needle):
    out = tmp_path / "study"
    line = _error(capsys, "reproduce", "--out", str(out), *(
        args if "--scale" in args else [*args, "--scale", "tiny"]))
    assert needle in line and not out.exists()


def test_a_held_study_folder_is_refused(tmp_path, capsys):
    out = tmp_path / "study"
    with exclusive(out, "study folder"):
        line = _error(capsys, "reproduce", "--world", "pendulum", "--scale", "tiny", "--out",
                      str(out))
    assert "is using this study folder" in line and not (out / "summary.json").exists()


def test_the_help_names_the_worlds_and_their_scales(capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "400")
    with pytest.raises(SystemExit):
        main(["reproduce", "--help"])
    text = " ".join(capsys.readouterr().out.replace("│", " ").split())
    for name in ("pendulum-video", "pendulum", "symmetric", "published", "scalefree",
                 "48x48 images as E2C", "--device"):
        assert name in text, name


def test_each_scale_names_its_seeds_and_schedule():
    """Without --seeds a world study runs its scale's seeds; given ones win."""
    from latent_sindy.study.runner import study_world
    from latent_sindy.study.settings import StudySettings
    from latent_sindy.worlds.pendulum.reproduce import pendulum_config, video_config

    cfg = StudySettings(world="pendulum-video", scale="demo")
    assert cfg.seeds is None and study_world(cfg.world)[1] is VIDEO
    demo = video_config("demo", cfg.seeds, "auto", 1)
    assert demo.seeds == (0, 1, 2) and demo.schedule == "scalefree"
    assert demo.splits == (100, 10, 10)
    frames = video_config("recovery-frames", None, "cpu", 1)
    assert frames.seeds == tuple(range(10)) and frames.derivatives == "central"
    assert frames.resolved_schedule().calibrate_epochs > 0
    published = video_config("published", None, "cuda", 1)
    assert published.seeds == tuple(range(10)) and published.schedule == "published"
    assert published.resolved_schedule().epochs == 6002 and published.device == "cuda"
    assert video_config("demo", (4, 7), "cpu", 1).seeds == (4, 7)
    assert pendulum_config("published", 3, "cpu").image_size == 48
    cpu = pendulum_config("published-cpu", 0, "cpu")
    assert (cpu.image_size, cpu.sequences, cpu.models) == (48, 1000, ())
    assert cpu.centroid_models == ("sindy", "mlp", "linear") and cpu.start == "random"
    assert cpu.centroid_latent == "centroid"
    learned = pendulum_config("geodesic-published", 0, "cpu")
    assert (learned.image_size, learned.sequences, learned.models) == (48, 1000, ())
    assert learned.centroid_latent == "geodesic"
    assert pendulum_config("geodesic", 0, "cpu").centroid_latent == "geodesic"


@pytest.mark.skipif(__import__("torch").cuda.is_available(), reason="a CUDA device is here")
def test_cuda_asked_for_on_a_machine_without_one_is_refused_up_front(tmp_path, capsys):
    out = tmp_path / "study"
    line = _error(capsys, "reproduce", "--world", "pendulum-video", "--scale", "tiny", "--out",
                  str(out), "--device", "cuda")
    assert "--device cuda" in line and "sees no CUDA device" in line and not out.exists()


@pytest.mark.parametrize("successes", [0, 49, 50])
def test_the_success_figure_draws_every_count_with_its_interval(tmp_path, successes):
    """All or none of 50 puts the Wilson interval's end on the rate itself."""
    from latent_sindy.worlds.pendulum.reproduce import _pendulum_figure

    rows = [{"model": m, "successes": k, "episodes": 50,
             "success_wilson95": list(wilson_interval(k, 50))}
            for m, k in (("state", successes), ("sindy", 50 - successes))]
    path = _pendulum_figure({0: rows, 1: rows}, tmp_path / "f.png")
    assert path.read_bytes()[:4] == b"\x89PNG"


def test_a_poor_first_start_is_restarted_and_the_calibration_can_prune():
    """Schedule.restarts: a first phase that reconstructs the validation frames worse than
    ``restart_above`` gets a fresh start (never with an unreachable bound, always with 0);
    the calibration runs scale-free and prunes when asked."""
    from dataclasses import replace

    video = video_pca.compressed_video(8, 5, "exact", (4, 2, 2), 50)
    data, lo, span = video_study.as_sequences(video)
    base = replace(video_study.SCHEDULES["scalefree"], epochs=2, refine_epochs=1,
                   prune_every=1, calibrate_epochs=3, calibrate_prune_every=1,
                   restart_fvu=float("inf"))
    never = video_study.train_seed(0, replace(base, restart_above=float("inf")), data, 8,
                                   video, lo, span)
    assert never["starts"] == 1 and never["start_kept"] == 1
    always = video_study.train_seed(0, replace(base, restart_above=0.0), data, 8, video, lo,
                                    span)
    assert always["starts"] == 2 and always["start_kept"] in (1, 2)
    assert always["epochs"] == 5
    # The second rule: calibrated equations that leave more than restart_fvu of z̈
    # unexplained (0: always) start again, and the start with the smaller fraction is kept.
    unexplained = video_study.train_seed(0, replace(base, restart_above=float("inf"),
                                                    restart_fvu=0.0), data, 8, video, lo, span)
    assert unexplained["starts"] == 2 and unexplained["start_kept"] in (1, 2)
    with pytest.raises(Exception, match="calibrate"):
        video_study.Schedule(1, 1e-3, 10, 5, 1, 0, calibrate_prune_every=-1)
    with pytest.raises(Exception, match="restart_fvu"):
        video_study.Schedule(1, 1e-3, 10, 5, 1, 0, restart_fvu=0.01)


def test_the_video_at_another_frequency_is_a_world_setting(tmp_path, monkeypatch):
    """``--world-config omega2=...`` makes the video at that ω²: its seeds train on it and
    are judged against -ω², and its rows are not those of the ω² = 1 study."""
    seen: list[float] = []

    def fake(seed, s, data, k, video, lo, span, device, omega2):
        seen.append(omega2)
        c = -2.25 * 1.01
        return {"seed": seed, "equation": f"z0'' = {c} sin(z0)", "exact_sin": True,
                "coefficient": c, "coefficients": {"sin(z0)": c}, "fvu_x": 0.1,
                "fvu_ddx": 0.2, "fvu_ddz": 0.3, "time_s": 1.0,
                "recovered": abs(c / omega2 + 1) <= 0.02}

    monkeypatch.setattr(video_study, "train_seed", fake)
    out = tmp_path / "study"
    assert main(["reproduce", "--world", "pendulum-video", "--world-config", "omega2=2.25",
                 "--scale", "tiny", "--out", str(out), "--device", "cpu"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert seen == [2.25] and summary["results"]["summary"]["recovered"] == 1
    assert summary["results"]["config"]["omega2"] == 2.25
    key = json.loads((out / "seeds.jsonl").read_text().splitlines()[0])["key"]
    assert key["omega2"] == 2.25 and key["time_unit"] == "data"
