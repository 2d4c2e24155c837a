"""The continuous-time model and its samples: ``LatentModel(config)`` of continuous-time
dynamics is a ContinuousLatentModel whose loss is the SINDy autoencoder's on a frame and its
time derivatives (the same bits as the terms computed from its parts), the trainer carries
its samples as DerivativeSamples, and what belongs to sequences (a window, poses, rewards) is
refused."""

from __future__ import annotations

import copy
import pickle
from dataclasses import replace

import numpy as np
import pytest
import torch

from latent_sindy.data import SequenceData
from latent_sindy.data.windows import Normalizer
from latent_sindy.models import (
    AutoencoderConfig,
    ContinuousLatentModel,
    LatentModel,
    LossWeights,
    ModelConfig,
    SindyConfig,
)
from latent_sindy.models.derivatives import along
from latent_sindy.models.dynamics import ContinuousSindyConfig
from latent_sindy.models.loss import latent_error
from latent_sindy.models.reward_head import Targets
from latent_sindy.training import DerivativeSamples, Sequences, TrainConfig, evaluate
from latent_sindy.training.fit_loop import Gradients
from latent_sindy.training.prepare import derivative_samples, training_tensors

pytestmark = pytest.mark.usefixtures("one_torch_thread")

AE = AutoencoderConfig(latent_dim=2, encoder_kind="mlp", decoder_kind="mlp", mlp_widths=(16, 8))
WEIGHTS = (LossWeights(),
           LossWeights(lambda_pred_x=0.3, lambda_pred_z=2.0, lambda_l1=1e-3),
           LossWeights(lambda_pred_z=5.0, relative_pred_z=True))


def continuous(order: int, time_unit: float = 1.0, nu: int = 2) -> ModelConfig:
    dyn = ContinuousSindyConfig(derivative_order=order, init="normal", init_scale=0.3,
                                time_unit=time_unit)
    return ModelConfig(dynamics=dyn, observation=AE).resolve(1, 6, nu)


def samples(order: int, nu: int = 2, n: int = 8) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(order)
    return torch.randn(n, 1 + order, 1, 6, 6, generator=g), torch.randn(n, nu, generator=g)


def terms_from_parts(model: LatentModel, x: torch.Tensor, u: torch.Tensor,
                     w: LossWeights) -> dict[str, torch.Tensor]:
    """The SINDy autoencoder's terms, computed here from the model's encoder, decoder and
    dynamics, operation for operation as the continuous-time loss always has."""
    k = model.dynamics.derivative_order
    frames = x.unbind(1)
    z = along(model.autoencoder.encoder, *frames)
    top = model.dynamics.derivative(torch.cat(z[:k], -1), u)
    x_hat = along(model.autoencoder.decoder, *z[:k], top)
    recon = (x_hat[0] - frames[0]).square().mean()
    pred_x = (x_hat[k] - frames[k]).square().mean()
    pred_z = latent_error(top, z[k], w.relative_pred_z)
    unit = model.dynamics.time_unit ** (2 * k)
    if unit != 1.0:
        pred_x = pred_x * unit
        pred_z = pred_z if w.relative_pred_z else pred_z * unit
    l1 = model.dynamics.l1_penalty()
    objective = recon + w.lambda_pred_x * pred_x + w.lambda_pred_z * pred_z
    zero = recon.new_zeros(())
    return {"total": objective + w.lambda_l1 * l1, "recon": recon, "pred_x": pred_x,
            "pred_z": pred_z, "l1": l1, "pose": zero, "objective": objective, "reward": zero}


def test_a_continuous_config_builds_the_continuous_model_and_a_discrete_one_the_plain() -> None:
    torch.manual_seed(0)
    model = LatentModel(continuous(2))
    assert type(model) is ContinuousLatentModel and isinstance(model, LatentModel)
    discrete = ModelConfig(dynamics=SindyConfig(order=2), observation=AE).resolve(1, 6, 2)
    assert type(LatentModel(discrete)) is LatentModel
    with pytest.raises(ValueError, match="takes continuous-time dynamics"):
        ContinuousLatentModel(discrete)
    # copies and pickles keep the type; the subclass built directly is the same model
    assert type(copy.deepcopy(model)) is ContinuousLatentModel
    assert type(pickle.loads(pickle.dumps(model))) is ContinuousLatentModel
    torch.manual_seed(0)
    direct = ContinuousLatentModel(continuous(2))
    for (k, a), (j, b) in zip(model.state_dict().items(), direct.state_dict().items(),
                              strict=True):
        assert k == j and torch.equal(a, b), k


#: The state dict of this test's continuous-time model as saved before it had a type of its
#: own (the same for both orders).
SAVED_KEYS = [f"autoencoder.{part}.net.{i}.{w}" for part in ("encoder", "decoder")
              for i in (0, 2, 4) for w in ("weight", "bias")] + ["dynamics.psi", "dynamics.mask"]


@pytest.mark.parametrize("order", [1, 2])
def test_its_state_dict_has_the_keys_it_had_and_loads_into_either_type(order: int) -> None:
    """The subclass adds no module: saved continuous-time models load as they are."""
    torch.manual_seed(0)
    model = LatentModel(continuous(order))
    assert list(model.state_dict()) == SAVED_KEYS
    other = LatentModel(continuous(order))
    other.load_state_dict(model.state_dict())  # strict
    for key, value in model.state_dict().items():
        assert torch.equal(other.state_dict()[key], value), key


@pytest.mark.parametrize(("order", "time_unit"), [(1, 1.0), (2, 1.0), (1, 2.0),
                                                  (2, 2 ** (-1 / 4))])
def test_the_loss_is_bit_for_bit_the_terms_computed_from_the_parts(order, time_unit) -> None:
    """Every term and every parameter's gradient of the total, exactly (torch.equal)."""
    torch.manual_seed(3)
    model = LatentModel(continuous(order, time_unit))
    x, u = samples(order)
    for w in WEIGHTS:
        got = model.loss(x, u, w)
        want = terms_from_parts(model, x, u, w)
        assert sorted(got) == sorted(want)
        for key in want:
            assert torch.equal(got[key], want[key]), (key, w)
        grads = []
        for total in (got["total"], want["total"]):
            model.zero_grad()
            total.backward()
            grads.append([p.grad.clone() for p in model.parameters() if p.grad is not None])
        assert len(grads[0]) == len(grads[1]) > 0
        for a, b in zip(*grads, strict=True):
            assert torch.equal(a, b)
    assert model.loss(x, u).keys() == terms_from_parts(model, x, u, LossWeights()).keys()


def test_the_trainer_gives_derivative_samples_to_the_loss_without_a_window() -> None:
    """One gradient step's terms and the evaluation are the loss on the samples, whatever
    window the settings hold (it is a sequence's)."""
    torch.manual_seed(1)
    model = LatentModel(continuous(2))
    x, u = samples(2)
    batch = DerivativeSamples(x, u)
    w = WEIGHTS[1]
    grads = Gradients(model, 1)
    try:
        terms = grads(batch, w, 3)
    finally:
        grads.close()
    want = model.loss(x, u, w)
    for key, value in want.items():
        assert torch.equal(terms[key], value.detach()), key
    assert batch.pick(torch.tensor([3, 1])).frames.shape == (2, 3, 1, 6, 6)
    assert batch.n == 8 and batch.pick(slice(2, 5)).actions.shape == (3, 2)
    ev = evaluate(model, batch, w, batch_size=3)  # batches of 3, 3, 2: their weighted mean
    with torch.no_grad():
        parts = [model.loss(x[a:b], u[a:b], w) for a, b in ((0, 3), (3, 6), (6, 8))]
    recon = sum(float(p["recon"].double()) * (b - a)
                for p, (a, b) in zip(parts, ((0, 3), (3, 6), (6, 8)), strict=True)) / 8
    assert ev["recon"] == pytest.approx(recon, rel=1e-12)


def test_poses_rewards_and_windows_are_refused() -> None:
    model = LatentModel(continuous(1))
    x, u = samples(1)
    with pytest.raises(ValueError, match="no pose or reward term"):
        model.loss(x, u, None, torch.zeros(8, 4))
    with pytest.raises(ValueError, match="no pose or reward term"):
        model.loss(x, u, None, Targets(None, torch.zeros(8, 1)))
    with pytest.raises(ValueError, match="without window"):
        model.loss(x, u, window=1)
    with pytest.raises(ValueError, match=r"expects x \(B, 2, C, h, w\) and u \(B, nu\)"):
        model.loss(x[:, :1], u)  # sequences' shapes are not samples'
    with pytest.raises(ValueError, match=r"expects x \(B, 2, C, h, w\) and u \(B, nu\)"):
        model.loss(x, u[:, None])


def test_derivative_samples_are_their_own_type_and_the_trainer_carries_them() -> None:
    rng = np.random.default_rng(0)
    frames = rng.uniform(0, 1, (6, 5, 1, 6, 6)).astype(np.float32)
    actions = rng.uniform(-1, 1, (6, 4, 2)).astype(np.float32)
    data = SequenceData(frames, actions, action_low=[-1, -1], action_high=[1, 1], dt=0.1,
                        seed=0)
    norm = Normalizer.from_trajectories(data)
    cfg = TrainConfig(model=continuous(2), batch_size=4)
    out = derivative_samples(data, norm, 2, cfg)
    assert type(out) is DerivativeSamples
    assert out.frames.shape == (30, 3, 1, 6, 6) and out.actions.shape == (30, 2)
    # the action at each frame: the last frame keeps its sequence's last action
    assert torch.equal(out.actions[:5], torch.as_tensor(actions[0, [0, 1, 2, 3, 3]]))
    torch.manual_seed(0)
    model = LatentModel(cfg.model)
    tensors = training_tensors(model, data, norm, cfg, torch.device("cpu"))
    assert type(tensors.train) is DerivativeSamples
    assert tensors.val is None or type(tensors.val) is DerivativeSamples
    assert not isinstance(tensors.train, Sequences)
    discrete = replace(cfg, model=ModelConfig(dynamics=SindyConfig(order=2),
                                              observation=AE).resolve(1, 6, 2))
    seqs = training_tensors(LatentModel(discrete.model), data, norm, discrete,
                            torch.device("cpu"))
    assert type(seqs.train) is Sequences
