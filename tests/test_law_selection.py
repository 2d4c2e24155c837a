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


def mask_of(*terms: int) -> np.ndarray:
    m = np.zeros((7, 1), bool)
    m[list(terms), 0] = True
    return m


@pytest.mark.parametrize("c", [0.03, 0.3])
def test_a_small_true_term_the_cut_lost_comes_back(c):
    th, y = pendulum_library(4000, c, 1e-3, 0)
    thv, yv = pendulum_library(1000, c, 1e-3, 1)
    law = select_law(th, y, thv, yv, start=mask_of(4))  # trained: sin z alone
    assert set(np.flatnonzero(law.coef[:, 0])) == {2, 4}
    assert law.coef[4, 0] == pytest.approx(-1.3, rel=1e-2)
    assert law.coef[2, 0] == pytest.approx(-c, rel=0.05)
    assert law.fvu < law.start_fvu
    assert law.fvu == pytest.approx(held_out_fvu(thv, yv, law.coef))


def test_a_right_law_stays_a_spurious_term_goes_and_a_wrong_one_is_swapped():
    th, y = pendulum_library(3000, 0.0, 1e-3, 2)
    thv, yv = pendulum_library(800, 0.0, 1e-3, 3)
    assert set(np.flatnonzero(select_law(th, y, thv, yv, start=mask_of(4)).mask)) == {4}
    assert set(np.flatnonzero(select_law(th, y, thv, yv, start=mask_of(4, 3)).mask)) == {4}
    assert set(np.flatnonzero(select_law(th, y, thv, yv, start=mask_of(3)).mask)) == {4}
    assert set(np.flatnonzero(select_law(th, y, thv, yv, start=mask_of()).mask)) == {4}


def test_a_law_grows_by_one_term_at_most():
    rng = np.random.default_rng(4)
    th = rng.normal(size=(2000, 7))
    y = th @ rng.normal(size=(7, 1))  # every term matters
    law = select_law(th[:1500], y[:1500], th[1500:], y[1500:], start=mask_of(0))
    assert int(law.mask.sum()) == 2


def test_select_law_refuses_mismatched_or_broken_input():
    th, y = pendulum_library(50, 0.1, 0.0, 0)
    from latent_sindy.errors import UserError
    with pytest.raises(UserError, match="theta"):
        select_law(th, y, th[:, :3], y, start=mask_of(4))
    with pytest.raises(UserError, match="mask"):
        select_law(th, y, th, y, start=np.ones((3, 1), bool))
    bad = th.copy()
    bad[0, 0] = np.nan
    with pytest.raises(UserError, match="NaN"):
        select_law(bad, y, th, y, start=mask_of(4))


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
    mixed = dyn({0: ["z0 z1"], 1: ["z1'"]})  # a product's factors swap places too
    swapped = dyn({0: ["z0'"], 1: ["z0 z1"]})
    assert law_key(mixed) == law_key(swapped)


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


def test_a_law_written_at_the_start_on_a_close_call_is_doubted_aloud():
    close = {"settled": True, "close": [(["z0", "sin(z0)"], 0.12), (["z0'", "sin(z0)"], 0.3)]}
    (note,) = doubt_notes({"start": close, "unexplained": 1e-3})
    assert "close call" in note and "z0' + sin(z0) took away only 30 %" in note
    # a start that trained on (not settled) wrote no law of its own; none close: no doubt
    # of the close call (the unsettled start's own doubt needs the law it searched)
    assert doubt_notes({"start": {**close, "settled": False}, "unexplained": 1e-3}) == []
    assert doubt_notes({"start": {"settled": True, "close": []}, "unexplained": 1e-3}) == []


def test_a_law_the_main_fit_wrote_after_an_unsettled_start_is_doubted_aloud():
    unsettled = {"law_fvu": [0.12, 0.5], "laws": [], "close": [], "short": []}
    (note,) = doubt_notes({"start": unsettled, "unexplained": 1e-3})
    assert "settled no law" in note and "left 50 % of the held-out" in note
    assert doubt_notes({"start": {**unsettled, "law_fvu": [0.1, 0.2], "settled": True},
                        "unexplained": 1e-3}) == []
    # no law searched (the data hold actions): nothing to say about the start
    assert doubt_notes({"start": {"eigenvalues": [1.0]}, "unexplained": 1e-3}) == []


def test_a_law_without_a_rate_term_on_sequences_shorter_than_a_swing_is_doubted_aloud():
    short = {"settled": True, "short": [("z0", 1.0)]}
    (note,) = doubt_notes({"start": short, "unexplained": 1e-3})
    assert "z0's law has no term in z0'" in note and "1.0 rad (0.16 of a period)" in note


def test_reselect_sets_the_chosen_law_on_a_trained_model():
    from latent_sindy import LatentSINDy, Phase, Restarts
    from latent_sindy.training.config import TrainConfig
    from latent_sindy.training.prepare import derivative_samples
    from latent_sindy.training.reselect import latent_derivatives, reselect_law
    from latent_sindy.worlds.pendulum.video_draws import VideoDraw

    video = VideoDraw(system="pendulum", omega2=(1.2,), damping=(0.1,), size=12, width=0.05,
                      trajectories=8, frames=30, dt=0.1).video()
    # (no principal-component front: the recipe's geodesic start, which needs one, is not
    # what this test is about, and costs most of its time)
    est = LatentSINDy(1, time="continuous", derivative_order=2, seed=0, pca_components=0).fit(
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
