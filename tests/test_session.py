"""One set-up for every training (prepare -> Session) and training by phases: a phase counts
its epochs on from the session's, chooses its kept weights among its own epochs, and changes
only the settings it names."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from latent_sindy import LatentSINDy
from latent_sindy.data import SequenceData
from latent_sindy.errors import UserError
from latent_sindy.models import AutoencoderConfig, ModelConfig
from latent_sindy.models.dynamics.sindy import SindyConfig
from latent_sindy.training.config import TrainConfig
from latent_sindy.training.session import Phase, prepare


def _data(seed: int = 0) -> SequenceData:
    rng = np.random.default_rng(seed)
    images = rng.integers(0, 255, (9, 5, 1, 8, 8), dtype=np.uint8)
    actions = rng.uniform(-1, 1, (9, 4, 1)).astype(np.float32)
    return SequenceData(images, actions, [-1], [1])


def _cfg(**changes) -> TrainConfig:
    model = ModelConfig(dynamics=SindyConfig(order=1, include_sine=False),
                        observation=AutoencoderConfig(latent_dim=2, encoder_kind="mlp",
                                                      decoder_kind="mlp"))
    return replace(TrainConfig(model=model, epochs=6, starts=1, prune_below=1e-3,
                               prune_every=2, refine_epochs=1, lr=1e-3), **changes)


def _state(session) -> dict[str, torch.Tensor]:
    return {k: v.clone() for k, v in session.model.state_dict().items()}


def test_one_phase_of_every_epoch_is_the_whole_fit() -> None:
    whole, phased = prepare(_cfg(), _data()), prepare(_cfg(), _data())
    a = whole.fit()
    b = phased.fit(Phase(6, "main"))
    assert [r["epoch"] for r in b.metrics] == list(range(1, 7)) and phased.done == 6
    assert a.kept["epoch"] == b.kept["epoch"]
    for k, v in a.state.items():
        assert torch.equal(v, b.state[k]), k


def test_a_phase_counts_its_epochs_on_and_selects_among_its_own() -> None:
    session = prepare(_cfg(), _data())
    first = session.fit(Phase(3, "warm-up", {"prune_every": 0}, adopt=False))
    last_of_first = _state(session)  # adopt=False: the session goes on from epoch 3's weights
    second = session.fit(Phase(3, "main"))
    assert [r["epoch"] for r in first.metrics] == [1, 2, 3]
    assert all(r["sindy/pruned"] is None for r in first.metrics)  # no pruning asked
    assert [r["epoch"] for r in second.metrics] == [4, 5, 6]
    # pruning every 2 epochs falls on epoch 4 (as in one run); the last (6) refines
    assert [r["sindy/pruned"] is not None for r in second.metrics] == [True, False, False]
    assert second.kept["epoch"] in (4, 5, 6) and session.done == 6
    # adopt: the session holds the phase's kept weights
    for k, v in second.state.items():
        assert torch.equal(session.model.state_dict()[k].cpu(), v), k
    assert any(not torch.equal(last_of_first[k], v) for k, v in second.state.items())


def test_a_phase_changes_the_learning_rate_it_names() -> None:
    session = prepare(_cfg(), _data())
    session.fit(Phase(1, "slow", {"lr": 1e-5}))
    assert [g["lr"] for g in session.opt.param_groups] == [1e-5] * len(session.opt.param_groups)
    session.fit(Phase(1, "back"))
    assert {g["lr"] for g in session.opt.param_groups} == {1e-3}


@pytest.mark.parametrize("phase, message", [
    (lambda: Phase(-1), "epochs -1"),
    (lambda: Phase(2, "x", {"bogus": 1}), "bogus"),
    (lambda: Phase(2, "x", {"epochs": 4}), "epochs"),
])
def test_a_phase_refuses_what_it_cannot_do(phase, message) -> None:
    with pytest.raises(UserError, match=message):
        phase()


def test_prepare_refuses_before_any_training() -> None:
    with pytest.raises(UserError, match="window"):
        prepare(_cfg(window=9), _data())


def test_the_estimator_in_memory_and_into_a_run_folder_train_the_same_model(tmp_path) -> None:
    kwargs = {"encoder": "mlp", "decoder": "mlp", "order": 1, "include_sine": False}
    a = LatentSINDy(2, seed=0, **kwargs).fit(_data(), epochs=3, starts=2, start_epochs=1)
    b = LatentSINDy(2, seed=0, **kwargs).fit(_data(), epochs=3, starts=2, start_epochs=1,
                                             out=tmp_path / "run")
    assert a.kept_ == b.kept_ and a.kept_["start"]["starts"] == 2
    assert np.array_equal(a.coefficients(), b.coefficients())


def test_the_estimator_trains_phases_after_its_fit() -> None:
    kwargs = {"encoder": "mlp", "decoder": "mlp", "order": 1, "include_sine": False}
    model = LatentSINDy(2, seed=0, **kwargs).fit(
        _data(), epochs=3, starts=1, phases=[Phase(2, "calibration", {"lr": 1e-4})])
    assert [r["epoch"] for r in model.metrics_] == [1, 2, 3, 4, 5]
    assert model.kept_["phase"] == "calibration" and model.kept_["epoch"] in (4, 5)
    plain = LatentSINDy(2, seed=0, **kwargs).fit(_data(), epochs=3, starts=1)
    assert not np.array_equal(plain.coefficients(), model.coefficients())


def test_phases_are_refused_into_a_run_folder_and_when_not_phases(tmp_path) -> None:
    est = LatentSINDy(2, seed=0, encoder="mlp", decoder="mlp", order=1, include_sine=False)
    with pytest.raises(UserError, match="in memory"):
        est.fit(_data(), epochs=1, phases=[Phase(1)], out=tmp_path / "run")
    with pytest.raises(UserError, match="Phase"):
        est.fit(_data(), epochs=1, phases=[{"epochs": 1}])
