"""Every script in examples/ runs top to bottom (a smoke run with tiny settings) and prints
what it promises."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def run(script: str, *args: str) -> str:
    out = subprocess.run([sys.executable, str(EXAMPLES / script), *args], capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout


def test_own_data_example(tmp_path):
    text = run("own_data.py", "--epochs", "2", "--out", str(tmp_path / "run"))
    assert "vx" in text and "planning from" in text and (tmp_path / "run" / "model.pt").exists()


def test_pushing_example():
    text = run("pushing.py", "--trajectories", "6", "--steps", "2", "--epochs", "1",
               "--episodes", "1", "--max-steps", "1", "--workers", "1")
    assert "psi" in text and "course criterion met" in text


def test_examples_are_single_readable_files():
    for script in EXAMPLES.glob("*.py"):
        assert len(script.read_text().splitlines()) <= 250, script
