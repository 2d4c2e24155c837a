"""The DeepMind Control study of ``latent-sindy reproduce --world dmc``: PlaNet's model-based
loop from pixels (seed episodes of random actions, then fit, plan with MPPI against the
learned reward, collect, refit warm-started) with three latent dynamics side by side, SINDy,
linear (E2C-like) and MLP, on the same seed episodes, planner and seeds; the return against
environment steps per model, beside the published lines at 100k steps (CURL's table).

    latent-sindy reproduce --world dmc --scale tiny --out /tmp/dmc
    latent-sindy reproduce --world dmc --world-config task=cartpole-swingup --scale demo \\
        --out results/dmc

Each (seed, model) loop is its own resumable folder, ``OUT/seed<S>/<model>/`` (data.h5,
log.json, the last model): a re-run reuses finished iterations and seeds. The study's
settings are in ``OUT/dmc_study.json``; a folder of other settings is refused.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from latent_sindy.atomic import write_atomic
from latent_sindy.configs import to_json
from latent_sindy.errors import UserError
from latent_sindy.worlds.dmc.config import DmcConfig

__all__ = ["MODELS", "SCALES", "DmcScale", "run_dmc_study", "run_loop", "study_scale"]

Say = Callable[[str], None]

#: The dynamics compared, in the report's order.
MODELS = ("sindy", "linear", "mlp")


@dataclass(frozen=True)
class DmcScale:
    """One ``--scale`` of the study: the loop, the models and the planner."""

    about: str
    seeds: tuple[int, ...]
    size: int
    """Image side (unless --world-config gives size)."""
    frames: int
    """Frames stacked (unless --world-config gives frames)."""
    seed_episodes: int
    iterations: int
    episode_steps: int
    """Actions an episode (× the action repeat: environment steps)."""
    epochs: int
    """Epochs of the first fit, from scratch."""
    warm_updates: int
    """Updates of every later refit, continuing the last model."""
    window: int
    latent_dim: int
    encoder: str
    samples: int
    horizon: int
    reward_head: int = 64
    batch_size: int = 32
    """Windows per mini-batch of every fit and refit (fixed: a refit's cost does not grow
    with the data)."""
    prune_rate: float = 0.3
    """Share of SINDy's active terms each warm refit prunes first (the smallest shares)."""
    prune_to: int = 48
    """Active SINDy terms below which the refits stop pruning by share."""
    lambda_: float = 0.1
    """MPPI's temperature on the horizon's summed reward (0.1: from the state at H 12, 0.1
    planned the cartpole to 814 where 1 gave about 700; the read scales plan over H 20 at 1,
    where 0.1 made every command its one best sample, the held pole's control noise;
    RESULTS.md)."""
    foreground_weight: float = 10.0
    """Extra weight of the moving pixels in the image terms (the cartpole's pole is a line of
    about one pixel at 32x32; with 10 the latent held more of the state and planned better,
    RESULTS.md)."""
    eval_episodes: int = 2
    """Test episodes after each fit, without exploration noise, kept out of the data."""
    episodes_per_iteration: int = 1
    """Planned episodes between two fits."""
    latent: str = "learned"
    """"learned": an autoencoder's latent, trained; "read": the cart-pole's pose read from the
    frames by image moments (:class:`~latent_sindy.worlds.dmc.reader.ColourPoseReader`),
    nothing learned but the dynamics and the reward head, each fit from scratch (SINDy in
    the windowed form over ``window`` steps, order ``order``, STLSQ's ``min_share``)."""
    order: int = 3
    min_share: float = 0.03
    support: float = 10.0
    """The read latent's planner gives up this much reward a step for each standardised unit
    a predicted latent lies outside the training latents in view (``ReadLatentConfig``);
    with it a horizon of 20 planned better than 12 (RESULTS.md)."""


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
        lambda_=1.0),
    "read-demo": DmcScale(
        "the pose read by image moments, one seed: 64x64, 2 frames, 30 seed episodes, then 3 "
        "fits each followed by 10 planned episodes of 125 actions (60k environment steps); "
        "SINDy order 3 fitted over windows of 5 steps (STLSQ min_share 0.03, trimmed), "
        "linear and MLP on the same latent; MPPI K 1000 H 20 λ 1, kept to the latents "
        "seen in training; 4 test episodes a fit",
        (0,), 64, 2, 30, 3, 125, 1, 0, 5, 6, "none", 1000, 20, eval_episodes=4,
        episodes_per_iteration=10, latent="read", lambda_=1.0),
    "read-benchmark": DmcScale(
        "the pose read by image moments at the 100k-step benchmark: as read-demo with 7 fits "
        "(30 random and 70 planned episodes, 100k environment steps), 5 test episodes a fit; "
        "seeds 0..4; hours on a CPU",
        (0, 1, 2, 3, 4), 64, 2, 30, 7, 125, 1, 0, 5, 6, "none", 1000, 20, eval_episodes=5,
        episodes_per_iteration=10, latent="read", lambda_=1.0),
}

#: Published returns at 100k environment steps on cartpole-swingup (mean, std over seeds):
#: CURL (Laskin et al. 2020), Table 1, and DrQ (Kostrikov et al. 2021) for DrQ.
REFERENCE = {"PlaNet": (297, 39), "Dreamer": (326, 27), "SAC+AE": (311, 11),
             "pixel SAC": (419, 40), "CURL": (582, 146), "DrQ": (759, 92),
             "SAC from states": (835, 22)}
REFERENCE_TASK, REFERENCE_STEPS = "cartpole-swingup", 100_000


def study_scale(scale: str, seeds: tuple[int, ...] | None) -> DmcScale:
    if scale not in SCALES:
        raise UserError(f"--scale {scale}: the dmc world's scales are {', '.join(SCALES)}")
    s = SCALES[scale]
    return dataclasses.replace(s, seeds=tuple(seeds)) if seeds else s


def _world_config(config: DmcConfig, s: DmcScale) -> DmcConfig:
    """The world's settings with the scale's image size and frames where the world keeps
    the defaults (a --world-config size or frames wins)."""
    default = DmcConfig(task=config.task)
    size = s.size if config.size == default.size else config.size
    frames = s.frames if config.frames == default.frames else config.frames
    return dataclasses.replace(config, size=size, frames=frames)


class _Say:
    """The loop's progress as lines for ``say``."""

    def __init__(self, say: Say, name: str) -> None:
        self.say, self.name = say, name

    def start(self, total: int, initial: int) -> None:
        if initial:
            self.say(f"{self.name}: {initial} of {total} iterations done before, reused")

    def update(self, iteration: int, metrics: dict[str, Any]) -> None:
        active = metrics.get("sindy/active")
        fit = metrics.get("fit_seconds")
        test = metrics.get("evaluation")
        self.say(f"{self.name}: iteration {iteration}, return {metrics['return']:.1f} at "
                 f"{metrics['env_steps']:.0f} environment steps"
                 + ("" if test is None else f", {test:.1f} without exploration noise")
                 + ("" if fit is None else f", fit {fit:.1f} s")
                 + ("" if active is None else f", {active:.0f} active terms"))

    def note(self, text: str) -> None:
        self.say(f"{self.name}: {text}")

    def close(self) -> None: ...


def _check_folder(out: Path, settings: dict[str, Any]) -> None:
    path = out / "dmc_study.json"
    if path.is_file():
        try:
            was = json.loads(path.read_text())
        except (OSError, ValueError) as e:
            raise UserError(f"{path} is damaged ({e}): delete {out} to start again") from e
        if was != settings:
            changed = sorted(k for k in set(was) | set(settings) if was.get(k) != settings.get(k))
            raise UserError(f"{out} holds a dmc study of other settings ({', '.join(changed)}): "
                            "use its settings (the seeds may change), or another --out")
    else:
        out.mkdir(parents=True, exist_ok=True)
        write_atomic(path, lambda f: f.write(json.dumps(settings, indent=1)), binary=False)


def run_dmc_study(config: DmcConfig, scale: str, out: Path, seeds: tuple[int, ...] | None,
                  device: str, threads: int, say: Say, workers: int = 1) -> dict[str, Any]:
    """Every (seed, model) loop of the scale in ``out`` (finished ones reused), ``workers``
    loops at a time (1: one after another in this process; more: in worker processes that
    end with this one, each loop's numbers the same as in this process): the study's
    settings and, per model and seed, the log of its loop and its wall time."""
    from latent_sindy.executors import ExecutorOptions, make_executor
    from latent_sindy.progress import say_stderr
    from latent_sindy.training.config import resolve_device

    if workers < 1:
        raise UserError(f"--workers {workers}: use 1 or more (loops run at once)")
    s = study_scale(scale, seeds)
    world = _world_config(config, s)
    on = resolve_device(device)
    loop = {k: v for k, v in dataclasses.asdict(s).items() if k not in ("about", "seeds")}
    settings = {"scale": scale, "world": to_json(world), "loop": loop}
    _check_folder(out, settings)
    jobs = [(seed, kind) for seed in s.seeds for kind in MODELS]
    workers = min(workers, len(jobs))
    say(f"dmc {world.task}, {scale} scale: {world.size}x{world.size}, {world.frames} "
        f"frame(s), repeat {world.action_repeat}; models {', '.join(MODELS)}; seeds "
        f"{', '.join(map(str, s.seeds))}; device {on}; {workers} loop(s) at a time")
    runs: dict[str, dict[int, dict[str, Any]]] = {m: {} for m in MODELS}
    ex = make_executor("local", ExecutorOptions(workers=workers))
    # each job its own wall time; a worker process says its lines on its stderr
    tell = say if ex.slots == 1 else say_stderr
    order = reversed(jobs) if ex.slots == 1 else jobs  # (one worker runs the last first)
    pending = {ex.submit(run_loop, world, s, seed, kind, out, str(on), threads, tell):
               (seed, kind) for seed, kind in order}
    try:
        while pending:
            for fut in ex.wait_one(pending):
                seed, kind = pending.pop(fut)
                runs[kind][seed] = fut.result()
    except BaseException:  # a loop failed or we were stopped: no other loop starts, and
        ex.shutdown(wait=False, cancel_futures=True)  # the workers end with this process
        raise
    ex.shutdown()
    return {"settings": settings, "seeds": list(s.seeds),
            "runs": {m: dict(sorted(runs[m].items())) for m in MODELS},
            "reference": {k: list(v) for k, v in REFERENCE.items()},
            "reference_task": REFERENCE_TASK, "reference_steps": REFERENCE_STEPS,
            "interval": "mean ± t(0.975, n-1)·sd/√n over seeds"}


def run_loop(world_config: DmcConfig, s: DmcScale, seed: int, kind: str, out: Path,
             device: str, threads: int, say: Say) -> dict[str, Any]:
    """One (seed, model) loop of the study in ``out/seed<S>/<kind>`` (resumed where it
    stopped): its log and wall time (:func:`_wall`) and this call's seconds."""
    import torch

    from latent_sindy import LatentSINDy
    from latent_sindy.control import ModelBasedConfig, MPPIConfig, compare_models
    from latent_sindy.models import DYNAMICS_KINDS, AutoencoderConfig, LossWeights, ModelConfig
    from latent_sindy.worlds.dmc.world import DmcWorld

    t0 = time.perf_counter()
    torch.set_num_threads(threads)
    world = DmcWorld(world_config)
    if s.latent == "read":
        from latent_sindy.control.read_latent import ReadLatent, ReadLatentConfig
        from latent_sindy.worlds.dmc.reader import ColourPoseReader

        fits = ReadLatentConfig(dynamics=kind, order=s.order, window=s.window,
                                min_share=s.min_share, reward_width=s.reward_head,
                                reader_episodes=s.seed_episodes,  # (the random ones)
                                support=s.support)

        def maker(iteration: int) -> Any:
            return ReadLatent(ColourPoseReader(world_config.size), fits,
                              seed=seed * 1000 + iteration)
    else:
        model = ModelConfig(dynamics=DYNAMICS_KINDS[kind](), reward_head=s.reward_head,
                            observation=AutoencoderConfig(latent_dim=s.latent_dim,
                                                          encoder_kind=s.encoder,
                                                          decoder_kind=s.encoder))
        loss = LossWeights(foreground_weight=s.foreground_weight)

        def maker(iteration: int) -> Any:
            return LatentSINDy(model=model, seed=seed * 1000 + iteration, device=device,
                               loss=loss)
    cfg = ModelBasedConfig(
        seed_episodes=s.seed_episodes, iterations=s.iterations,
        episodes_per_iteration=s.episodes_per_iteration,
        episode_steps=s.episode_steps, steps_per_action=world_config.action_repeat,
        warm_updates=s.warm_updates, seed=seed, batch_size=s.batch_size,
        prune_rate=s.prune_rate, prune_to=s.prune_to, eval_episodes=s.eval_episodes,
        mppi=MPPIConfig(samples=s.samples, horizon=s.horizon, sigma=0.3,
                        lambda_=s.lambda_, shift="repeat"))
    result = compare_models(world, {kind: maker}, cfg, out=out / f"seed{seed}",
                            progress=lambda name: _Say(say, f"seed {seed} {name}"),
                            fit_settings={"epochs": s.epochs, "window": s.window})[kind]
    return {"log": result.log, "wall_s": _wall(result.log),
            "this_call_s": time.perf_counter() - t0}


def _wall(log: dict[str, Any]) -> float:
    """A loop's time from its log (so a resumed loop counts its earlier calls): its
    episodes' collection and planning, its fits and its test episodes."""
    return (sum(e["seconds"] for e in log["episodes"])
            + sum(it["fit_seconds"] + (it.get("eval_seconds") or 0.0)
                  for it in log["iterations"]))


def mean_interval(values: list[float]) -> tuple[float, float | None, float | None]:
    """Mean, and the half-width of its 95% t-interval and the sd over seeds (None for one)."""
    n = len(values)
    mean = sum(values) / n
    if n < 2:
        return mean, None, None
    sd = math.sqrt(sum((v - mean) ** 2 for v in values) / (n - 1))
    return mean, _T975.get(n - 1, 1.96 + 2.5 / (n - 1)) * sd / math.sqrt(n), sd


#: Student's t at 0.975 by degrees of freedom (beyond 10: 1.96 + 2.5/df, within 0.002).
_T975 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306,
         9: 2.262, 10: 2.228}
