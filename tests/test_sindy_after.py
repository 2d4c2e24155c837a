"""SINDy fitted after the autoencoder (``TrainConfig.sindy_fit = "after"``) and a learned
moments encoder whose order the data chooses (``moment_order = 0``): the order chosen is the
drawn object's symmetry, the record states it, and the coefficients are exactly the sparse
regression of the trained encoder's transitions."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from latent_sindy import LatentSINDy
from latent_sindy.data import SequenceData, write_sequences
from latent_sindy.errors import UserError
from latent_sindy.models import AutoencoderConfig, ModelConfig, SindyConfig
from latent_sindy.models.latent_model import LossWeights
from latent_sindy.sindy import STLSQ
from latent_sindy.training import TrainConfig
from test_mask_moments import TABLE, draw


def moving(half: tuple[float, float], n: int = 10, steps: int = 5, seed: int = 0
           ) -> SequenceData:
    """A block of half sides ``half`` (pixels) pushed about: each action moves it by (u0, u1)
    pixels and turns it by u2 radians."""
    rng = np.random.default_rng(seed)
    pose = np.c_[rng.uniform(11, 21, (n, 2)), rng.uniform(-math.pi, math.pi, n)]
    u = rng.uniform(-1.2, 1.2, (n, steps, 3)) * [1, 1, 0.3]
    frames = []
    for t in range(steps + 1):
        frames.append([draw(*p, half=half) for p in pose])
        if t < steps:
            pose = pose + u[:, t]
    images = np.stack(frames, 1)[:, :, None] / 255.0
    split = np.r_[np.zeros(n - 2, int), np.ones(2, int)]
    return SequenceData(images=images.astype(np.float32), actions=u.astype(np.float32),
                        action_low=[-1.2, -1.2, -0.36], action_high=[1.2, 1.2, 0.36],
                        split=split)


def estimator(min_share: float = 0.05, order: int = 0) -> LatentSINDy:
    obs = AutoencoderConfig(encoder_kind="mask_moments", decoder_kind="sprite", latent_dim=4,
                            moment_order=order, mask_channels=4, mask_layers=1)
    return LatentSINDy(model=ModelConfig(observation=obs, dynamics=SindyConfig(order=1)),
                       settings=TrainConfig(sindy_fit="after", sindy_init_share=min_share,
                                            order_epochs=2, batch_size=20, prune_every=0),
                       loss=LossWeights(lambda_pred_x=0.0, lambda_pred_z=0.0, lambda_l1=0.0),
                       seed=0)


@pytest.mark.parametrize(("half", "order"), [((2.5, 2.5), 4), ((3.5, 1.2), 2)])
def test_the_data_chooses_the_order_and_the_record_states_it(half, order) -> None:
    """A square looks alike every quarter turn (4), a bar every half turn (2); the settings
    keep the 0 asked for, the model the order chosen."""
    est = estimator().fit(moving(half), epochs=2)
    assert est.record_["model"]["observation"]["encoder"]["order"] == order
    assert est.record_["train"]["model"]["observation"]["encoder"]["order"] == 0
    assert est.model_.autoencoder.encoder.order == order


def test_after_the_autoencoder_the_coefficients_are_the_regression_of_its_latents() -> None:
    """The coefficients equal STLSQ of the trained encoder's training transitions, at the
    given share (some terms dropped); the joint fit's do not."""
    data = moving((2.5, 2.5))
    est = estimator(min_share=0.1, order=4).fit(data, epochs=2)
    model, norm = est.model_, est.normalizer_
    train = data.split("train")
    with torch.no_grad():
        z = model.encode(norm.normalize(train.images))
    u = torch.as_tensor(train.actions)
    again = SindyConfig(order=1).build(4, 3)
    again.fit_state_data(z[:, :-1].reshape(-1, 4), u.reshape(-1, 3), z[:, 1:].reshape(-1, 4),
                         optimizer=STLSQ(min_share=0.1))
    got, want = est.coefficients(), again.coefficients().detach().numpy().T
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-6)
    assert 0 < (got != 0).sum() < got.size  # the share dropped some terms, not all
    joint = LatentSINDy(model=est.model_config, settings=TrainConfig(batch_size=20),
                        seed=0).fit(data, epochs=2)
    assert not np.allclose(joint.coefficients(), want, atol=1e-3)


def test_a_run_folder_keeps_the_choice_and_is_reused(tmp_path) -> None:
    """Trained into a folder, the run loads at the order chosen; the study's check of a
    finished run against the same settings finds no difference."""
    from latent_sindy.training.runs import load_run
    from latent_sindy.worlds.push.study.jobs import ensure_trained

    path = tmp_path / "d.h5"
    write_sequences(path, moving((3.5, 1.2)))
    est = estimator()
    cfg = est.train_config(data=path, out=tmp_path / "run", epochs=2)
    assert ensure_trained(cfg) == "trained"
    assert load_run(tmp_path / "run").model.autoencoder.encoder.order == 2
    assert ensure_trained(cfg) == "reused"


def test_settings_the_fit_refuses_are_refused_before_the_order_is_chosen(monkeypatch) -> None:
    """--sindy-fit after with dynamics it cannot fit: the error comes before any training."""
    from latent_sindy.models.dynamics import LinearConfig
    from latent_sindy.training import fit_loop

    def no_training(*args, **kwargs):
        raise AssertionError("trained before the settings were checked")

    monkeypatch.setattr(fit_loop, "fit", no_training)
    est = estimator()
    est.model = ModelConfig(observation=est.model_config.observation, dynamics=LinearConfig())
    with pytest.raises(UserError, match="--sindy-fit after"):
        est.fit(moving((2.5, 2.5), n=4, steps=2), epochs=1)


@pytest.mark.parametrize(("settings", "match"), [
    ({"sindy_fit": "later"}, "--sindy-fit"), ({"order_epochs": 0}, "--order-epochs")])
def test_bad_settings_name_the_value(settings, match) -> None:
    with pytest.raises(UserError, match=match):
        TrainConfig(**settings)


def test_the_angle_frequency_follows_the_encoders_order() -> None:
    """A pose library's angle frequency 0 takes the moments encoder's order once it is known,
    and is refused with an encoder that has none."""
    from latent_sindy.models.state import StateConfig

    obs = AutoencoderConfig(encoder_kind="moments", decoder_kind="sprite", latent_dim=4,
                            moment_order=3)
    pytest.importorskip("latent_sindy.worlds.push")  # (registers the face library)
    dyn = SindyConfig(order=1, library="face", library_options=("frequency=0",))
    cfg = ModelConfig(observation=obs, dynamics=dyn).resolve(1, 32, 3)
    assert cfg.dynamics.options.frequency == 3.0 and cfg.resolved
    with pytest.raises(UserError, match="frequency=0 takes the moments encoder"):
        ModelConfig(observation=StateConfig(), dynamics=dyn)
    _ = TABLE
