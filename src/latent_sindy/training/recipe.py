"""The continuous-time recipe: what ``LatentSINDy(time="continuous")`` trains with unless
told otherwise, for any video.

It is the pendulum video's (RESULTS.md, "The pendulum video"), made free of the data's
scales: the SINDy autoencoder's fully connected networks behind a principal-component front
(:data:`COMPONENTS`, fewer for smaller frames); the ``scalefree`` schedule (:data:`SCHEDULE`:
250 epochs at learning rate 3e-3, batch 100, pruning at 0.1 every 25 epochs, 50 of
refinement; coefficients starting normal with std 1e-3); loss weights set for the frames'
pixel spread (:func:`recipe_loss`); a time unit chosen from the data (``time_unit=None``);
then a calibration of 300 epochs (:func:`calibration`), the law checked against its
neighbours on held-out derivatives (:mod:`~latent_sindy.training.reselect`), and fresh
starts by the rule :data:`RESTARTS` until two agree; the schedule counts updates
(:func:`schedule_scale`). Each start begins at the frames' geodesic coordinates, and where
the law searched on them with their unit and zero explains the held-out z̈, the start is
settled there and none of the training above runs
(:mod:`~latent_sindy.training.manifold_start`).

    from latent_sindy import LatentSINDy
    model = LatentSINDy(latent_dim=1, time="continuous", derivative_order=2).fit(video)
    model.print()                       # z0'' = c sin(z0), c near -ω², when it succeeds
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from latent_sindy.data import SequenceData
from latent_sindy.models.loss import LossWeights
from latent_sindy.training.config import TrainConfig
from latent_sindy.training.manifold_start import begin_session
from latent_sindy.training.reselect import reselect_session
from latent_sindy.training.session import Phase, Restarts

__all__ = ["COMPONENTS", "INIT", "REFERENCE_BATCHES", "RESTARTS", "SCHEDULE", "apply_recipe",
           "calibration",
           "components_for", "default_settings", "pixel_spread", "recipe_epochs", "recipe_loss",
           "recipe_settings", "scaled", "schedule_scale", "unit_of"]

#: Principal components in front of the networks (the published model's 48).
COMPONENTS = 48
#: The main fit's settings (the pendulum video study's ``scalefree`` schedule).
SCHEDULE: dict[str, Any] = {"epochs": 250, "lr": 3e-3, "batch_size": 100, "prune_below": 0.1,
                            "prune_every": 25, "refine_epochs": 50, "weight_decay": 0.0,
                            "starts": 1}
#: Batches an epoch of the video the schedule was set on (100 trajectories of 100 frames).
REFERENCE_BATCHES = 100
#: The coefficients' start.
INIT: dict[str, Any] = {"init": "normal", "init_scale": 1e-3}
#: Starts are trained until one with a good validation reconstruction and under 1 % of the
#: encoder's z^(k) unexplained writes the law (the same active terms) of another, three at most;
#: the kept start is the best of the largest group that agrees (a single start's residual
#: does not tell a wrong law from a right one: RESULTS.md, "Videos drawn from a family").
RESTARTS = Restarts(count=2, recon_above=0.1, fvu_above=0.01, agree=2)
#: The published weights (pixels in [0, 1], means over pixels): ẍ, then z̈ and L1 of the
#: schedule; both of the latter grow as the frames' spread shrinks (:func:`recipe_loss`).
PRED_X, PRED_Z, L1 = 5e-4, 5e-7, 1e-9 / 12


def pixel_spread(data: SequenceData) -> float:
    """The training frames' standard deviation (the normaliser's) in pixels of [0, 1]."""
    return data.pixel_stats()[1] / data.pixel_scale()


def recipe_loss(spread: float, pred_x: float = PRED_X, relative_z: float = 0.0) -> LossWeights:
    """The recipe's weights on frames of pixel spread ``spread``: our reconstruction and ẍ
    terms are the published ones over spread² (normalised frames), so the z̈ and L1 terms
    are scaled up by 1/spread² to keep the published balance; ``relative_z`` > 0: the z̈ term
    scale-free with that weight instead (the calibration's)."""
    up = 1.0 / max(spread, 1e-12) ** 2
    loss = LossWeights(lambda_pred_x=pred_x, lambda_pred_z=PRED_Z * up, lambda_l1=L1 * up)
    return dataclasses.replace(loss, lambda_pred_z=relative_z, relative_pred_z=True) \
        if relative_z else loss


def calibration(spread: float, epochs: int = 300, prune_every: int = 25) -> Phase:
    """The last phase: ``epochs`` at learning rate 1e-3 with the ẍ weight 100 times the
    main fit's and the z̈ term scale-free (weight 100: it straightens z instead of shrinking
    it), pruning every ``prune_every`` epochs through its first two thirds, the last third
    refining."""
    return Phase(epochs, "calibration", {
        "lr": 1e-3, "loss": recipe_loss(spread, pred_x=5e-2, relative_z=100.0),
        "refine_epochs": epochs - 2 * epochs // 3, "prune_every": prune_every})


def schedule_scale(data: SequenceData, batch_size: int = SCHEDULE["batch_size"]) -> float:
    """How many of the schedule's epochs make one of ``data``'s: the recipe counts updates,
    not passes, so that a video of few short trajectories trains as long as one of many
    long ones (:data:`REFERENCE_BATCHES` batches an epoch: the schedule's own video,
    100 training trajectories of 100 frames)."""
    train = data.split("train")
    batches = max(1, math.ceil(train.n * (train.steps + 1) / batch_size))
    return REFERENCE_BATCHES / batches


def scaled(epochs: int, factor: float) -> int:
    """``epochs`` of the schedule in epochs of data ``factor`` (:func:`schedule_scale`)."""
    return max(1, round(epochs * factor))


def components_for(data: SequenceData) -> int:
    """:data:`COMPONENTS`, or fewer where the frames have fewer values or the training split
    fewer frames (less one: their mean)."""
    train = data.split("train")
    frames = train.n * (train.steps + 1) - 1
    return max(1, min(COMPONENTS, int(np.prod(data.frame_shape)), frames))


def default_settings(recipe: bool) -> TrainConfig:
    """An estimator's training settings when it is given none: the recipe's schedule, or
    the defaults at learning rate 1e-3."""
    return recipe_settings() if recipe else TrainConfig(lr=1e-3)


def recipe_settings(base: TrainConfig | None = None) -> TrainConfig:
    """``base`` (seed, device and the rest; None: the defaults) with the recipe's schedule."""
    return dataclasses.replace(base or TrainConfig(), **SCHEDULE)


def apply_recipe(cfg: TrainConfig, data: SequenceData, loss: LossWeights | None,
                 components: int | None, phases: Any, restarts: Restarts | None,
                 in_folder: bool = False, scale: bool = False
                 ) -> tuple[TrainConfig, list[Phase], Restarts | None, dict[str, Any]]:
    """A fit's settings ``cfg`` (its model already the recipe's) on ``data`` with the recipe
    filled in where the caller left it (None): the loss weights, the principal components
    (with the mlp encoder and decoder, which take them),
    the phases (the calibration) and the restart rule; ``in_folder``: a run folder's fit,
    which trains the main fit alone (phases and restarts are in memory only); ``scale``
    (the caller gave no epochs): the schedule's epochs, pruning interval and refinement, and
    the calibration's, counted in updates (:func:`schedule_scale`). The last of the four
    returned are ``fit_in_memory``'s hooks: what each start does before its main fit (the
    encoder started at the frames' geodesic coordinates,
    :func:`~latent_sindy.training.manifold_start.begin_session`) and after its phases (the
    law chosen again on held-out derivatives,
    :func:`~latent_sindy.training.reselect.reselect_session`); none in a run folder."""
    spread = pixel_spread(data)
    factor = schedule_scale(data, cfg.batch_size) if scale else 1.0
    if scale:
        cfg = dataclasses.replace(cfg, epochs=scaled(cfg.epochs, factor),
                                  prune_every=scaled(cfg.prune_every, factor),
                                  refine_epochs=scaled(cfg.refine_epochs, factor))
    model = cfg.model
    mlp = (model.observation.encoder_kind, model.observation.decoder_kind) == ("mlp", "mlp")
    k = (components_for(data) if mlp else 0) if components is None else components
    model = dataclasses.replace(model, observation=dataclasses.replace(model.observation,
                                                                       pca_components=k))
    cfg = dataclasses.replace(cfg, model=model, loss=loss or recipe_loss(spread))
    if in_folder:
        return cfg, list(phases or ()), restarts, {}
    calibrate = calibration(spread, scaled(300, factor), scaled(25, factor))
    return (cfg, [calibrate] if phases is None else list(phases),
            RESTARTS if restarts is None else restarts,
            {"begin": begin_session, "finish": reselect_session})


def recipe_epochs(settings: dict[str, Any]) -> dict[str, Any]:
    """A fit's ``settings`` with the refinement cut to a fifth of other ``epochs`` given
    without one (the schedule's 50 of 250)."""
    if "epochs" in settings and "refine_epochs" not in settings:
        refine = min(SCHEDULE["refine_epochs"], int(settings["epochs"]) // 5)
        return {**settings, "refine_epochs": refine}
    return settings


def unit_of(time_unit: float | str | None, recipe: bool) -> float | None:
    """The continuous-time model's ``time_unit`` of an estimator's argument: "data" (and
    None with the recipe) chooses it from the data (None), a number is itself, else 1."""
    if time_unit == "data" or (time_unit is None and recipe):
        return None
    return 1.0 if time_unit is None else float(time_unit)
