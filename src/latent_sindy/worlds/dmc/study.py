"""The DeepMind Control study of ``latent-sindy reproduce --world dmc``: PlaNet's model-based
loop from pixels (seed episodes of random actions, then fit, plan with MPPI against the
learned reward, collect, refit warm-started) with three latent dynamics side by side, SINDy,
linear (E2C-like) and MLP, on the same seed episodes, planner and seeds; the return against
environment steps per model, beside the published lines at 100k steps (CURL's table).
:func:`dmc_study` is what the world's ``reproduce`` hook returns: the runs as a
:class:`~latent_sindy.world_study.WorldStudy`, made by the generic model-based report
(:mod:`latent_sindy.study.model_based_report`: tables of return against environment steps
per model with intervals over seeds, costs, active terms; the last SINDy equations; a figure)
with the published reference rows of cartpole-swingup.

    latent-sindy reproduce --world dmc --scale tiny --out /tmp/dmc
    latent-sindy reproduce --world dmc --world-config task=cartpole-swingup --scale demo \\
        --out results/dmc

Each (seed, model) loop is its own resumable folder, ``OUT/seed<S>/<model>/`` (data.h5,
log.json, the last model): a re-run reuses finished iterations and seeds. The study's
settings are in ``OUT/dmc_study.json``; a folder of other settings is refused.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Collection
from functools import partial
from pathlib import Path
from typing import Any

from latent_sindy.study import model_based as study
from latent_sindy.study.model_based import (
    MODELS,
    LoopScale,
    mean_interval,
    pick_scale,
    sized_config,
)
from latent_sindy.study.model_based_report import Reference, model_based_study
from latent_sindy.world_study import WorldStudy
from latent_sindy.worlds.dmc.config import DmcConfig

__all__ = ["MODELS", "SCALES", "DmcScale", "dmc_study", "mean_interval", "run_dmc_study",
           "run_seed", "study_scale"]

Say = Callable[[str], None]

#: One ``--scale`` of the study: the generic model-based study's scale
#: (:class:`~latent_sindy.study.model_based.LoopScale`).
DmcScale = LoopScale


#: How the larger scales' fits batch and prune, for --help.
_FITS = ("; batches of 32 windows, each warm refit first pruning SINDy's smallest 30% of "
         "terms, down to 48; MPPI λ 0.1, moving pixels weighted 11x, 2 test episodes a fit "
         "(5 at the benchmark scale)")

SCALES: dict[str, DmcScale] = {
    "tiny": DmcScale(
        "about a minute on 2 cores, for tests: 16x16 single frames, 2 seed episodes and 2 "
        "planned ones of 8 actions, 2 epochs then 4 updates a refit in batches of 8, MPPI K "
        "16 H 3; seed 0",
        (0,), 16, 1, 2, 2, 8, 2, 4, 2, 3, "mlp", 16, 3, 16, batch_size=8, eval_episodes=1),
    "small": DmcScale(
        "a few minutes a model on a CPU core: 32x32, 2 frames, 5 seed episodes and 6 planned "
        "ones of 125 actions, latent size 6 (SINDy's 252 terms), 15 epochs then 100 updates "
        "a refit, MPPI K 300 H 12; seed 0" + _FITS,
        (0,), 32, 2, 5, 6, 125, 15, 100, 4, 6, "conv", 300, 12),
    "demo": DmcScale(
        "a short measurable run: 32x32, 2 frames, 5 seed episodes and 5 planned ones of 125 "
        "actions (1000 environment steps each at the cartpole's repeat 8, 10k in all), 40 "
        "epochs then 100 updates a refit, MPPI K 300 H 12; seeds 0..2" + _FITS,
        (0, 1, 2), 32, 2, 5, 5, 125, 40, 100, 4, 6, "conv", 300, 12),
    "benchmark": DmcScale(
        "the 100k-step benchmark (PlaNet's and CURL's setting): 64x64, 2 frames, 5 seed "
        "episodes and 95 planned ones of 1000 environment steps (100k in all), 100 epochs then "
        "100 updates a refit, MPPI K 1000 H 12; seeds 0..4; days on a CPU, for a GPU" + _FITS,
        (0, 1, 2, 3, 4), 64, 2, 5, 95, 125, 100, 100, 4, 8, "conv", 1000, 12,
        eval_episodes=5),
    "read-tiny": DmcScale(
        "the read latent for tests, about a minute: 32x32, 2 frames, 3 seed episodes and 1 "
        "planned one of 20 actions, MPPI K 16 H 3; seed 0",
        (0,), 32, 2, 3, 1, 20, 1, 0, 5, 6, "none", 16, 3, eval_episodes=1, latent="read",
        select=False, lambda_=1.0),
    "read-demo": DmcScale(
        "the pose read by image moments, one seed: 64x64, 2 frames, 30 seed episodes, then 3 "
        "fits each followed by 10 planned episodes of 125 actions (60k environment steps); "
        "SINDy order 3 fitted over windows of 5 steps (STLSQ min_share 0.03, trimmed), "
        "linear and MLP on the same latent; MPPI K 1000 H 20 λ 1, kept to the latents "
        "seen in training; 4 test episodes a fit",
        (0,), 64, 2, 30, 3, 125, 1, 0, 5, 6, "none", 1000, 20, eval_episodes=4,
        episodes_per_iteration=10, latent="read", select=False, lambda_=1.0),
    "read-100k": DmcScale(
        "the pose read by image moments at the 100k-step benchmark: as read-demo with 7 fits "
        "(30 random and 70 planned episodes, 100k environment steps), 5 test episodes a fit; "
        "seeds 0..4; hours on a CPU",
        (0, 1, 2, 3, 4), 64, 2, 30, 7, 125, 1, 0, 5, 6, "none", 1000, 20, eval_episodes=5,
        episodes_per_iteration=10, latent="read", select=False, lambda_=1.0),
    "keypoints-demo": DmcScale(
        "as read-demo on a latent learned from the frames alone, no reader written for the "
        "world: 4 keypoints of what moves (transported features, 6000 updates on the seed "
        "episodes' frames); SINDy's fit checked at each fit on held-out episodes and "
        "replaced where its rollouts diverge",
        (0,), 64, 2, 30, 3, 125, 1, 0, 5, 4, "none", 1000, 20, eval_episodes=4,
        episodes_per_iteration=10, latent="keypoints", lambda_=1.0),
    "keypoints-100k": DmcScale(
        "as read-100k on the keypoints of keypoints-demo (learned from the frames alone): 7 "
        "fits, 100k environment steps; seeds 0..4; hours on a CPU",
        (0, 1, 2, 3, 4), 64, 2, 30, 7, 125, 1, 0, 5, 4, "none", 1000, 20, eval_episodes=5,
        episodes_per_iteration=10, latent="keypoints", lambda_=1.0),
}

# The same loops on 8 keypoints (K, the reader's one structural setting): on a 100k loop's
# random episodes, 8 keypoints held the pole's side where 4 did not (RESULTS.md)
for _name in ("keypoints-demo", "keypoints-100k"):
    SCALES[_name.replace("keypoints", "keypoints8")] = dataclasses.replace(
        SCALES[_name], about=f"as {_name} on 8 keypoints instead of 4", latent_dim=8)
del _name
SCALES["keypoints8-sparse-100k"] = dataclasses.replace(
    SCALES["keypoints8-100k"], sparsest_within=2.0,
    about="as keypoints8-100k with SINDy's fit, at every fit, the sparsest of its 18 within "
          "2 of the best held-out error (readable equations for some prediction)")

#: Published returns at 100k environment steps on cartpole-swingup (mean, std over seeds):
#: CURL (Laskin et al. 2020), Table 1, and DrQ (Kostrikov et al. 2021) for DrQ.
REFERENCE = {"PlaNet": (297, 39), "Dreamer": (326, 27), "SAC+AE": (311, 11),
             "pixel SAC": (419, 40), "CURL": (582, 146), "DrQ": (759, 92),
             "SAC from states": (835, 22)}
REFERENCE_TASK, REFERENCE_STEPS = "cartpole-swingup", 100_000


def study_scale(scale: str, seeds: tuple[int, ...] | None) -> DmcScale:
    return pick_scale(SCALES, scale, seeds, "dmc")


def run_dmc_study(config: DmcConfig, scale: str, out: Path, seeds: tuple[int, ...] | None,
                  device: str, threads: int, say: Say, workers: int = 1,
                  given: Collection[str] | None = None) -> dict[str, Any]:
    """Every (seed, model) loop of the scale in ``out`` (finished ones reused), ``workers``
    loops at a time (1: one after another in this process; more: in worker processes that
    end with this one, each loop's numbers the same as in this process): the study's
    settings and, per model and seed, the log of its loop and its wall time
    (:func:`latent_sindy.study.model_based.run_loops`). ``given``: the fields of ``config``
    a user set (:func:`~latent_sindy.study.model_based.sized_config`)."""
    from latent_sindy.worlds.dmc.world import DmcWorld

    s = study_scale(scale, seeds)
    world = sized_config(config, DmcConfig(task=config.task), s, given)
    header = (f"dmc {world.task}, {scale} scale: {world.size}x{world.size}, {world.frames} "
              f"frame(s), repeat {world.action_repeat}")
    result = study.run_loops(DmcWorld(world), s, scale, out, device, threads, say, workers,
                             name="dmc", header=header, steps_per_action=world.action_repeat,
                             reader=_reader(world, s, out))
    return {**result, "reference": {k: list(v) for k, v in REFERENCE.items()},
            "reference_task": REFERENCE_TASK, "reference_steps": REFERENCE_STEPS}


#: The published lines with where each was published.
_REFERENCE = Reference(REFERENCE_TASK, REFERENCE_STEPS, REFERENCE,
                       {name: "DrQ's paper, Table 1" if name == "DrQ" else
                        "CURL's paper, Table 1" for name in REFERENCE})


def dmc_study(config: DmcConfig, scale: str, out: Path, seeds: tuple[int, ...] | None,
              device: str, threads: int, say: Say, workers: int = 1,
              given: Collection[str] | None = None) -> WorldStudy:
    """The study at ``scale`` in ``out`` (finished loops reused, ``workers`` loops at a
    time), as a WorldStudy; ``given``: the fields of ``config`` a user set."""
    result = run_dmc_study(config, scale, out, seeds, device, threads, say, workers, given)
    task = result["settings"]["world"]["task"]
    return model_based_study(
        result, scale, out, f"DeepMind Control from pixels: {task}, model-based, SINDy / "
        "linear / MLP", task, _REFERENCE)


def _reader(world_config: DmcConfig, s: DmcScale, out: Path) -> Callable[[], Any] | None:
    """What makes the scale's reader: the frames' geodesic coordinates or keypoints (both
    learned; the keypoints' fit kept in the study's folder ``out``), or the cart-pole's pose
    by image moments (a hand-made reader)."""
    from latent_sindy.worlds.dmc.reader import ColourPoseReader

    return study.scale_reader(s, world_config.frames,
                              partial(ColourPoseReader, world_config.size), out)


def run_seed(world_config: DmcConfig, s: DmcScale, seed: int, kind: str, out: Path,
             device: str, threads: int, say: Say) -> dict[str, Any]:
    """One (seed, model) loop of the study in ``out/seed<S>/<kind>`` (resumed where it
    stopped): its log and wall time and this call's seconds
    (:func:`latent_sindy.study.model_based.run_seed`)."""
    from latent_sindy.worlds.dmc.world import DmcWorld

    return study.run_seed(DmcWorld(world_config), s, seed, kind, out, device, threads, say,
                          world_config.action_repeat, _reader(world_config, s, out))
