"""A world's settings from the command line: `collect --world W --world-config KEY=VALUE ...`
builds the world's class on its config dataclass with those fields, checked like a file."""

from __future__ import annotations

import pytest

from latent_sindy.cli import main
from latent_sindy.configs import from_pairs
from latent_sindy.data import read_sequences
from latent_sindy.errors import UserError
from latent_sindy.worlds.pendulum.config import PendulumConfig


def test_pairs_are_read_as_json_or_else_as_strings():
    cfg = from_pairs(PendulumConfig, ["image_size=32", "start=random", "perturbation=0.2"],
                     "--world-config")
    assert cfg == PendulumConfig(image_size=32, start="random", perturbation=0.2)
    assert from_pairs(PendulumConfig, [], "x") == PendulumConfig()
    with pytest.raises(UserError, match=r"--world-config: unknown settings \['size'\]"):
        from_pairs(PendulumConfig, ["size=32"], "--world-config")
    with pytest.raises(UserError, match="not KEY=VALUE"):
        from_pairs(PendulumConfig, ["image_size"], "--world-config")
    with pytest.raises(UserError, match=r"image_size.*expected an integer"):
        from_pairs(PendulumConfig, ["image_size=big"], "--world-config")


def test_collect_builds_the_world_on_the_settings_given(tmp_path, capsys):
    out = tmp_path / "p.h5"
    assert main(["collect", "--world", "pendulum", "--world-config", "image_size=16",
                 "start=random", "--trajectories", "3", "--steps", "2", "--out",
                 str(out)]) == 0
    data = read_sequences(out)
    assert data.frame_shape == (2, 16, 16)
    assert data.world_config == PendulumConfig(image_size=16, start="random")
    assert main(["collect", "--world-config", "image_size=16", "--out",
                 str(tmp_path / "push.h5")]) == 2
    assert "another world's settings" in capsys.readouterr().err
