"""The house as the README draws it: the layout section names what the tree holds, the README
stays a front door. (Modules are split by meaning, with no line cap.)"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "latent_sindy"


def test_the_readme_is_a_front_door():
    assert len((ROOT / "README.md").read_text().splitlines()) <= 200


def test_the_readme_layout_matches_the_tree():
    text = (ROOT / "README.md").read_text()
    block = text.split("## Layout", 1)[1].split("```")[1]
    named = set(re.findall(r"^  (\S+)", block, re.M))
    for name in named:
        assert (PACKAGE / name.rstrip("/")).exists(), f"README names {name}, not in the tree"
    shown = {n.split("/")[0] for n in named}
    actual = {p.name for p in PACKAGE.iterdir() if p.is_dir() and p.name != "__pycache__"}
    assert actual <= shown, f"packages the README's layout leaves out: {actual - shown}"
    for link in re.findall(r"\]\((docs/[^)#]+)", text):
        assert (ROOT / link).exists(), link


def test_the_core_names_no_world():
    """Outside its own package no module (docstrings included) names the pushing world's
    modules or asks for it by name: the core reaches worlds through the plug-ins only."""
    pattern = re.compile(r'worlds\.push|get_world\("push"\)')
    push = PACKAGE / "worlds" / "push"
    found = [f"{p.relative_to(ROOT)}:{i}" for p in PACKAGE.rglob("*.py")
             if push not in p.parents
             for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert not found, found


def test_the_no_world_contract_lists_every_core_module():
    """The import contract that keeps worlds out of the core covers the whole core."""
    import tomllib

    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    forbidden = next(c for c in contracts["contracts"] if c["type"] == "forbidden"
                     and c["forbidden_modules"] == ["latent_sindy.worlds"])
    core = {f"latent_sindy.{p.stem if p.is_file() else p.name}" for p in PACKAGE.iterdir()
            if (p.suffix == ".py" and p.stem != "__init__")
            or (p.is_dir() and (p / "__init__.py").exists() and p.name != "worlds")}
    assert core == set(forbidden["source_modules"])
