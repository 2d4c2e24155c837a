"""The family of videos the estimator's default is judged on, and the judge itself."""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from latent_sindy.errors import UserError
from latent_sindy.worlds.pendulum.video_draws import (
    RANGES,
    SYSTEMS,
    VideoDraw,
    draw,
    judge_equations,
)

ROOT = Path(__file__).resolve().parents[1]


def small(d: VideoDraw, **changes) -> VideoDraw:
    return dataclasses.replace(d, **{"trajectories": 4, "frames": 60, **changes})


@pytest.mark.parametrize("system", SYSTEMS)
def test_exact_derivatives_match_finite_differences_of_the_frames(system):
    d = small(draw(np.random.default_rng(5), system=system), dt=0.002, noise=0.0,
              background=0.0, exact=True, size=24)
    v = d.video()
    x = v.images.astype(np.float64)
    fd1 = (x[:, 2:] - x[:, :-2]) / (2 * d.dt)
    fd2 = (x[:, 2:] - 2 * x[:, 1:-1] + x[:, :-2]) / d.dt ** 2
    for fd, exact in ((fd1, v.images_dot), (fd2, v.images_ddot)):
        ref = exact[:, 1:-1]
        assert np.abs(fd - ref).max() < 0.01 * np.abs(ref).max()


def test_states_obey_the_drawn_law():
    d = VideoDraw(system="pendulum", omega2=(2.0,), damping=(0.3,), trajectories=3, frames=50,
                  dt=0.05)
    q = d.states()[:, :, 0]  # (N, F, 3): q, q̇, q̈
    assert np.allclose(q[..., 2], -2.0 * np.sin(q[..., 0]) - 0.3 * q[..., 1])
    energy = q[..., 1] ** 2 / 2 - 2.0 * np.cos(q[..., 0])
    assert np.all(np.diff(energy, axis=1) <= 1e-9)  # friction only takes energy away
    assert np.all(np.abs(q[:, 0, 0]) < math.pi)


def test_draws_stay_within_the_ranges_and_repeat_by_seed():
    seen = set()
    for i in range(40):
        d = draw(np.random.default_rng([7, i]))
        seen.add(d.system)
        assert RANGES["size"][0] <= d.size <= RANGES["size"][1]
        assert RANGES["trajectories"][0] <= d.trajectories <= RANGES["trajectories"][1]
        assert RANGES["frames"][0] <= d.frames <= RANGES["frames"][1]
        for w2, c in zip(d.omega2, d.damping, strict=True):
            assert RANGES["omega2"][0] <= w2 <= RANGES["omega2"][1]
            assert 0 <= c <= min(0.4, 0.3 * math.sqrt(w2)) + 1e-12
            assert d.dt * math.sqrt(w2) <= 2 * math.pi / 8 + 1e-12  # 8 frames a period
        assert d == draw(np.random.default_rng([7, i]))
    assert seen == set(SYSTEMS)


def test_video_is_a_valid_sequence_with_or_without_derivatives():
    d = small(draw(np.random.default_rng(3), system="pendulum"), noise=0.02, background=0.3)
    with_rates = dataclasses.replace(d, exact=True).video()
    frames_only = dataclasses.replace(d, exact=False).video()
    assert with_rates.images.min() >= 0 and with_rates.images.max() <= 1
    assert with_rates.images_ddot is not None and frames_only.images_dot is None
    assert np.array_equal(with_rates.images, frames_only.images)
    assert with_rates.split_counts()["train"] >= 1


def test_judge_names_each_failure():
    d = VideoDraw(system="pendulum", omega2=(1.5,), damping=(0.2,))
    names = ["1", "z0", "z0'", "sin(z0)", "z0 z0'^2"]
    ok = judge_equations(d, names, np.array([[0, 0, -0.21, -1.52, 0]]))
    assert ok == {"recovered": True, "why": ""}
    assert judge_equations(d, names, np.zeros((1, 5)))["why"] == "all terms pruned"
    assert judge_equations(d, names, np.array([[0, 0, 0, -1.5, 0]]))["why"] == "missed z0'"
    wrong = judge_equations(d, names, np.array([[0, -0.2, -0.2, -1.5, 0]]))
    assert wrong["why"] == "wrong term z0"
    assert "off by" in judge_equations(d, names, np.array([[0, 0, -0.2, -1.3, 0]]))["why"]
    assert not judge_equations(d, names, np.array([[0, 0, -0.25, -1.5, 0]]))["recovered"]
    assert not judge_equations(d, names, np.array([[0, 0, np.nan, -1.5, 0]]))["recovered"]


def test_judge_takes_two_pendulums_in_either_order_and_a_spring_offset():
    two = VideoDraw(system="two_pendulums", omega2=(1.0, 2.0), damping=(0.0, 0.1),
                    centre=((-0.5, 0.0), (0.5, 0.0)), radius=(0.3, 0.3), direction=(0.0, 0.0))
    names = ["z0", "z1", "z0'", "z1'", "sin(z0)", "sin(z1)"]
    swapped = np.array([[0, 0, -0.1, 0, -2.0, 0], [0, 0, 0, 0, 0, -1.0]])
    assert judge_equations(two, names, swapped)["recovered"]
    spring = VideoDraw(system="spring", omega2=(2.0,), damping=(0.1,))
    assert judge_equations(spring, ["1", "z0", "z0'"], np.array([[0.4, -2.0, -0.1]]))[
        "recovered"]


def test_a_draw_refuses_inconsistent_settings():
    with pytest.raises(UserError, match="one per blob"):
        VideoDraw(system="two_pendulums")
    with pytest.raises(UserError, match="system"):
        VideoDraw(system="rope")


@pytest.mark.slow  # about a minute on 2 cores: three runs of the benchmark script
def test_benchmark_smoke_writes_a_row_per_fit_and_resumes(tmp_path):
    out = tmp_path / "rows.jsonl"
    cmd = [sys.executable, str(ROOT / "benchmarks" / "video_draws.py"), "--smoke",
           "--derivatives", "exact", "--out", str(out)]
    first = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stderr
    assert len(out.read_text().splitlines()) == 1
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0 and len(out.read_text().splitlines()) == 1
    assert "recovered 0 of 1" in again.stdout or "recovered 1 of 1" in again.stdout
    # --record: the fit's row in the tracked result file, under the label and the mode
    record = subprocess.run([*cmd, "--record", str(tmp_path / "results"), "--label", "trial"],
                            capture_output=True, text=True, timeout=600)
    assert record.returncode == 0, record.stderr
    from latent_sindy.result_files import read_rows

    rows = read_rows(tmp_path / "results" / "pendulum-video" / "family-draws.csv")
    assert [(r["model"], r["case"]) for r in rows] == [("trial, exact derivatives", "draw 0")]
    assert rows[0]["recovered"] in (True, False) and rows[0]["fit_s"] >= 0


def test_benchmark_refuses_bad_arguments(tmp_path):
    script = str(ROOT / "benchmarks" / "video_draws.py")
    for args in (["--derivatives", "pixels"], ["--workers", "0"], ["--only", "5..2"],
                 ["--out", str(tmp_path)]):
        r = subprocess.run([sys.executable, script, *args], capture_output=True, text=True,
                           timeout=120)
        assert r.returncode == 2, (args, r.stderr)
        assert "Traceback" not in r.stderr


# ------------------------------------------------------------------ the second generator
def _second_generator():
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "second_generator", ROOT / "benchmarks" / "second_generator.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # (its dataclass looks its module up)
    spec.loader.exec_module(module)
    return module


def test_the_second_generator_draws_within_the_family_ranges_its_own_way():
    gen = _second_generator()
    draws = [gen.second_draw(np.random.default_rng([0, i, 2])) for i in range(40)]
    for d in draws:
        assert 0.3 <= min(d.omega2) and max(d.omega2) <= 4.0
        assert all(c <= min(0.4, 0.3 * math.sqrt(w2)) + 1e-12
                   for w2, c in zip(d.omega2, d.damping, strict=True))
        assert 24 <= d.size <= 80 and 20 <= d.trajectories <= 200 and 40 <= d.frames <= 400
        assert 0.01 <= d.dt <= min(0.15, 2 * math.pi / math.sqrt(max(d.omega2)) / 8) + 1e-12
        assert 0 <= d.noise <= 0.02
    # the habits the family does not have, each drawn somewhere
    assert {d.style for d in draws} == set(gen.STYLES)
    assert {d.split for d in draws} == {"none", "random"}
    assert any(d.uint8 for d in draws) and not any(d.uint8 and d.exact for d in draws)
    assert {d.system for d in draws} == set(SYSTEMS)


@pytest.mark.parametrize("system", SYSTEMS)
def test_the_second_generators_derivatives_match_finite_differences(system):
    gen = _second_generator()
    d = next(d for i in range(60)
             if (d := gen.second_draw(np.random.default_rng([1, i, 2]))).system == system)
    d = dataclasses.replace(d.shrunk(24, 3, 60), dt=0.002, noise=0.0, texture=0.2,
                            exact=True, uint8=False)
    v = d.video()
    assert v.images.dtype == np.float64 and v.images.min() == 0 and v.images.max() == 1
    x = v.images
    fd2 = (x[:, 2:] - 2 * x[:, 1:-1] + x[:, :-2]) / d.dt ** 2
    ref = v.images_ddot[:, 1:-1]
    assert np.abs(fd2 - ref).max() < 0.01 * np.abs(ref).max()
    # the law it judges by is the family's, in the library's names
    assert d.law() == VideoDraw(system=system, omega2=d.omega2, damping=d.damping,
                                centre=((0, 0),) * d.latent_dim, radius=(0.5,) * d.latent_dim,
                                direction=(0,) * d.latent_dim).law()


def test_the_second_generator_films_a_camera_video_as_uint8_with_no_split():
    gen = _second_generator()
    d = gen.second_draw(np.random.default_rng(4))
    d = dataclasses.replace(d.shrunk(24, 10, 40), exact=False, uint8=True, split="none")
    v = d.video()
    assert v.images.dtype == np.uint8 and v.images_ddot is None
    assert v.split_counts()["train"] > 0 and v.split_counts()["val"] > 0
