"""A continuous-time model's own time unit: fitted in model time, shown and used in the
data's; chosen from the data so that a faster or slower video trains as the reference."""

from __future__ import annotations

import copy
import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from latent_sindy.data import SequenceData
from latent_sindy.errors import UserError
from latent_sindy.models import AutoencoderConfig, LossWeights, ModelConfig
from latent_sindy.models.derivatives import characteristic_time
from latent_sindy.models.dynamics import ContinuousSindyConfig
from latent_sindy.models.dynamics.continuous import (
    TIME_UNIT_REFERENCE,
    TIME_UNIT_STEP,
    time_unit_for,
)
from latent_sindy.models.latent_model import LatentModel
from latent_sindy.training import TrainConfig
from latent_sindy.training.record import run_record

pytestmark = pytest.mark.usefixtures("one_torch_thread")

T = 2 ** (-1 / 4)


def pair(order: int, sine: bool = True) -> tuple:
    """The same coefficients Ψ in a model of unit T and one of unit 1."""
    cfg = ContinuousSindyConfig(derivative_order=order, order=3, include_sine=sine,
                                init="normal", init_scale=0.3)
    one = cfg.build(2, 1)
    scaled = replace(cfg, time_unit=T).build(2, 1)
    with torch.no_grad():
        scaled.psi.copy_(one.psi)
    return one, scaled


@pytest.mark.parametrize("order", [1, 2])
def test_the_real_time_derivative_is_the_model_time_one_rescaled(order: int) -> None:
    one, scaled = pair(order)
    g = torch.Generator().manual_seed(0)
    phase, u = torch.randn(16, 2 * order, generator=g), torch.randn(16, 1, generator=g)
    stretch = torch.tensor([T ** (i // 2) for i in range(2 * order)])  # z^(j) times T^j
    expected = one.derivative(phase * stretch, u) / T ** order
    torch.testing.assert_close(scaled.derivative(phase, u), expected)
    assert float(scaled.l1_penalty().detach()) == pytest.approx(float(one.l1_penalty().detach()))


def test_the_coefficients_are_the_real_time_equations() -> None:
    """Without sines of velocities the real-time library (unit 1) times coefficients() is the
    model's derivative; set_coefficients takes real-time values back."""
    one, scaled = pair(2, sine=False)
    g = torch.Generator().manual_seed(1)
    phase, u = torch.randn(32, 4, generator=g), torch.randn(32, 1, generator=g)
    real = one.library(phase, u) @ scaled.coefficients()
    torch.testing.assert_close(scaled.derivative(phase, u), real)
    assert not torch.allclose(scaled.coefficients(), one.coefficients())
    again = copy.deepcopy(scaled).set_coefficients(scaled.coefficients().detach())
    torch.testing.assert_close(again.psi, scaled.psi)
    whole = torch.zeros_like(scaled.psi, dtype=torch.long)
    whole[1, 0] = 1  # integers are real-time coefficients too
    assert float(copy.deepcopy(scaled).set_coefficients(whole).coefficients()[1, 0]) == \
        pytest.approx(1.0)


def test_a_sine_of_a_velocity_is_written_with_its_model_time_argument() -> None:
    _, scaled = pair(2)
    assert "sin(z0)" in scaled.names and f"sin({T:.4g} z0')" in scaled.names
    assert "sin(z0')" in pair(2)[0].names


def test_the_loss_in_real_time_is_the_loss_in_model_time() -> None:
    """Frames with real-time derivatives through a model of unit T give the terms that the
    same weights give with unit 1 on the derivatives in model time (ẋ T, ẍ T²)."""
    ae = AutoencoderConfig(latent_dim=2, encoder_kind="mlp", decoder_kind="mlp",
                           mlp_widths=(16, 8))
    cfg = ModelConfig(dynamics=ContinuousSindyConfig(derivative_order=2, init="normal",
                                                     init_scale=0.3), observation=ae)
    resolved = cfg.resolve(1, 6, 0)
    torch.manual_seed(0)
    one = LatentModel(resolved)
    scaled = LatentModel(replace(resolved, dynamics=replace(resolved.dynamics, time_unit=T)))
    scaled.load_state_dict(one.state_dict())
    x = torch.randn(8, 3, 1, 6, 6, generator=torch.Generator().manual_seed(2))
    own = x * torch.tensor([1.0, T, T * T])[None, :, None, None, None]
    u = torch.zeros(8, 0)
    for w in (LossWeights(lambda_pred_x=0.3, lambda_pred_z=2.0, lambda_l1=1e-3),
              LossWeights(lambda_pred_z=5.0, relative_pred_z=True)):
        a, b = scaled.loss(x, u, weights=w), one.loss(own, u, weights=w)
        for key in ("recon", "pred_x", "pred_z", "l1", "total"):
            assert float(a[key]) == pytest.approx(float(b[key]), rel=1e-4), key


def test_characteristic_time_is_one_over_the_frequency() -> None:
    pixels = np.array([[0.3, -1.2, 0.7]])
    for w in (0.5, 2.0):
        t = np.linspace(0, 8 * np.pi / w, 4001)[:, None]  # four whole periods
        x, dx, ddx = (np.sin(w * t) * pixels, w * np.cos(w * t) * pixels,
                      -w * w * np.sin(w * t) * pixels)
        assert characteristic_time(x, dx, 1) == pytest.approx(1 / w, rel=1e-2)
        assert characteristic_time(x, ddx, 2) == pytest.approx(1 / w, rel=1e-2)


def test_the_unit_maps_a_faster_system_to_the_reference() -> None:
    assert time_unit_for(TIME_UNIT_REFERENCE) == 1.0
    assert time_unit_for(TIME_UNIT_REFERENCE * 1.05) == 1.0  # near it: exactly 1
    assert time_unit_for(TIME_UNIT_REFERENCE / 2) == pytest.approx(0.5)
    assert time_unit_for(TIME_UNIT_REFERENCE / 1.2) == pytest.approx(1 / TIME_UNIT_STEP)
    with pytest.raises(UserError, match="do not move"):
        time_unit_for(math.inf)


def oscillator_video(omega: float) -> SequenceData:
    """An oscillator at ω seen through a fixed linear image, with exact derivatives."""
    rng = np.random.default_rng(0)
    t = np.arange(30) * 0.05
    phase = rng.uniform(0, 2 * np.pi, (8, 1))
    th = np.cos(omega * t + phase)
    w = rng.uniform(-0.4, 0.4, (1, 1, 4, 4))
    x, dot, ddot = ((a[..., None, None, None] * w).astype(np.float32)
                    for a in (th, -omega * np.sin(omega * t + phase), -omega**2 * th))
    return SequenceData(x + np.float32(0.5), dt=0.05, images_dot=dot, images_ddot=ddot)


def test_a_run_record_holds_the_unit_chosen_from_the_data() -> None:
    ae = AutoencoderConfig(latent_dim=1, encoder_kind="mlp", decoder_kind="mlp")

    def unit(omega: float) -> float:
        dyn = ContinuousSindyConfig(derivative_order=2, time_unit=None)
        cfg = TrainConfig(model=ModelConfig(dynamics=dyn, observation=ae))
        return run_record(cfg, oscillator_video(omega))["model"]["dynamics"]["time_unit"]

    slow, fast = unit(1.0), unit(4.0)
    assert slow == pytest.approx(time_unit_for(1.0), rel=0.2)
    assert slow / fast == pytest.approx(4.0, rel=0.2)  # four times as fast: a quarter


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf, True])
def test_a_bad_time_unit_is_a_one_line_user_error(bad) -> None:
    with pytest.raises(UserError, match="time_unit"):
        ContinuousSindyConfig(time_unit=bad)


def test_a_saved_model_keeps_its_unit_and_equations(tmp_path) -> None:
    from latent_sindy import LatentSINDy

    data = oscillator_video(4.0)
    est = LatentSINDy(1, time="continuous", derivative_order=2, time_unit="data", seed=0,
                      settings=TrainConfig(batch_size=40, lr=1e-3)).fit(data, epochs=1)
    unit = est.model_.dynamics.time_unit
    assert unit != 1.0 and est.record_["model"]["dynamics"]["time_unit"] == unit
    again = LatentSINDy.load(est.save(tmp_path / "run"))
    assert again.model_.dynamics.time_unit == unit
    assert again.equations() == est.equations()
    np.testing.assert_array_equal(again.coefficients(), est.coefficients())


def test_the_motion_time_holds_on_noisy_frames_any_blob_and_background():
    """The time unit is read on the centroid of what moves: the same for a noise-free and a
    noisy video of one motion (noise up to 40 % of the frames' spread: a few per cent of a
    camera's range, which weighs every pixel of the frame), a narrow and a wide blob, a
    short and a long pendulum, with a background or none, where the pixels' characteristic
    time moves with the blob."""
    import dataclasses

    from latent_sindy.models.derivatives import motion_time
    from latent_sindy.worlds.pendulum.video_draws import VideoDraw

    base = VideoDraw(system="pendulum", omega2=(1.0,), damping=(0.0,), size=32, width=0.01,
                     trajectories=12, frames=200, dt=0.02, exact=True)
    times = [motion_time(dataclasses.replace(base, **c).video().images, 0.02) for c in
             ({}, {"noise": 0.02}, {"noise": 0.2}, {"noise": 0.4}, {"width": 0.04},
              {"radius": (0.4,)}, {"background": 0.4})]
    assert max(times) / min(times) < 1.05
    assert times[0] == pytest.approx(1.0, rel=0.1)  # about 1/ω
    pixels = []
    for c in ({}, {"width": 0.04}):
        v = dataclasses.replace(base, **c).video()
        pixels.append(characteristic_time(v.images.reshape(-1, 1, 32, 32),
                                          v.images_ddot.reshape(-1, 1, 32, 32), 2))
    assert pixels[1] / pixels[0] > 1.3  # what the unit was read from before
    faster = dataclasses.replace(base, omega2=(4.0,)).video()
    assert motion_time(faster.images, 0.02) == pytest.approx(times[0] / 2, rel=0.1)


def test_the_motion_time_holds_when_the_motion_dies_out():
    """A damped spring filmed long after its swings died out rests, in most frames, where
    the still scene (the median frame) shows it: those frames differ from it in a few noisy
    pixels, whose centroid would read as fast motion. They read no position, and the time
    stays about 1/ω, with noise or without."""
    import dataclasses

    from latent_sindy.models.derivatives import motion_time
    from latent_sindy.worlds.pendulum.video_draws import VideoDraw

    base = VideoDraw(system="spring", omega2=(2.75,), damping=(0.36,), size=32, width=0.03,
                     trajectories=12, frames=400, dt=0.05, exact=True)
    swinging = motion_time(dataclasses.replace(base, frames=60, damping=(0.0,)).video().images,
                           0.05)
    assert swinging == pytest.approx(2.75 ** -0.5, rel=0.05)
    for noise in (0.0, 0.02, 0.1):
        dying = motion_time(dataclasses.replace(base, noise=noise).video().images, 0.05)
        assert dying == pytest.approx(swinging, rel=0.15)
