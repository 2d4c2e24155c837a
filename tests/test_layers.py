"""The package's layering (pyproject's import-linter contracts) holds, and would catch a break:
a lower layer importing a higher one, a world importing another, the core importing a world."""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "latent_sindy"
LINT = Path(sys.executable).with_name("lint-imports")


def _contract_ini() -> str:
    """pyproject's [tool.importlinter] as an .importlinter file."""
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    lines = ["[importlinter]", f"root_package = {cfg['root_package']}"]
    for i, c in enumerate(cfg["contracts"]):
        lines += [f"[importlinter:contract:{i}]", f"name = {c['name']}", f"type = {c['type']}"]
        # a layers, an independence or a forbidden contract
        for key in ("layers", "modules", "source_modules", "forbidden_modules"):
            if key in c:
                lines += [f"{key} ="] + [f"    {m}" for m in c[key]]
        if c.get("ignore_imports"):
            lines += ["ignore_imports ="] + [f"    {i}" for i in c["ignore_imports"]]
    return "\n".join(lines) + "\n"


def _lint(src: Path, tmp: Path) -> subprocess.CompletedProcess:
    ini = tmp / ".importlinter"
    ini.write_text(_contract_ini())
    env = {"PYTHONPATH": str(src.parent), "PATH": "/usr/bin:/bin"}
    return subprocess.run([str(LINT), "--config", str(ini), "--no-cache"], capture_output=True,
                          text=True, env=env, cwd=tmp, timeout=120)


@pytest.mark.skipif(not LINT.exists(), reason="import-linter is not installed")
def test_the_contract_holds_and_fails_on_a_back_import(tmp_path: Path) -> None:
    assert _lint(SRC, tmp_path).returncode == 0
    copy = tmp_path / "src" / "latent_sindy"
    shutil.copytree(SRC, copy, ignore=shutil.ignore_patterns("__pycache__"))
    store = copy / "data" / "store.py"
    store.write_text(store.read_text() + "\nimport latent_sindy.training  # noqa\n")
    broken = _lint(copy, tmp_path)
    assert broken.returncode != 0
    assert "latent_sindy.data is not allowed to import latent_sindy.training" in broken.stdout
    store.write_text(store.read_text().replace("\nimport latent_sindy.training  # noqa\n", ""))
    world = copy / "worlds" / "pendulum" / "physics.py"  # one world importing another
    world.write_text(world.read_text() + "\nimport latent_sindy.worlds.push.criteria  # noqa\n")
    crossed = _lint(copy, tmp_path)
    assert crossed.returncode != 0
    assert "latent_sindy.worlds.pendulum is not allowed to import latent_sindy.worlds.push" \
        in crossed.stdout.replace("\n", " ")
    world.write_text(world.read_text().replace(
        "\nimport latent_sindy.worlds.push.criteria  # noqa\n", ""))
    cli = copy / "cli.py"  # the top layer, which the layers allow to import anything below
    cli.write_text(cli.read_text() + "\nimport latent_sindy.worlds.pendulum.physics  # noqa\n")
    named = _lint(copy, tmp_path)
    assert named.returncode != 0
    assert "latent_sindy.cli is not allowed to import latent_sindy.worlds" in named.stdout


def _imports(path: Path):
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith(
                "latent_sindy"):
            yield node.module, [a.name for a in node.names]
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("latent_sindy"):
                    yield a.name, []


def test_no_module_imports_another_packages_private_names() -> None:
    offences = []
    for path in SRC.rglob("*.py"):
        package = path.relative_to(SRC).parts[0] if len(path.relative_to(SRC).parts) > 1 else ""
        for module, names in _imports(path):
            parts = module.split(".")
            target_package = parts[1] if len(parts) > 1 else ""
            private = [p for p in parts[1:] if p.startswith("_")]
            private += [n for n in names if n.startswith("_") and not n.endswith("__")]
            if private and target_package != package:
                offences.append(f"{path.relative_to(SRC)} imports {module} {names}")
    assert not offences, offences
