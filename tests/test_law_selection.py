"""The law chosen along the sparsity path on held-out derivatives, the law's name whatever
the latents' order, and the warnings a doubtful law gets."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from latent_sindy.equations import UNEXPLAINED_LIMIT, doubt_notes
from latent_sindy.models.dynamics.continuous import ContinuousSindyDynamics
from latent_sindy.sindy.selection import held_out_fvu, select_law
from latent_sindy.training.session import law_key


def pendulum_library(n: int, c: float, noise: float, seed: int):
    rng = np.random.default_rng(seed)
    z, v = rng.uniform(-2, 2, (n, 1)), rng.uniform(-2, 2, (n, 1))
    theta = np.hstack([np.ones_like(z), z, v, z * v ** 2, np.sin(z), z ** 3, v ** 3])
    target = -1.3 * np.sin(z) - c * v + noise * rng.normal(size=z.shape)
    return theta, target


@pytest.mark.parametrize("c", [0.0, 0.03, 0.3])
def test_the_path_keeps_a_small_true_term_and_no_spurious_one(c):
    th, y = pendulum_library(4000, c, 1e-3, 0)
    thv, yv = pendulum_library(1000, c, 1e-3, 1)
    law = select_law(th, y, thv, yv)
    expected = {4} | ({2} if c else set())
    assert set(np.flatnonzero(law.coef[:, 0])) == expected
    assert law.coef[4, 0] == pytest.approx(-1.3, rel=1e-2)
    if c:
        assert law.coef[2, 0] == pytest.approx(-c, rel=0.05)
    assert law.fvu == pytest.approx(held_out_fvu(thv, yv, law.coef))


def test_the_sparsest_law_within_the_tolerance_of_the_best_is_kept():
    th, y = pendulum_library(3000, 0.3, 0.0, 2)
    thv, yv = pendulum_library(500, 0.3, 0.0, 3)
    law = select_law(th, y, thv, yv)
    best = min(p["fvu"] for p in law.path)
    assert law.fvu <= 1.25 * best + 1e-6
    assert all(p["active"] >= int(law.mask.sum()) for p in law.path
               if p["fvu"] <= 1.25 * best + 1e-6)


def test_select_law_refuses_mismatched_or_broken_input():
    th, y = pendulum_library(50, 0.1, 0.0, 0)
    from latent_sindy.errors import UserError
    with pytest.raises(UserError, match="theta"):
        select_law(th, y, th[:, :3], y)
    bad = th.copy()
    bad[0, 0] = np.nan
    with pytest.raises(UserError, match="NaN"):
        select_law(bad, y, th, y)


def test_a_law_reads_the_same_whatever_the_latents_order():
    def dyn(active: dict[int, list[str]]) -> ContinuousSindyDynamics:
        d = ContinuousSindyDynamics(2, 0, derivative_order=2, order=2)
        mask = torch.zeros_like(d.mask)
        for j, names in active.items():
            for n in names:
                mask[d.names.index(n), j] = True
        d.mask.copy_(mask)
        return d

    a = dyn({0: ["sin(z0)"], 1: ["sin(z1)", "z1'"]})
    b = dyn({0: ["sin(z0)", "z0'"], 1: ["sin(z1)"]})
    c = dyn({0: ["sin(z0)"], 1: ["sin(z1)", "z0'"]})
    assert law_key(a) == law_key(b) != law_key(c)


def test_doubt_notes_name_disagreeing_starts_and_an_unexplained_share():
    agreed = {"restarts": {"starts": 2, "agreed": True, "laws": []}, "unexplained": 1e-3}
    assert doubt_notes(agreed) == []
    split = {"restarts": {"starts": 3, "agreed": False, "laws": [
        {"law": [["sin(z0)"]]}, {"law": [["z0", "z0 z0'^2"]]}, {"law": []}]},
        "unexplained": 1e-3}
    (note,) = doubt_notes(split)
    assert "no two of the 3 starts" in note and "z0 + z0 z0'^2" in note
    (note,) = doubt_notes({"unexplained": 2 * UNEXPLAINED_LIMIT})
    assert "10 % of the latent's derivative unexplained" in note


def test_reselect_sets_the_chosen_law_on_a_trained_model():
    from latent_sindy import LatentSINDy, Phase, Restarts
    from latent_sindy.training.config import TrainConfig
    from latent_sindy.training.prepare import derivative_samples
    from latent_sindy.training.reselect import latent_derivatives, reselect_law
    from latent_sindy.worlds.pendulum.video_draws import VideoDraw

    video = VideoDraw(system="pendulum", omega2=(1.2,), damping=(0.1,), size=12, width=0.05,
                      trajectories=8, frames=30, dt=0.1).video()
    est = LatentSINDy(1, time="continuous", derivative_order=2, seed=0).fit(
        video, epochs=2, phases=[Phase(1, "calibration")], restarts=Restarts(count=0))
    model = est.model_
    split = [derivative_samples(video.split(s), est.normalizer_, 2, TrainConfig())
             for s in ("train", "val")]
    choice = reselect_law(model, *split)
    assert choice is not None
    assert np.array_equal(model.dynamics.mask.numpy(), choice.mask)
    psi = model.dynamics.psi.detach().double().numpy()
    assert np.allclose(psi, choice.coef.astype(np.float32), rtol=1e-6, atol=0)
    # the share reported is the chosen law's on the validation samples, in the model's time
    phase, top, u = latent_derivatives(model, split[1])
    dyn = model.dynamics
    theta = dyn.library(phase * dyn._phase_scale, u).double().numpy()
    target = (top * dyn.time_unit ** 2).double().numpy()
    assert held_out_fvu(theta, target, choice.coef) == pytest.approx(choice.fvu, rel=1e-9)
