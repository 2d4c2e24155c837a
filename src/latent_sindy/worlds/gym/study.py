"""The gym world's study, ``latent-sindy reproduce --world gym``: the model-based study of
:mod:`latent_sindy.study.model_based` (PlaNet's loop, SINDy, linear and MLP latent dynamics on
the same seed episodes, planner and seeds) against the environment's own reward, with the
learned-latent settings of the dmc world's scales.

    latent-sindy reproduce --world gym --world-config id=Pendulum-v1 --scale small --out /tmp/p

Each (seed, model) loop is its own resumable folder, ``OUT/seed<S>/<model>/``; the study's
settings are in ``OUT/gym_study.json`` and a folder of other settings is refused.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Collection
from pathlib import Path

from latent_sindy.study.model_based import (
    LoopScale,
    pick_scale,
    run_loops,
    scale_reader,
    sized_config,
)
from latent_sindy.study.model_based_report import model_based_study
from latent_sindy.world_study import WorldStudy
from latent_sindy.worlds.gym.config import GymConfig

__all__ = ["SCALES", "gym_study", "study_scale"]

Say = Callable[[str], None]

SCALES: dict[str, LoopScale] = {
    "tiny": LoopScale(
        "seconds, for tests: 16x16 single frames, 2 seed episodes and 2 planned ones of 8 "
        "actions, 2 epochs then 4 updates a refit in batches of 8, MPPI K 16 H 3; seed 0",
        (0,), 16, 1, 2, 2, 8, 2, 4, 2, 3, "mlp", 16, 3, 16, batch_size=8, eval_episodes=1),
    "small": LoopScale(
        "a few minutes a model on a CPU core, sized for Pendulum-v1's episodes of 200 "
        "steps: 64x64, 2 frames, 5 seed episodes and 3 planned ones of 200 actions, latent "
        "size 6, conv encoder, 15 epochs then 100 updates a refit in batches of 32 (SINDy "
        "pruned by 30% a refit, down to 48 terms), MPPI K 300 H 12 λ 0.1, moving pixels "
        "weighted 11x, 2 test episodes a fit; seed 0",
        (0,), 64, 2, 5, 3, 200, 15, 100, 4, 6, "conv", 300, 12),
    "geodesic-tiny": LoopScale(
        "seconds, for tests: the geodesic latent at 16x16, 2 frames, 3 seed episodes and 1 "
        "planned one of 20 actions, MPPI K 32 H 3; seed 0",
        (0,), 16, 2, 3, 1, 20, 1, 0, 5, 2, "none", 32, 3, eval_episodes=1,
        latent="geodesic", lambda_=1.0),
    "geodesic": LoopScale(
        "the latent learned from the frames alone (2 geodesic coordinates of the newest "
        "frame, read as an angle where they wind round, and their rates from the frame "
        "before; no world knowledge), sized for Pendulum-v1: 64x64, 2 frames, 20 random "
        "seed episodes of 200 actions each held 10 steps, then 3 fits each followed by 5 "
        "planned episodes; SINDy order 3 over windows of 5 steps (STLSQ min_share 0.03, "
        "trimmed; checked on held-out episodes, replaced where its rollouts diverge), linear "
        "and MLP on the same latent; MPPI K 1000 H 20 λ 1 σ 1; 10 test "
        "episodes a fit; seed 0",
        (0,), 64, 2, 20, 3, 200, 1, 0, 5, 2, "none", 1000, 20, eval_episodes=10,
        episodes_per_iteration=5, latent="geodesic", lambda_=1.0, sigma=1.0, seed_hold=10),
}
SCALES["keypoints"] = dataclasses.replace(
    SCALES["geodesic"], latent="keypoints", latent_dim=4,
    about="as geodesic, on a latent of 4 keypoints of what moves, learned from the random "
    "episodes' frames alone by transporting one frame's features into another (6000 "
    "updates; no world knowledge): their principal coordinates, read as an angle where two "
    "wind round, and their rates from the frame before; seed 0")


def study_scale(scale: str, seeds: tuple[int, ...] | None) -> LoopScale:
    return pick_scale(SCALES, scale, seeds, "gym")


def gym_study(config: GymConfig, scale: str, out: Path, seeds: tuple[int, ...] | None,
              device: str, threads: int, say: Say, workers: int = 1,
              given: Collection[str] | None = None) -> WorldStudy:
    """The study at ``scale`` in ``out`` (finished loops reused, ``workers`` loops at a
    time), as a WorldStudy; the environment is made first (nothing is written for an id
    gymnasium cannot make or a renderer that is missing); ``given``: the fields of ``config``
    a user set (:func:`~latent_sindy.study.model_based.sized_config`)."""
    from latent_sindy.worlds.gym.world import GymWorld, describe

    s = study_scale(scale, seeds)
    world = sized_config(config, GymConfig(id=config.id), s, given)
    describe(world)
    header = (f"gym {world.id}, {scale} scale: {world.size}x{world.size}, {world.frames} "
              f"frame(s), repeat {world.action_repeat}")
    result = run_loops(GymWorld(world), s, scale, out, device, threads, say, workers,
                       name="gym", header=header, steps_per_action=world.action_repeat,
                       reader=scale_reader(s, world.frames, out=out))
    return model_based_study(result, scale, out, f"Gymnasium from pixels: {world.id}, "
                             "model-based, SINDy / linear / MLP", world.id)
