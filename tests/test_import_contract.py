"""The core knows no world: its bottom layers load neither the simulator nor gymnasium, and the
package's face loads nothing heavy (the layers themselves are checked by lint-imports)."""

from __future__ import annotations

import subprocess
import sys

import pytest


@pytest.mark.parametrize("modules", [
    "latent_sindy.sindy, latent_sindy.models",
    "latent_sindy.data, latent_sindy.training, latent_sindy.api",
    "latent_sindy",
])
def test_the_core_imports_no_simulator(modules):
    code = (f"import sys, {modules}; "
            "bad = [m for m in ('pybullet', 'gymnasium') if m in sys.modules]; "
            "assert not bad, bad")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr


def test_a_world_is_listed_by_name_without_importing_it():
    code = ("import sys; from latent_sindy.plugins import get_world, world_names; "
            "assert 'push' in world_names(); "
            "from latent_sindy.data import read_sequences; "
            "assert 'latent_sindy.worlds.push' not in sys.modules")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
