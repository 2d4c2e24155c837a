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


#: Runs ``argv`` through the CLI as if PyBullet (the push extra) were not installed.
WITHOUT_PYBULLET = r"""
import sys


class NoPyBullet:
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in ("pybullet", "pybullet_data", "pybullet_utils"):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)


sys.meta_path.insert(0, NoPyBullet())
from latent_sindy.cli import main  # noqa: E402

sys.exit(main(sys.argv[1:]))
"""


def test_without_pybullet_the_push_world_says_which_extra_to_install(tmp_path):
    """PyBullet is the push extra: without it, collecting in the push world ends with one
    line naming the extra, and what needs no simulator (the CLI, the world's plug-in and its
    libraries) still works."""
    out = subprocess.run([sys.executable, "-c", WITHOUT_PYBULLET, "collect", "--out",
                          str(tmp_path / "d.h5"), "--trajectories", "1", "--steps", "1",
                          "--workers", "1", "--no-progress"], capture_output=True, text=True)
    assert out.returncode == 2, out.stderr
    assert out.stderr.count("\n") == 1 and "latent-sindy[push]" in out.stderr, out.stderr
    library = WITHOUT_PYBULLET.replace(
        "sys.exit(main(sys.argv[1:]))",
        "from latent_sindy.models import SindyConfig\n"
        "print(SindyConfig(order=1, library='face').build(4, 3).n_candidates())\n"
        "assert 'pybullet' not in sys.modules")
    out = subprocess.run([sys.executable, "-c", library], capture_output=True, text=True)
    assert out.returncode == 0 and int(out.stdout) > 0, out.stderr
