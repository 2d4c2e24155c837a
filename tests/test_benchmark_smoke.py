"""Every kept benchmark's ``--smoke`` run: tiny sizes through the real code path, and the
figures it prints have the rows and the finite numbers its full run would print.

Each script runs in this process (``main(argv)``), so the suite pays no extra interpreter or
torch start-up per benchmark. ``benchmarks/video_draws.py --smoke`` is run (twice, with its
resume) by tests/test_video_draws.py. Benchmarks of an optional extra (dm-control, pysindy,
scikit-learn) skip where it is not installed.
"""

from __future__ import annotations

import importlib.util
import json
import math
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NUMBER = r"[-+]?(?:\d+\.?\d*(?:e[-+]?\d+)?|nan|inf)"


def _run(name: str, monkeypatch, capsys, *argv: str) -> str:
    """``benchmarks/NAME.py --smoke ARGV`` in this process; its stdout."""
    import torch

    spec = importlib.util.spec_from_file_location(f"bench_{name}", ROOT / "benchmarks" /
                                                  f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)  # (its dataclasses look it up)
    spec.loader.exec_module(module)
    threads = torch.get_num_threads()
    try:
        status = module.main(["--smoke", *argv])
    finally:
        torch.set_num_threads(threads)
    assert status in (None, 0), status
    return capsys.readouterr().out


def _numbers(line: str) -> list[float]:
    return [float(v) for v in re.findall(NUMBER, line.split(None, 1)[1] if " " in line
                                         else line)]


def _row(out: str, start: str) -> str:
    rows = [ln for ln in out.splitlines() if ln.startswith(start)]
    assert rows, f"no line starts with {start!r}:\n{out}"
    return rows[0]


def _finite_positive(values: list[float]) -> bool:
    return bool(values) and all(math.isfinite(v) and v > 0 for v in values)


def test_collect(monkeypatch, capsys):
    out = _run("collect", monkeypatch, capsys)
    push = re.search(r"one push: (\S+) ms \((\d+) simulation steps", out)
    assert push and float(push[1]) > 0 and int(push[2]) > 0, out
    render = re.search(r"observation render: (\S+) ms camera world vs (\S+) ms full scene", out)
    assert render and 0 < float(render[1]) < float(render[2]), out
    rate = _row(out, "       1 ").split()
    assert float(rate[1]) > 0 and float(rate[2]) >= 1.0, out  # transitions/s, attempts


def test_mppi(monkeypatch, capsys):
    pytest.importorskip("pytorch_mppi")
    out = _run("mppi", monkeypatch, capsys)
    for setting in ("K=16, H=3", "K=8, H=2"):
        table = out.split(setting + ":", 1)[1].split("\n\n", 1)[0]
        for model in ("sindy1", "sindy2", "sindy3", "sindy4", "linear", "mlp"):
            cells = _row(table.split("\n", 2)[2], model).split()
            assert _finite_positive([float(cells[1]), float(cells[2])]), table
    assert "ours SINDy-2 / ours linear" in out and out.count("target") == 4


def test_train(monkeypatch, capsys):
    out = _run("train", monkeypatch, capsys)
    sindy = _row(out, "sindy2").split()
    assert sindy[1] == "1" and sindy[2] == "226", out  # H, library terms of order 2 (nz 16)
    assert _finite_positive([float(v) for v in sindy[3:7]]), out


def test_reach(monkeypatch, capsys):
    out = _run("reach", monkeypatch, capsys)
    for region in ("workspace", "bounds", "far"):
        made = re.search(rf"^{region}\s+made\s+(\S+) % \[\S+, \S+\] \((\d+)/12\)", out, re.M)
        assert made and 0 <= float(made[1]) <= 100, out
    # the sampling workspace is within reach (BENCHMARKS.md: 300 of 300)
    assert "(12/12)" in _row(out, "workspace"), out


def test_fit_state(monkeypatch, capsys):
    pytest.importorskip("pysindy")
    out = _run("fit_state", monkeypatch, capsys)
    clean = _row(out, "duffing     0").split("|")
    assert clean[1].split()[0] == "yes", out  # our STLSQ recovers the noise-free law
    assert "exact recovery: ours 1/1" in out, out
    noisy = [ln for ln in out.split("noisy:", 1)[1].splitlines() if ln.startswith("duffing")]
    assert len(noisy) == 13 and all(math.isfinite(float(ln.split()[-1])) for ln in noisy), out


def test_prediction_floor(monkeypatch, capsys):
    pytest.importorskip("sklearn")
    out = _run("prediction_floor", monkeypatch, capsys)
    rows = [ln for ln in out.split("h=10", 1)[1].splitlines() if ln.strip()]
    assert len(rows) == 8, out
    for ln in rows:
        cells = [float(v) for v in re.findall(r"(\d+\.\d+) /\s*(\d+\.\d+)", ln)[0]]
        assert all(math.isfinite(v) and v >= 0 for v in cells), ln
    def one_push(model: str) -> float:  # position error (cm) after one push
        return float(re.findall(r"(\d+\.\d+) /", _row(out, model))[0])

    # the true pose and the push tell more than "nothing moves" (the data is seeded)
    assert one_push("extra-trees (true pose") < one_push("nothing moves"), out


def test_textured_world(monkeypatch, capsys):
    out = _run("textured_world", monkeypatch, capsys)
    for name in ("position mean (cm)", "orientation mean (deg)", "weight on the block (%)"):
        values = [float(v) for v in _row(out, name)[len(name):].split()]
        assert len(values) == 5 and all(math.isfinite(v) and v >= 0 for v in values), out
    # the symmetric world's plain table isolates the block: all the weight falls on it
    assert float(_row(out, "weight on the block (%)").split()[-5]) > 90, out


def test_pendulum_video(monkeypatch, capsys):
    out = _run("pendulum_video", monkeypatch, capsys)
    row = json.loads(out.strip().splitlines()[-1])
    assert row["train_frames"] == 500 and row["batch"] == 50 and row["steps_per_epoch"] == 10
    assert 0 < row["step_best_s"] <= row["step_median_s"] and math.isfinite(
        row["published_run_h"])


def test_suite(monkeypatch, capsys, tmp_path):
    out = _run("suite", monkeypatch, capsys, "--json", str(tmp_path / "rows.json"))
    row = _row(out, "| lorenz |")
    assert "failed" not in row and row.split("|")[2].strip() == "1", out
    rows = json.loads((tmp_path / "rows.json").read_text())["rows"]
    assert len(rows) == 1 and math.isfinite(rows[0]["one_step"]) and rows[0]["terms"] > 0
    # the ratio a perfect latent step would reach: the next frames encoded and decoded
    assert math.isfinite(rows[0]["ceiling"]) and rows[0]["ceiling"] > 0
    assert row.count("x |") >= 3, out  # one-step, the ceiling and the rollout


def test_latent_probe(monkeypatch, capsys):
    pytest.importorskip("pygame", reason="the gym extra (classic-control rendering) is not "
                        "installed")
    out = _run("latent_probe", monkeypatch, capsys)
    for probe in ("linear", "quadratic"):
        row = [ln for ln in out.splitlines() if ln.startswith("| 2 |") and f"| {probe} |" in ln]
        assert len(row) == 1, out
        values = _numbers(row[0])
        # the coordinates, R² of cos θ, sin θ and θ', the share seen, the fit seconds
        assert len(values) == 6 and all(math.isfinite(v) and v <= 1.0 for v in values[1:4])
        assert values[4] == 1.0, out  # the geodesic reader reads every frame


def test_latent_probe_of_the_keypoint_reader(monkeypatch, capsys):
    pytest.importorskip("pygame", reason="the gym extra (classic-control rendering) is not "
                        "installed")
    out = _run("latent_probe", monkeypatch, capsys, "--reader", "keypoints", "--parts", "2")
    assert "keypoints latent" in out, out
    for probe in ("linear", "quadratic"):
        row = [ln for ln in out.splitlines() if ln.startswith("| 2 (") and f"| {probe} |" in ln]
        assert len(row) == 1, out
        values = _numbers(row[0])
        # the keypoints, the coordinates kept, R² of cos θ, sin θ and θ', the share of the
        # frames seen, the fit seconds
        assert len(values) == 7 and 1 <= values[1] <= 4 and 0 < values[5] <= 1, out
        assert all(math.isfinite(v) and v <= 1.0 for v in values[2:5]), out


# ------------------------------------------------------------------ the dmc extra
def _dm_control():
    pytest.importorskip("dm_control", reason="the dmc extra is not installed")


def test_dmc(monkeypatch, capsys):
    _dm_control()
    out = _run("dmc", monkeypatch, capsys)
    frame = re.search(r"32x32: (\S+) ms a frame rendered, (\S+) ms a control step", out)
    assert frame and _finite_positive([float(frame[1]), float(frame[2])]), out
    assert re.search(r"collect 1 x 3 .* actions/s", out), out


def test_dmc_model_based(monkeypatch, capsys):
    _dm_control()
    out = _run("dmc_model_based", monkeypatch, capsys)
    kinds = re.findall(r"^\s+\d+\s+(random|planned)\s+(\S+)", out, re.M)
    assert [k for k, _ in kinds] == ["random", "planned"], out
    assert all(math.isfinite(float(r)) for _, r in kinds), out
    assert re.search(r"iteration 1: fit \S+ s", out), out


def test_dmc_states(monkeypatch, capsys):
    _dm_control()
    out = _run("dmc_states", monkeypatch, capsys)
    for fit in ("plain", "trimmed"):
        mean = re.search(rf"^{fit}\s*: mean return over 1 seeds (\S+)", out, re.M)
        assert mean and math.isfinite(float(mean[1])) and float(mean[1]) >= 0, out
    assert "z4[t+1] = " in out, out  # the first seed's equations


def test_dmc_reader_accuracy(monkeypatch, capsys):
    _dm_control()
    out = _run("dmc_reader_accuracy", monkeypatch, capsys)
    assert "a sweep of 60 poses" in out, out
    seen = [float(v) for v in re.findall(r"seen (\d\.\d+)", out)]
    assert len(seen) == 4 and all(0 < v <= 1 for v in seen), out
    errors = re.findall(r"sweep: seen \S+; angle error (\S+)°", out)
    assert len(errors) == 2 and all(float(e) < 20 for e in errors), out


def test_pca_front(monkeypatch, capsys):
    out = _run("pca_front", monkeypatch, capsys)
    (low,) = re.findall(r"principal angles: min (\S+)", out)
    assert float(low) > 0.999, out  # the same subspace both ways
    assert "subspace iteration / exact" in out


# ------------------------------------------------------------------ the smoke flag itself
def test_smoke_changes_defaults_and_a_given_flag_still_wins():
    import argparse

    from latent_sindy.errors import UserError
    from latent_sindy.script_args import parse_with_smoke

    def parser() -> argparse.ArgumentParser:
        p = argparse.ArgumentParser(prog="bench")
        p.add_argument("--episodes", type=int, default=30)
        p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
        return p

    full = parse_with_smoke(parser(), [], {"episodes": 2, "seeds": [0]})
    assert (full.smoke, full.episodes, full.seeds) == (False, 30, [0, 1, 2])
    smoke = parse_with_smoke(parser(), ["--smoke"], {"episodes": 2, "seeds": [0]})
    assert (smoke.smoke, smoke.episodes, smoke.seeds) == (True, 2, [0])
    given = parse_with_smoke(parser(), ["--smoke", "--episodes", "5"], {"episodes": 2})
    assert given.episodes == 5
    with pytest.raises(UserError, match="'epochs' is no option of bench"):
        parse_with_smoke(parser(), ["--smoke"], {"epochs": 1})


def _pendulum_study(out: Path, latent: str = "geodesic") -> Path:
    """A model-based study's folder as ``reproduce --world gym`` leaves it, of a blob going
    round a pivot at 16×16 (two frames stacked): its settings and one seed's episodes,
    4 random and 4 planned, with the states (cos θ, sin θ, θ')."""
    import dataclasses

    import numpy as np

    from latent_sindy.data import SequenceData, write_sequences
    from latent_sindy.worlds.gym.study import SCALES

    rng = np.random.default_rng(0)
    n, steps, size, dt = 8, 40, 16, 0.05
    yy, xx = np.mgrid[0:size, 0:size]

    def frame(theta: float) -> np.ndarray:
        cx, cy = 7.5 + 5 * np.sin(theta), 7.5 - 5 * np.cos(theta)
        return (255 * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / 3.0)).astype(np.uint8)

    images = np.zeros((n, steps + 1, 2, size, size), np.uint8)
    states = np.zeros((n, steps + 1, 3), np.float32)
    for e in range(n):
        theta, rate = rng.uniform(0, 2 * np.pi), rng.uniform(-4, 4)
        before = frame(theta)
        for t in range(steps + 1):
            images[e, t] = before, frame(theta)
            states[e, t] = np.cos(theta), np.sin(theta), rate
            before, theta = frame(theta), theta + rate * dt
    loop = dataclasses.asdict(dataclasses.replace(SCALES["geodesic"], seed_episodes=4,
                                                  latent=latent, latent_dim=2, frames=2))
    del loop["about"], loop["seeds"]
    (out / "seed0" / "sindy").mkdir(parents=True)
    (out / "gym_study.json").write_text(json.dumps(
        {"scale": "geodesic", "world": {"id": "Pendulum-v1", "size": size, "frames": 2},
         "loop": loop}))
    write_sequences(out / "seed0" / "sindy" / "data.h5", SequenceData(
        images, rng.uniform(-1, 1, (n, steps, 1)).astype(np.float32), action_low=[-1.0],
        action_high=[1.0], rewards=np.zeros((n, steps), np.float32), states=states, dt=dt))
    return out


def test_latent_probe_of_a_studys_own_latent(monkeypatch, capsys, tmp_path):
    study = _pendulum_study(tmp_path / "study")
    out = _run("latent_probe", monkeypatch, capsys, "--study", str(study))
    assert "4 planned episodes" in out and "2 geodesic coordinate(s), read as an angle" in out
    row = [ln for ln in out.splitlines() if ln.startswith("| 2 |") and "| linear |" in ln]
    values = _numbers(row[0])
    assert values[1] > 0.9 and values[2] > 0.9, out  # cos θ and sin θ, read as the angle
    with pytest.raises(SystemExit, match=r"one \*_study\.json"):
        _run("latent_probe", monkeypatch, capsys, "--study", str(tmp_path))
    read = _pendulum_study(tmp_path / "read", latent="read")
    with pytest.raises(SystemExit, match="its latent is 'read'"):
        _run("latent_probe", monkeypatch, capsys, "--study", str(read))


def test_sindy_fit_choice_on_a_studys_own_latent(monkeypatch, capsys, tmp_path):
    from latent_sindy.read_latent import ERROR_CAP, FIT_CHOICES

    study = _pendulum_study(tmp_path / "study")
    out = _run("sindy_fit_choice", monkeypatch, capsys, "--study", str(study))
    fixed, checked = _row(out, "| fixed |"), _row(out, "| checked |")
    sparse = _row(out, "| sparsest within 2 |")
    assert "window 5, trim 0.3, min_share 0.03" in fixed  # (the geodesic scale's fit)
    for row in (fixed, checked, sparse):
        terms, error, diverged = (float(v) for v in re.findall(NUMBER, row.split("|", 3)[3])[:3])
        assert terms >= 1 and 0 <= error <= ERROR_CAP and 0 <= diverged <= 100
    tried = [ln for ln in out.splitlines() if ln.startswith(("* window", "  window"))]
    marked = [ln for ln in tried if ln.startswith("*")]
    assert len(marked) == 1 and marked[0][2:].split(":")[0] in checked
    assert tried[0][2:].startswith("window 5, trim 0.3, min_share 0.03")  # (the set fit first)
    assert len(tried) in (1, len(FIT_CHOICES))
    read = _pendulum_study(tmp_path / "read", latent="read")
    with pytest.raises(SystemExit, match="its latent is 'read'"):
        _run("sindy_fit_choice", monkeypatch, capsys, "--study", str(read))
