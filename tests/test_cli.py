"""Every command answers by subprocess; bad input is one line on stderr, exit 2, no damage."""

from __future__ import annotations

import subprocess
import sys

import pytest

from latent_sindy.cli import main
from latent_sindy.data import write_sequences
from synthetic import make_trajectories


def run(*args: str, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "latent_sindy.cli", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


def assert_one_line_error(r: subprocess.CompletedProcess, *needles: str) -> None:
    assert r.returncode == 2, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("latent-sindy: error:"), r.stderr
    assert "Traceback" not in r.stderr
    for n in needles:
        assert n in lines[0]


def test_help_lists_commands_and_options():
    r = run("--help")
    assert r.returncode == 0
    for cmd in ("collect", "info", "preview", "train", "equations", "control", "reproduce"):
        assert cmd in r.stdout
    r = run("collect", "--help")
    assert r.returncode == 0 and "--trajectories" in r.stdout and "resum" in r.stdout


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--steps", "0"], "--steps 0"),
        (["--workers", "-2"], "--workers -2"),
        (["--trajectories", "0"], "--trajectories 0"),
        (["--channels", "2"], "channels=2"),
        (["--test-fraction", "-0.1"], "--test-fraction -0.1"),
    ],
)
def test_collect_rejects_impossible_settings(tmp_path, args, needle):
    out = tmp_path / "d.h5"
    r = run("collect", "--out", str(out), "--no-progress", *args)
    assert_one_line_error(r, needle)
    assert not out.exists()


def test_info_on_missing_foreign_and_valid_files(tmp_path):
    assert_one_line_error(run("info", str(tmp_path / "none.h5")), "does not exist")
    junk = tmp_path / "junk.h5"
    junk.write_text("hello")
    assert_one_line_error(run("info", str(junk)), str(junk), "not an HDF5 file")
    good = tmp_path / "good.h5"
    write_sequences(good, make_trajectories())
    r = run("info", str(good))
    assert r.returncode == 0 and "valid latent-sindy data file" in r.stdout


def test_collect_does_not_overwrite_a_foreign_file(tmp_path):
    out = tmp_path / "d.h5"
    out.write_bytes(b"precious")
    r = run("collect", "--out", str(out), "--trajectories", "2", "--steps", "1",
            "--no-progress")
    assert_one_line_error(r, str(out), "delete it or choose another --out")
    assert out.read_bytes() == b"precious"


def test_collect_info_preview_end_to_end(tmp_path):
    out = tmp_path / "d.h5"
    r = run("collect", "--out", str(out), "--trajectories", "3", "--steps", "2",
            "--workers", "2", "--val-fraction", "0.34", "--test-fraction", "0")
    assert r.returncode == 0, r.stderr
    assert "wrote" in r.stdout and out.exists()
    r = run("collect", "--out", str(out), "--trajectories", "3", "--steps", "2",
            "--workers", "2", "--val-fraction", "0.34", "--test-fraction", "0")
    assert r.returncode == 0 and "already complete" in r.stdout
    r = run("preview", str(out), "--rows", "2")
    assert r.returncode == 0, r.stderr
    png = out.with_suffix(".png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert_one_line_error(run("preview", str(out), "--rows", "0"), "--rows 0")


def test_train_equations_control_smoke(tmp_path):
    data = tmp_path / "d.h5"
    write_sequences(data, make_trajectories(n=6, steps=3))
    run_dir = tmp_path / "run"
    r = run("train", "sindy", "--data", str(data), "--order", "1", "--epochs", "2",
            "--prune-every", "1", "--out", str(run_dir), "--no-progress")
    assert r.returncode == 0, r.stderr
    for name in ("config.json", "model.pt", "metrics.csv", "loss.png"):
        assert (run_dir / name).is_file(), name
    assert_one_line_error(
        run("train", "--data", str(data), "--out", str(run_dir), "--epochs", "2"),
        "already holds a trained model")
    r = run("equations", str(run_dir))
    assert r.returncode == 0, r.stderr
    assert "z0[t+1] = z0" in r.stdout and "sparsity" in r.stdout
    assert (run_dir / "coefficients.csv").is_file()
    r = run("control", str(run_dir), "--max-steps", "2", "--samples", "8", "--horizon", "2",
            "--no-progress")
    assert r.returncode == 0, r.stderr
    out = run_dir / "control-paper-latent"
    assert (out / "results.json").is_file() and (out / "episode_000.gif").is_file()
    assert "success (course)" in r.stdout


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["train", "--epochs", "0"], "--epochs 0"),
        (["train", "sindy", "--order", "5"], "order 5"),
        (["train", "--data", "nowhere.h5"], "does not exist"),
        (["equations", "no-run"], "no-run"),
        (["control", "no-run"], "no-run"),
    ],
)
def test_learning_commands_reject_bad_input(tmp_path, args, needle):
    assert_one_line_error(run(*args, cwd=tmp_path), needle)



def main_error(capsys, *args: str) -> str:
    """Run the command in this process (fast); the one line it printed on stderr."""
    code = main(list(args))
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("latent-sindy: error:"), err
    return lines[0]


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--seeds", "0..x"], "--seeds '0..x'"),
        (["--seeds", "5..2"], "--seeds 5..2"),
        (["--seeds", "0", "0"], "distinct"),
        (["--sweep", "lambda_l1"], "SETTING=V1,V2"),
        (["--sweep", "colour=1,2"], "unknown setting 'colour'"),
        (["--sweep", "order=1,x"], "'x' is not an int"),
        (["--sweep", "order=2,5"], "order 5"),
        (["--sweep", "lambda_l1=1e-3,1e-3"], "distinct values"),
        (["--sweep", "lambda_l1=-1"], "--sweep lambda_l1=-1"),
        (["--sweep", "order=1,2", "--models", "linear"], "none of the chosen models"),
        (["--models", "sindy9"], "--models sindy9"),
        (["--gpus", "-1"], "--gpus -1.0"),
        (["--gpus", "1"], "--gpus 1.0 is for --executor ray"),
        (["--sweep", "lambda_l1=1e-7,1.0000001e-7"], "name the same run twice"),
    ],
)
def test_reproduce_rejects_bad_seeds_sweeps_and_models(tmp_path, capsys, args, needle):
    out = tmp_path / "study"
    assert needle in main_error(capsys, "reproduce", "--scale", "tiny", "--out", str(out), *args)
    assert not out.exists()  # refused before anything was written


def test_ray_executor_without_ray_names_the_extra(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # as if Ray were not installed
    line = main_error(capsys, "reproduce", "--scale", "tiny", "--out", str(tmp_path / "s"),
                      "--executor", "ray")
    assert "--executor ray needs Ray" in line and "pip install 'latent-sindy[ray]'" in line


def test_collect_from_another_world_through_its_hook(tmp_path, capsys) -> None:
    from latent_sindy.data import read_sequences

    out = tmp_path / "pendulum.h5"
    assert main(["collect", "--world", "pendulum", "--trajectories", "4", "--steps", "3",
                 "--seed", "1", "--out", str(out)]) == 0
    data = read_sequences(out)
    assert (data.world, data.n, data.steps, data.seed) == ("pendulum", 4, 3, 1)
    assert main(["collect", "--world", "pendulum", "--out", str(out)]) == 2  # no overwrite
    assert "exists" in capsys.readouterr().err


@pytest.mark.parametrize("args, says", [
    (["--world", "pendulum", "--image-size", "64"], "push world's: drop them"),
    (["--world", "pendulum-video"], "does not collect data"),
    (["--world", "nope"], "is not installed"),
])
def test_collect_refuses_what_a_world_cannot_take(tmp_path, capsys, args, says) -> None:
    out = tmp_path / "x.h5"
    assert main(["collect", *args, "--out", str(out)]) == 2
    assert says in capsys.readouterr().err and not out.exists()


def test_control_runs_another_worlds_closed_loop(tmp_path, capsys) -> None:
    import json

    from latent_sindy import LatentSINDy
    from latent_sindy.data import read_sequences

    data_file, run = tmp_path / "p.h5", tmp_path / "run"
    assert main(["collect", "--world", "pendulum", "--trajectories", "8", "--steps", "4",
                 "--out", str(data_file)]) == 0
    LatentSINDy(3, seed=0, encoder="mlp", decoder="mlp", order=1, include_sine=False).fit(
        read_sequences(data_file), epochs=1, starts=1, out=run)
    assert main(["control", str(run), "--episodes", "2", "--max-steps", "3", "--samples",
                 "10", "--horizon", "2"]) == 0
    record = json.loads((run / "control-latent" / "results.json").read_text())
    assert record["world"] == "pendulum" and len(record["results"]) == 2
    assert all(len(r["actions"]) == 3 for r in record["results"])  # no criterion met early
    assert "upright" in record["success"]
    assert main(["control", str(run), "--task", "random"]) == 2
    assert "the push world's" in capsys.readouterr().err


def test_control_refuses_a_world_without_a_closed_loop(tmp_path, capsys) -> None:
    from latent_sindy import LatentSINDy
    from latent_sindy.worlds.pendulum import pendulum_video

    data = pendulum_video(n_train=4, n_val=1, n_test=1, steps=6, size=16)
    run = tmp_path / "run"
    LatentSINDy(1, seed=0, encoder="mlp", decoder="mlp", order=1, include_sine=False).fit(
        data, epochs=1, starts=1, out=run)
    assert main(["control", str(run)]) == 2
    assert "has no closed loop" in capsys.readouterr().err
