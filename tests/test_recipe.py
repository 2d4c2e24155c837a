"""The continuous-time recipe: what ``LatentSINDy(time="continuous")`` trains with when
given no settings, and that it is the pendulum-video study's ``scalefree`` schedule."""

from __future__ import annotations

import numpy as np
import pytest

from latent_sindy import LatentSINDy, Phase, Restarts, SequenceData
from latent_sindy.errors import UserError
from latent_sindy.training import TrainConfig, manifold_start, recipe
from latent_sindy.worlds.pendulum.video_schedules import SCHEDULES

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def small_video(omega2: float = 2.0) -> SequenceData:
    from latent_sindy.worlds.pendulum.video import pendulum_video

    return pendulum_video(n_train=4, n_val=2, n_test=2, steps=40, size=9, frames_every=2,
                          omega2=omega2)


def test_the_recipe_is_the_studys_scalefree_schedule() -> None:
    s = SCHEDULES["scalefree"]
    assert recipe.SCHEDULE == {"epochs": s.epochs, "lr": s.lr, "batch_size": s.batch,
                               "prune_below": s.prune_below, "prune_every": s.prune_every,
                               "refine_epochs": s.refine_epochs, "weight_decay": 0.0,
                               "starts": 1}
    assert recipe.INIT == {"init": s.init, "init_scale": s.init_scale}
    assert (recipe.PRED_X, recipe.PRED_Z, recipe.L1) == (s.pred_x, s.pred_z, s.l1 / 12)
    calib = recipe.calibration(0.5)
    assert calib.epochs == s.calibrate_epochs
    assert calib.changes["lr"] == s.calibrate_lr
    assert calib.changes["prune_every"] == s.calibrate_prune_every
    assert calib.changes["loss"].lambda_pred_x == s.calibrate_x
    assert calib.changes["loss"].lambda_pred_z == s.calibrate_relative
    assert calib.changes["loss"].relative_pred_z
    # the study's limits; the recipe trains until two starts agree on the law (three at most)
    assert recipe.RESTARTS == Restarts(2, s.restart_above, s.restart_fvu, agree=2)


def test_a_continuous_fit_without_settings_takes_the_recipe(monkeypatch) -> None:
    # (the settings are checked here, not the start's quality: a shorter regression)
    monkeypatch.setattr(manifold_start, "REGRESSION_STEPS", 300)
    data = small_video()
    est = LatentSINDy(1, time="continuous", derivative_order=2, seed=0)
    assert (est.encoder, est.decoder, est.recipe) == ("mlp", "mlp", True)
    est.fit(data, epochs=2, phases=[Phase(1, "calibration", {"lr": 1e-4})])
    rec = est.record_
    spread = data.pixel_stats()[1]
    assert rec["model"]["observation"]["pca_components"] == recipe.components_for(data)
    assert rec["model"]["dynamics"]["init"] == "normal"
    assert isinstance(rec["model"]["dynamics"]["time_unit"], float)
    assert rec["train"]["lr"] == 3e-3 and rec["train"]["batch_size"] == 100
    assert rec["train"]["loss"]["lambda_pred_z"] == pytest.approx(5e-7 / spread**2)
    assert est.kept_["restarts"]["starts"] in (2, 3) and est.kept_["phase"] == "calibration"


def test_settings_given_mean_no_recipe_and_a_folder_takes_the_main_fit(tmp_path) -> None:
    data = small_video()
    own = LatentSINDy(1, time="continuous", derivative_order=2,
                      settings=TrainConfig(batch_size=20, lr=1e-3))
    own.fit(data, epochs=1)
    assert not own.recipe and "restarts" not in own.kept_
    assert own.record_["model"]["observation"]["pca_components"] == 0
    assert own.record_["model"]["dynamics"]["time_unit"] == 1.0  # the data's time
    chosen = LatentSINDy(1, time="continuous", derivative_order=2, time_unit="data",
                         settings=TrainConfig(batch_size=20)).fit(data, epochs=1)
    assert chosen.record_["model"]["dynamics"]["time_unit"] != 1.0
    with pytest.raises(UserError, match="time_unit data are for time='continuous'"):
        LatentSINDy(1, time_unit="data")
    # into a run folder the recipe trains its main fit (its phases and restarts: in memory)
    folder = LatentSINDy(1, time="continuous", derivative_order=2).fit(data, epochs=1,
                                                                       out=tmp_path / "run")
    assert folder.record_["model"]["observation"]["pca_components"] == 48
    assert folder.record_["train"]["lr"] == 3e-3 and "restarts" not in folder.kept_
    with pytest.raises(UserError, match="in memory"):
        LatentSINDy(1, time="continuous", derivative_order=2).fit(
            data, epochs=1, out=tmp_path / "other", phases=[Phase(1, "calibration")])


def test_components_fit_small_frames_and_few_frames() -> None:
    data = small_video()
    assert recipe.components_for(data) == 48  # 81 pixels, 4 x 21 training frames
    tiny = SequenceData(np.random.default_rng(0).uniform(0, 1, (12, 4, 1, 3, 3)).astype(
        np.float32), dt=0.1, seed=0)
    assert recipe.components_for(tiny) == 9
    few = SequenceData(tiny.images[:3], dt=0.1, seed=0)  # one training sequence of 4 frames
    assert few.split_counts()["train"] == 1 and recipe.components_for(few) == 3


def test_the_recipe_puts_components_only_where_the_networks_take_them() -> None:
    est = LatentSINDy(1, time="continuous", derivative_order=2, decoder="fc")
    est.fit(small_video(), epochs=1, phases=[], restarts=Restarts(count=0))
    assert est.record_["model"]["observation"]["pca_components"] == 0
