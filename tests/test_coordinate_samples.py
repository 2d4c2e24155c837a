"""Behind a principal-component front a continuous-time model trains on its samples'
coordinates: the loss terms and their gradients equal the frames' (up to rounding), the
trainer picks the coordinates by itself, and another start gets the same front."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from latent_sindy.data import SequenceData
from latent_sindy.data.windows import Normalizer
from latent_sindy.models import AutoencoderConfig, LatentModel, LossWeights, ModelConfig
from latent_sindy.models.dynamics import ContinuousSindyConfig
from latent_sindy.training import TrainConfig
from latent_sindy.training.prepare import derivative_samples, training_tensors
from latent_sindy.training.samples import CoordinateSamples, DerivativeSamples

pytestmark = pytest.mark.usefixtures("one_torch_thread")

WEIGHTS = (LossWeights(lambda_pred_x=0.3, lambda_pred_z=2.0, lambda_l1=1e-3),
           LossWeights(lambda_pred_z=5.0, relative_pred_z=True))


def model_with_front(order: int, k: int = 5, time_unit: float = 1.0) -> LatentModel:
    torch.manual_seed(order)
    ae = AutoencoderConfig(latent_dim=2, encoder_kind="mlp", decoder_kind="mlp",
                           mlp_widths=(16, 8), pca_components=k)
    dyn = ContinuousSindyConfig(derivative_order=order, init="normal", init_scale=0.3,
                                time_unit=time_unit)
    return LatentModel(ModelConfig(dynamics=dyn, observation=ae).resolve(1, 6, 2))


def frames(order: int, n: int = 40) -> tuple[torch.Tensor, torch.Tensor]:
    """Samples whose frames mostly lie on a few directions, plus what no front keeps."""
    g = torch.Generator().manual_seed(10 + order)
    base = torch.randn(4, 36, generator=g, dtype=torch.float64)
    x = (torch.randn(n, 1 + order, 4, generator=g, dtype=torch.float64) @ base
         + 0.05 * torch.randn(n, 1 + order, 36, generator=g, dtype=torch.float64))
    return x.float().reshape(n, 1 + order, 1, 6, 6), torch.randn(n, 2, generator=g)


@pytest.mark.parametrize("order,unit", [(1, 1.0), (2, 1.0), (2, 0.7)])
@pytest.mark.parametrize("w", WEIGHTS)
def test_the_coordinates_give_the_frames_loss_and_gradients(order, unit, w):
    model = model_with_front(order, time_unit=unit)
    x, u = frames(order)
    model.fit_statistics(x[:, 0], None)
    on_frames = model.loss(x, u, w)
    grads = torch.autograd.grad(on_frames["total"], list(model.parameters()))
    coords, left = model.coordinates(x)
    assert coords.shape == (40, 1 + order, 5) and left.shape == (40, 1 + order)
    assert (left > 0).all()  # the front leaves part of every frame out
    on_coords = model.coordinate_loss(coords, u, left, w)
    for name, value in on_frames.items():
        torch.testing.assert_close(on_coords[name], value, rtol=2e-5, atol=1e-7)
    for a, b in zip(torch.autograd.grad(on_coords["total"], list(model.parameters())), grads,
                    strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-7)


def test_the_terms_would_differ_without_what_the_front_leaves_out():
    model = model_with_front(2)
    x, u = frames(2)
    model.fit_statistics(x[:, 0], None)
    coords, left = model.coordinates(x)
    with torch.no_grad():
        full = model.coordinate_loss(coords, u, left)
        alone = model.coordinate_loss(coords, u, 0 * left)
        assert float(model.loss(x, u)["recon"]) == pytest.approx(float(full["recon"]), rel=2e-5)
    # what the front leaves out: 0.05 of noise on 32 of the 36 pixel directions, about
    # 0.05² · 32 / 36 a pixel of each frame and derivative
    for key, part in (("recon", 0), ("pred_x", 2)):
        gap = float(full[key] - alone[key])  # (a float32 difference of two losses: its
        # rounding differs between machines by a few parts in 1e4)
        assert gap == pytest.approx(float(left[:, part].mean()) / 36, rel=1e-3)
        assert 0.5 * 0.05**2 < gap < 1.5 * 0.05**2


def test_a_model_without_a_front_refuses_coordinates():
    torch.manual_seed(0)
    ae = AutoencoderConfig(latent_dim=2, encoder_kind="mlp", decoder_kind="mlp",
                           mlp_widths=(16, 8))
    model = LatentModel(ModelConfig(dynamics=ContinuousSindyConfig(derivative_order=2),
                                    observation=ae).resolve(1, 6, 2))
    assert model.front() is None
    with pytest.raises(ValueError, match="no principal-component front"):
        model.coordinates(torch.zeros(3, 3, 1, 6, 6))
    with pytest.raises(ValueError, match="coordinate_loss expects"):
        model.coordinate_loss(torch.zeros(3, 3, 5), torch.zeros(3, 2), torch.zeros(3, 3))


def video(n: int = 6, steps: int = 9) -> SequenceData:
    x, _ = frames(2, n * (steps + 1))
    x = 0.1 * x.reshape(n, steps + 1, 3, 1, 6, 6)
    return SequenceData((0.5 + x[:, :, 0]).clamp(0, 1).numpy(),
                        np.zeros((n, steps, 2), np.float32), [-1, -1], [1, 1],
                        split=np.array([0] * 4 + [1] * 2),
                        images_dot=x[:, :, 1].numpy(), images_ddot=x[:, :, 2].numpy(), dt=0.1)


def test_the_trainer_trains_a_front_on_coordinates_and_gives_another_start_the_same_front():
    data = video()
    norm = Normalizer.from_trajectories(data)
    cfg = TrainConfig(batch_size=8)
    model = model_with_front(2)
    tensors = training_tensors(model, data, norm, cfg, torch.device("cpu"))
    assert isinstance(tensors.train, CoordinateSamples)
    assert isinstance(tensors.val, CoordinateSamples) and tensors.val.n == 20
    raw = derivative_samples(data.split("train"), norm, 2, cfg)
    torch.testing.assert_close(tensors.train.loss(model, cfg.loss, None)["objective"],
                               raw.loss(model, cfg.loss, None)["objective"], rtol=2e-5,
                               atol=1e-7)
    other = model_with_front(2)
    assert not torch.equal(other.front()[0].weight, model.front()[0].weight)
    tensors.prime(other)
    for a, b in zip(other.front(), model.front(), strict=True):
        assert torch.equal(a.weight, b.weight) and torch.equal(a.bias, b.bias)


def test_without_a_front_the_trainer_keeps_the_frames():
    data = video()
    torch.manual_seed(0)
    ae = AutoencoderConfig(latent_dim=2, encoder_kind="mlp", decoder_kind="mlp",
                           mlp_widths=(16, 8))
    model = LatentModel(ModelConfig(dynamics=ContinuousSindyConfig(derivative_order=2),
                                    observation=ae).resolve(1, 6, 2))
    tensors = training_tensors(model, data, Normalizer.from_trajectories(data),
                               TrainConfig(batch_size=8), torch.device("cpu"))
    assert isinstance(tensors.train, DerivativeSamples)
