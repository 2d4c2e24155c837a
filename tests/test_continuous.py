"""Continuous-time latent SINDy (the SINDy autoencoder's formulation): the chain-rule time
derivatives through the networks, their estimate from frames, the fit of a small oscillator
video, the equations, the step, the files and the refused settings."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from latent_sindy import LatentSINDy, SequenceData
from latent_sindy.errors import UserError
from latent_sindy.models import AutoencoderConfig, LossWeights, ModelConfig
from latent_sindy.models.derivatives import along, along_layers, estimate_derivatives
from latent_sindy.models.dynamics import ContinuousSindyConfig, make_dynamics
from latent_sindy.models.encoders import MlpEncoder
from latent_sindy.training import TrainConfig

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def pendulum_frames(theta: np.ndarray, rate: np.ndarray, accel: np.ndarray, side: int = 11
                    ) -> tuple[np.ndarray, ...]:
    """The pendulum video's image of angles theta (...) on a side x side grid over
    [-1.5, 1.5]², exp(-((X - sin θ)² + (Y + cos θ)²) / 0.05), with its exact first and second
    time derivatives for the angle's rate and acceleration (chain rule): (..., 1, side, side)
    float32 each."""
    g = np.linspace(-1.5, 1.5, side)
    x, y = np.meshgrid(g, -g)  # Y from 1.5 at the top to -1.5
    th, th1, th2 = (np.asarray(a, np.float64)[..., None, None] for a in (theta, rate, accel))
    c, s = np.cos(th), np.sin(th)
    img = np.exp(-((x - s) ** 2 + (y + c) ** 2) / 0.05)
    d_theta = 40 * (x * c + y * s)  # d log I / dθ
    d2_theta = d_theta**2 + 40 * (y * c - x * s)  # (d²I / dθ²) / I
    dot = img * d_theta * th1
    ddot = img * (d2_theta * th1**2 + d_theta * th2)
    return tuple(a[..., None, :, :].astype(np.float32) for a in (img, dot, ddot))


def oscillator(n: int = 10, frames: int = 40, dt: float = 0.1, seed: int = 0,
               images: str = "linear") -> SequenceData:
    """n sequences of a harmonic oscillator θ̈ = -θ (amplitudes 0.3-1) seen as images with
    their exact derivatives: a fixed random linear map of θ on 8 x 8 pixels ("linear"), or
    the pendulum video's image of θ on 11 x 11 ("pendulum")."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames) * dt
    amp, phase = rng.uniform(0.3, 1.0, (n, 1)), rng.uniform(0, 2 * np.pi, (n, 1))
    th, rate = amp * np.cos(t + phase), -amp * np.sin(t + phase)
    if images == "pendulum":
        x, dot, ddot = pendulum_frames(th, rate, -th)
    else:
        w = np.random.default_rng(1234).uniform(-0.4, 0.4, (1, 8, 8))
        x, dot, ddot = ((a[..., None, None, None] * w).astype(np.float32)
                        for a in (th, rate, -th))
        x = x + np.float32(0.5)
    return SequenceData(x, dt=dt, images_dot=dot, images_ddot=ddot, seed=seed)


def estimator(seed: int = 0, refine: int = 20, **model) -> LatentSINDy:
    """The oscillator's estimator: 1 latent, z'' over polynomials of (z, z') to order 3
    without the constant (which would let an offset of z and a cubic term stand in for the
    linear one), small fully connected networks."""
    dyn = ContinuousSindyConfig(**{"derivative_order": 2, "order": 3, "include_sine": False,
                                   "include_constant": False, "init": "normal",
                                   "init_scale": 0.1, **model})
    ae = AutoencoderConfig(latent_dim=1, encoder_kind="mlp", decoder_kind="mlp",
                           mlp_widths=(32, 16))
    return LatentSINDy(1, model=ModelConfig(dynamics=dyn, observation=ae), seed=seed,
                       loss=LossWeights(lambda_pred_x=0.1, lambda_pred_z=0.1, lambda_l1=1e-2),
                       settings=TrainConfig(lr=1e-2, weight_decay=0.0, batch_size=40,
                                            prune_below=0.1, prune_every=40,
                                            refine_epochs=refine))


@pytest.fixture(scope="module")
def fitted() -> LatentSINDy:
    with torch.random.fork_rng():
        torch.set_num_threads(1)
        return estimator(refine=4).fit(oscillator(n=6, frames=30), epochs=8,
                                                          prune_every=2, prune_below=0.01)


# ---------------------------------------------------------------- derivatives


def test_forward_mode_derivatives_equal_finite_differences_along_a_path() -> None:
    """ż = J ẋ and z̈ = J ẍ + H[ẋ, ẋ] of the fully connected encoder, against central
    differences of z(x(t)) along x(t) = x + ẋ t + ẍ t²/2 (float64)."""
    torch.manual_seed(0)
    cfg = AutoencoderConfig(channels=1, image_size=8, latent_dim=3, encoder_kind="mlp",
                            decoder_kind="mlp")
    enc = MlpEncoder(cfg.encoder_part(), cfg.image_shape, cfg.latent_dim).double()
    x, dx, ddx = torch.randn(3, 5, 1, 8, 8, dtype=torch.float64).unbind(0)
    z, dz, ddz = along(enc, x, dx, ddx)
    h = 1e-4
    with torch.no_grad():
        up, mid, down = (enc(x + dx * t + ddx * t * t / 2) for t in (h, 0.0, -h))
    torch.testing.assert_close(z, mid)
    torch.testing.assert_close(dz, (up - down) / (2 * h), rtol=1e-6, atol=1e-7)
    torch.testing.assert_close(ddz, (up - 2 * mid + down) / h**2, rtol=1e-4, atol=1e-5)
    _, dz1 = along(enc, x, dx)  # first order alone
    torch.testing.assert_close(dz1, dz)
    assert torch.autograd.grad(ddz.sum(), enc.net[0].weight)[0].abs().sum() > 0


def test_layer_by_layer_derivatives_equal_forward_mode_through_the_whole_network() -> None:
    torch.manual_seed(1)
    net = nn.Sequential(nn.Linear(6, 5), nn.Tanh(), nn.Linear(5, 4), nn.ELU(), nn.Linear(4, 2))
    x, dx, ddx = torch.randn(3, 7, 6).unbind(0)
    for whole, layers in ((along(net, x, dx, ddx), along_layers(net, x, dx, ddx)),
                          (along(net, x, dx), along_layers(net, x, dx))):
        for a, b in zip(whole, layers, strict=True):
            torch.testing.assert_close(a, b)


@pytest.mark.parametrize(("method", "tolerance"), [("central", (0.005, 0.015)),
                                                   ("smooth", (0.006, 0.08))])
def test_derivatives_estimated_from_frames_match_the_exact_ones(method, tolerance) -> None:
    """Pendulum-video frames 0.02 apart (the paper's dt): the estimate's RMS error relative
    to the exact derivatives' RMS (measured: central 0.0019 and 0.0052, smooth 0.0029 and
    0.047; ẍ from the exact ẋ 0.0038)."""
    data = oscillator(n=3, frames=60, dt=0.02, images="pendulum")
    dot, ddot = estimate_derivatives(data.images, data.dt, 2, method)
    for est, exact, tol in ((dot, data.images_dot, tolerance[0]),
                            (ddot, data.images_ddot, tolerance[1])):
        assert est.shape == exact.shape and est.dtype == np.float32
        rel = np.sqrt(np.mean((est - exact) ** 2) / np.mean(exact**2))
        assert rel < tol, (method, rel)
    (first,) = estimate_derivatives(data.images, data.dt, 1, method)
    np.testing.assert_array_equal(first, dot)
    _, from_exact = estimate_derivatives(data.images, data.dt, 2, method, dx=data.images_dot)
    rel = np.sqrt(np.mean((from_exact - data.images_ddot) ** 2) / np.mean(data.images_ddot**2))
    assert rel < tolerance[1], rel


# ---------------------------------------------------------------- the model


def test_step_integrates_the_equations() -> None:
    """RK4 over dt: z' = -z gives exp(-dt); z'' = -z moves (z, z') along the circle."""
    first = make_dynamics("continuous", 1, 0, derivative_order=1, order=1, include_sine=False,
                          dt=0.1)
    first.set_coefficients(torch.tensor([[0.0], [-1.0]]))  # terms 1, z0
    z = first.rollout(torch.ones(1, 1), torch.zeros(1, 10, 0))[0, :, 0]
    torch.testing.assert_close(z, torch.exp(-0.1 * torch.arange(11.0)), rtol=1e-6, atol=1e-7)
    second = make_dynamics("continuous", 1, 0, derivative_order=2, order=1,
                           include_sine=False, dt=0.1)
    assert second.names == ["1", "z0", "z0'"]
    second.set_coefficients(torch.tensor([[0.0], [-1.0], [0.0]]))
    s = second.rollout(torch.tensor([[1.0, 0.0]]), torch.zeros(1, 10, 0))[0]
    t = 0.1 * torch.arange(11.0)
    torch.testing.assert_close(s, torch.stack([torch.cos(t), -torch.sin(t)], -1),
                               rtol=1e-5, atol=1e-6)
    with pytest.raises(UserError, match="phase state of 2 coordinates"):
        second.step(torch.zeros(1, 1), torch.zeros(1, 0))


def test_equations_are_written_with_primes() -> None:
    dyn = ContinuousSindyConfig(derivative_order=2, order=3).build(1, 0)
    names = dyn.names
    assert names[:6] == ["1", "z0", "z0'", "z0^2", "z0 z0'", "z0'^2"]
    assert names[-2:] == ["sin(z0)", "sin(z0')"]
    bare = ContinuousSindyConfig(derivative_order=2, order=3, include_constant=False)
    assert bare.build(1, 0).names == names[1:]
    coef = torch.zeros(len(names), 1)
    coef[names.index("sin(z0)")] = -0.98
    coef[names.index("z0 z0'^2")] = 0.012
    dyn.set_coefficients(coef)
    assert dyn.equations() == ["z0'' = 0.012 z0 z0'^2 - 0.98 sin(z0)"]
    one = ContinuousSindyConfig(derivative_order=1, order=2).build(2, 1)
    assert one.names[:4] == ["1", "z0", "z1", "u0"]
    coef = torch.zeros(len(one.names), 2)
    coef[1, 0], coef[3, 1] = -1.0, 0.5
    one.set_coefficients(coef)
    assert one.equations() == ["z0' = -1 z0", "z1' = 0.5 u0"]


# ---------------------------------------------------------------- fitting


def test_a_short_fit_recovers_the_oscillator() -> None:
    """z'' = -z from 8 sequences of 40 frames in 120 epochs (about 20 s on one core): z0
    alone stays active, its coefficient -1 (the oscillator's, whatever the scale of z).

    These settings gave z'' = -1 z0 (-1.01 for seed 4) with seeds 0, 2, 3 and 4 of 0-5. Seeds
    1 and 5 ended in z'' = -0.6 z0^3 and z'' = 0.465 z0 - 0.383 z0^3, local minima whose fit
    shows it (validation pred_x 0.54 and 0.28, against 0.005-0.014): the SINDy autoencoder's
    known dependence on its start. With the constant term, or with L1 weight 1e-3, fewer
    seeds found the linear equation alone."""
    est = estimator(seed=0).fit(oscillator(), epochs=120)
    names = est.model_.dynamics.names
    coef = est.coefficients()[0]
    assert {names[i] for i in np.flatnonzero(coef)} == {"z0"}, est.equations()
    assert coef[names.index("z0")] == pytest.approx(-1.0, abs=0.05)
    last = est.metrics_[-1]
    assert last["val/recon"] < 0.01 and last["val/pred_x"] < 0.05


def test_the_relative_latent_term_is_the_unexplained_fraction_and_scale_free(
        fitted: LatentSINDy) -> None:
    """relative_pred_z: the z̈ term is the absolute one over the encoder's z̈ variance, and
    stretching z (the decoder undoing it) leaves it as it was where the absolute term grows
    with the stretch squared."""
    import copy
    from dataclasses import replace

    model = copy.deepcopy(fitted.model_)
    names = model.dynamics.names
    coef = torch.zeros(len(names), 1)
    coef[names.index("z0")] = -0.7  # z'' = -0.7 z: the same equation in any scale of z
    model.dynamics.set_coefficients(coef)
    x = torch.randn(16, 3, 1, 8, 8, generator=torch.Generator().manual_seed(0))
    u = torch.zeros(16, 0)
    plain = LossWeights(lambda_pred_z=1.0)
    rel = replace(plain, relative_pred_z=True)

    def terms(m) -> tuple[float, float, torch.Tensor]:
        with torch.no_grad():
            ddz = along(m.autoencoder.encoder, *x.unbind(1))[2]
            return (float(m.loss(x, u, weights=plain)["pred_z"]),
                    float(m.loss(x, u, weights=rel)["pred_z"]), ddz)

    a, r, ddz = terms(model)
    assert r == pytest.approx(a / float((ddz - ddz.mean()).square().mean()), rel=1e-5)
    with torch.no_grad():
        enc = [m for m in model.autoencoder.encoder.net if isinstance(m, nn.Linear)][-1]
        dec = next(m for m in model.autoencoder.decoder.net if isinstance(m, nn.Linear))
        enc.weight.mul_(3.0)
        enc.bias.mul_(3.0)
        dec.weight.div_(3.0)
    a3, r3, _ = terms(model)
    assert a3 == pytest.approx(9 * a, rel=1e-4)
    assert r3 == pytest.approx(r, rel=1e-4)


def test_refinement_drops_the_l1_term_and_prunes_no_more(fitted: LatentSINDy) -> None:
    """8 epochs, the last 4 refining: their total is the objective (no L1 term), and the
    pruning (every 2 epochs here) stops after epoch 4."""
    rows = fitted.metrics_
    assert [r["epoch"] for r in rows] == list(range(1, 9))
    for r in rows:
        refining = r["epoch"] > 4
        gap = r["train/total"] - r["train/objective"]
        assert (gap == pytest.approx(0.0, abs=1e-12)) == refining, r
        assert r["train/l1"] > 0
        assert (r["sindy/pruned"] is None) == (refining or r["epoch"] % 2 == 1), r


def test_the_same_seed_gives_the_same_model_from_estimated_derivatives() -> None:
    """Frames alone (a real camera): the derivatives are estimated; seeded, reproducible."""
    data = oscillator(n=6, frames=30)
    frames = SequenceData(data.images, dt=data.dt, seed=0)
    a = estimator(refine=0).fit(frames, epochs=3)
    b = estimator(refine=0).fit(frames, epochs=3)
    np.testing.assert_array_equal(a.coefficients(), b.coefficients())
    assert np.isfinite(a.metrics_[-1]["val/objective"])
    c = estimator(refine=0).fit(data, epochs=3)  # the exact derivatives differ
    assert not np.array_equal(a.coefficients(), c.coefficients())


def test_two_threads_train_it_with_torch_threads(monkeypatch) -> None:
    """Forward-mode derivatives cannot run in several Python threads at once: with two
    threads the batch is not split ("ops"), and a split is refused."""
    monkeypatch.setattr(torch, "get_num_threads", lambda: 2)
    est = estimator(refine=0).fit(oscillator(n=4, frames=10), epochs=1)
    assert np.isfinite(est.metrics_[-1]["val/objective"])
    with pytest.raises(UserError, match="--parallel batch splits a batch"):
        estimator(refine=0).fit(oscillator(n=4, frames=10), epochs=1, parallel="batch")


def test_save_and_load_give_the_same_model(fitted: LatentSINDy, tmp_path) -> None:
    assert fitted.equations()[0].startswith("z0'' = ")
    fitted.save(tmp_path / "run")
    back = LatentSINDy.load(tmp_path / "run")
    np.testing.assert_array_equal(back.coefficients(), fitted.coefficients())
    assert back.equations() == fitted.equations()
    assert back.time == "continuous" and back.derivative_order == 2
    images = oscillator(n=2, frames=5).images
    np.testing.assert_array_equal(back.encode(images), fitted.encode(images))
    with pytest.raises(UserError, match="previous=frames_before"):  # ż is not in a frame
        back.predict(images[0, 1], np.zeros(0, np.float32))
    np.testing.assert_array_equal(  # the loaded model steps from two frames as the fitted
        back.predict(images[0, 1], np.zeros(0, np.float32), previous=images[0, 0]),
        fitted.predict(images[0, 1], np.zeros(0, np.float32), previous=images[0, 0]))


def test_a_first_order_model_predicts_by_integrating_one_step() -> None:
    data = oscillator(n=4, frames=10)
    est = LatentSINDy(1, time="continuous", encoder="mlp", decoder="mlp", seed=0,
                      settings=TrainConfig(batch_size=20)).fit(data, epochs=1)
    assert est.equations()[0].startswith("z0' = ")
    assert est.model_.dynamics.dt == pytest.approx(0.1)  # the data's
    x = data.images[:3, 0]
    pred = est.predict(x, np.zeros((3, 0), np.float32))
    with torch.no_grad():
        z = est.model_.encode(est.normalizer_.normalize(x))
        want = est._pixels(est.model_.decode(est.model_.dynamics.step(z, torch.zeros(3, 0))))
    np.testing.assert_allclose(pred, want, rtol=1e-6)


# ---------------------------------------------------------------- refused settings


def test_bad_settings_are_one_line_user_errors() -> None:
    with pytest.raises(UserError, match="derivative_order 3: use 1"):
        LatentSINDy(1, time="continuous", derivative_order=3)
    with pytest.raises(UserError, match=r"derivative_order 2, .* are for time='continuous'"):
        LatentSINDy(1, derivative_order=2)
    with pytest.raises(UserError, match=r"time_unit 2\.0 are for time='continuous'"):
        LatentSINDy(1, time_unit=2.0)
    with pytest.raises(UserError, match="time_unit -1"):
        LatentSINDy(1, time="continuous", derivative_order=2, encoder="mlp", decoder="mlp",
                    time_unit=-1.0)
    with pytest.raises(UserError, match="time='continuous' is for SINDy"):
        LatentSINDy(1, time="continuous", dynamics="linear")
    with pytest.raises(UserError, match="time 'weekly'"):
        LatentSINDy(1, time="weekly")
    with pytest.raises(UserError, match="--decoder mlp or fc"):
        LatentSINDy(1, time="continuous", decoder="conv")
    data = oscillator(n=4, frames=10)
    no_time = SequenceData(data.images, seed=0)  # no dt, no derivatives
    est = LatentSINDy(1, time="continuous", derivative_order=2, encoder="mlp", decoder="mlp")
    with pytest.raises(UserError, match=r"give the data's time step \(SequenceData\(dt=\.\.\.\)"):
        est.fit(no_time, epochs=1)
    with pytest.raises(UserError, match="--derivatives central is for continuous-time"):
        TrainConfig(derivatives="central")
    with pytest.raises(UserError, match="--refine-epochs 5: use 0 to --epochs"):
        TrainConfig(epochs=4, refine_epochs=5)


def test_the_command_line_trains_and_prints_a_second_order_model(tmp_path, capsys) -> None:
    from latent_sindy.cli import main
    from latent_sindy.data.store import write_sequences

    write_sequences(tmp_path / "osc.h5", oscillator(n=4, frames=12))
    run = tmp_path / "run"
    assert main(["train", "--data", str(tmp_path / "osc.h5"), "--out", str(run), "--epochs", "3",
                 "--refine-epochs", "1", "--batch-size", "16", "--no-progress", "--threads", "1",
                 "continuous", "--derivative-order", "2", "image", "--encoder", "mlp",
                 "--decoder", "mlp", "--latent-dim", "1", "--mlp-widths", "16", "8"]) == 0
    capsys.readouterr()
    assert main(["equations", str(run)]) == 0
    out = capsys.readouterr().out
    assert "continuous-time SINDy latent dynamics" in out and "z0'' = " in out
    assert LatentSINDy.load(run).derivative_order == 2
