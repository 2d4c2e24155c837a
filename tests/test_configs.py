"""One serializer for every config: round trips, one-line errors, tagged unions."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from latent_sindy.configs import from_json, to_json
from latent_sindy.control.mppi import MPPIConfig
from latent_sindy.errors import UserError
from latent_sindy.models import LinearConfig, MlpConfig, ModelConfig, SindyConfig
from latent_sindy.study.settings import StudySettings
from latent_sindy.training import TrainConfig
from latent_sindy.worlds.push.collect import CollectionPlan
from latent_sindy.worlds.push.config import PushEnvConfig
from latent_sindy.worlds.push.episodes import ControlConfig
from latent_sindy.worlds.push.study.config import PushStudyConfig
from latent_sindy.worlds.push.study.scales import DEMO_LONG, SCALES, Scale

CONFIGS = [
    PushEnvConfig(channels=3, image_size=48),
    CollectionPlan(trajectories=7, steps=2, seed=3),
    ModelConfig(dynamics=SindyConfig(order=3, include_cosine=True)),
    ModelConfig(dynamics=LinearConfig(init_scale=0.01), action_dim=3),
    ModelConfig(dynamics=MlpConfig(hidden=8, layers=3)),
    TrainConfig(out=Path("runs/x"), model=ModelConfig(dynamics=MlpConfig()), window=3),
    ControlConfig(task="random", space="image", mppi=MPPIConfig(samples=7, sigma=(0.1, 0.2, 0.3))),
    SCALES["tiny"],
    PushStudyConfig(scale="tiny", seeds=(0, 2), data=Path("d.h5")),
    StudySettings(scale="tiny", seeds=(0, 2), world="pendulum", record=Path("results")),
]


@pytest.mark.parametrize("cfg", CONFIGS, ids=lambda c: type(c).__name__)
def test_every_config_round_trips_through_json(cfg) -> None:
    text = json.dumps(to_json(cfg))
    back = from_json(type(cfg), json.loads(text), "test")
    assert back == cfg
    assert json.dumps(to_json(back)) == text


def test_tagged_union_is_read_back_as_its_kind() -> None:
    d = to_json(ModelConfig(dynamics=LinearConfig()))
    assert d["dynamics"] == {"kind": "linear", "init_scale": 1e-3}
    assert isinstance(from_json(ModelConfig, d, "m").dynamics, LinearConfig)


@pytest.mark.parametrize(("edit", "message"), [
    (lambda d: d.update(warp_drive=1), r"f\.json: unknown settings \['warp_drive'\]"),
    (lambda d: d["model"]["dynamics"].update(kind="transformer"),
     r"f\.json\.model\.dynamics: kind 'transformer' is unknown"),
    (lambda d: d.update(epochs="ten"), r"f\.json\.epochs: expected an integer"),
    (lambda d: d.update(epochs=True), r"f\.json\.epochs: expected an integer"),
    (lambda d: d.update(betas=[0.9]), r"f\.json\.betas: expected 2 values"),
    (lambda d: d.update(epochs=0), r"f\.json: --epochs 0"),
    (lambda d: d["model"]["dynamics"].update(order=9), r"f\.json\.model\.dynamics: SINDy order 9"),
    (lambda d: d.update(model=[]), r"f\.json\.model: expected a mapping"),
])
def test_bad_values_are_one_line_errors_naming_the_key(edit, message: str) -> None:
    d = to_json(TrainConfig())
    edit(d)
    with pytest.raises(UserError, match=message) as e:
        from_json(TrainConfig, d, "f.json")
    assert "\n" not in str(e.value)


def test_scales_are_named_overrides_of_the_demo() -> None:
    base = Scale()
    assert SCALES["demo"] == base
    paper = {f.name for f in dataclasses.fields(Scale)
             if getattr(SCALES["paper"], f.name) != getattr(base, f.name)}
    assert paper == {"epochs", "lr", "batch_size", "prune_every", "eval_every",
                     "paper_episodes", "random_episodes", "other_random_episodes",
                     "image_paper_episodes", "image_random_episodes", "batching"}
    assert SCALES["tiny"].mppi == MPPIConfig(samples=8, horizon=2)
    # the large scale: ten times the paper's trajectories on the demo-long schedule
    assert dataclasses.replace(SCALES["large"], trajectories=base.trajectories) == DEMO_LONG
    assert (DEMO_LONG.epochs, DEMO_LONG.lr) == (2 * base.epochs, base.lr / 2)
    assert SCALES["large"].trajectories == 10 * SCALES["paper"].trajectories
