"""Frames without derivatives: the encoder's latents of five frames around each sample are
differentiated, never the pixels (``--derivatives latent``, what ``auto`` takes then)."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from latent_sindy import LatentSINDy, Phase, Restarts
from latent_sindy.errors import UserError
from latent_sindy.training.config import TrainConfig
from latent_sindy.training.prepare import (
    derivative_source,
    frame_windows,
    stencil_stride,
    training_tensors,
)
from latent_sindy.training.samples import CoordinateSamples, DerivativeSamples
from latent_sindy.worlds.pendulum.video_draws import VideoDraw

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def video(exact: bool = False, frames: int = 40):
    return VideoDraw(system="pendulum", omega2=(1.3,), damping=(0.1,), size=12, width=0.05,
                     trajectories=8, frames=frames, dt=0.08, exact=exact).video()


def fitted(data, **kw):
    est = LatentSINDy(1, time="continuous", derivative_order=2, seed=0)
    return est.fit(data, epochs=1, phases=[Phase(1, "calibration")],
                   restarts=Restarts(count=0), **kw)


@pytest.fixture(scope="module")
def frames_fit():
    """One fit on frames alone, shared: the stencil is its model's method, whatever its
    weights."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return fitted(video())
    finally:
        torch.set_num_threads(n)


@pytest.mark.parametrize("wh", [0.1, 0.3, 0.8])
def test_the_stencil_differentiates_a_latent_to_fourth_order(frames_fit, wh):
    h, w = 0.05, wh / 0.05
    t = torch.linspace(0, 3, 50, dtype=torch.float64)[:, None] + h * torch.arange(-2, 3)
    z = torch.sin(w * t)[..., None]  # (B, 5, 1)
    _zc, dz, ddz = frames_fit.model_.stencil_latents(z, h)
    centre = t[:, 2:3]
    assert torch.allclose(dz, w * torch.cos(w * centre), atol=w * wh ** 4 / 20)
    assert torch.allclose(ddz, -w * w * torch.sin(w * centre), atol=w * w * wh ** 4 / 60)


def test_frames_without_derivatives_train_on_stencils_and_exact_ones_on_themselves(frames_fit):
    frames_only, exact = video(), video(exact=True)
    cfg = TrainConfig(model=LatentSINDy(1, time="continuous", derivative_order=2).model_config)
    assert derivative_source(cfg, frames_only) == "latent"
    assert derivative_source(cfg, exact) == "given"
    assert derivative_source(dataclasses.replace(cfg, derivatives="central"),
                             frames_only) == "central"
    est = frames_fit  # (fitted on frames_only)
    tensors = training_tensors(est.model_, frames_only, est.normalizer_,
                               dataclasses.replace(cfg, batch_size=10), torch.device("cpu"),
                               fresh=False)
    assert isinstance(tensors.train, CoordinateSamples) and tensors.train.stencil > 0
    assert tensors.train.coords.shape[1] == 5
    # the windows' middle frames are the frames, their neighbours stride frames apart
    stride = round(tensors.train.stencil / 0.08)
    train = frames_only.split("train")
    _f, idx, _ = frame_windows(train, est.normalizer_, stride)
    assert tensors.train.n == len(idx) == train.n * (train.steps + 1 - 4 * stride)
    assert torch.equal(idx[:, 1:] - idx[:, :-1], torch.full((len(idx), 4), stride))


def test_the_stride_follows_the_time_unit_within_the_frames():
    assert stencil_stride(1.0, 0.01, 400) == 30
    assert stencil_stride(1.0, 0.2, 400) == 1
    assert stencil_stride(1.0, 0.01, 41) == 5  # half a sequence's frames stay centres


def test_the_coordinates_give_the_frames_stencil_loss(frames_fit):
    data = video()
    est = frames_fit  # (fitted on data)
    model = est.model_
    f, idx, u = frame_windows(data.split("train"), est.normalizer_, 2)
    frames = DerivativeSamples(f[idx], u, 0.16)
    coords = CoordinateSamples.of(frames, model)
    weights = est.record_ and model_weights(est)
    a = frames.loss(model, weights, None)
    b = coords.loss(model, weights, None)
    for key in ("recon", "pred_z", "objective"):
        assert a[key].item() == pytest.approx(b[key].item(), rel=1e-3, abs=1e-6)


def model_weights(est):
    from latent_sindy.configs import from_json
    from latent_sindy.models.loss import LossWeights
    return from_json(LossWeights, est.record_["train"]["loss"], "loss")


def test_latent_derivatives_asked_for_need_five_frames_not_a_smoothing_window():
    data = video(frames=6)
    est = LatentSINDy(1, time="continuous", derivative_order=2, seed=0)
    # 6 frames: a stencil fits; the smoothing window (9 frames) is not asked for
    est.fit(data, epochs=1, derivatives="latent", phases=[], restarts=Restarts(count=0))
    assert est.record_["train"]["derivatives"] == "latent"
    with pytest.raises(UserError, match="too short"):
        est.fit(data, epochs=1, derivatives="smooth", phases=[], restarts=Restarts(count=0))
