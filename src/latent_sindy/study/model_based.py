"""The model-based study of any world whose ``env.step`` gives a reward: PlaNet's loop from
pixels (seed episodes of random actions, then fit, plan with MPPI against the learned reward,
collect, refit warm-started) with three latent dynamics side by side, SINDy, linear
(E2C-like) and MLP, on the same seed episodes, planner and seeds. It knows no world: a
world's study (the dmc and gym worlds') gives its world object, its scale and, for a latent
read from the frames rather than learned, its reader; :mod:`.model_based_report` makes the
report of what it returns.

    result = run_loops(world, SCALE, "tiny", Path("/tmp/s"), "cpu", 1, print, name="gym",
                       header="gym Pendulum-v1, tiny scale")

Each (seed, model) loop is its own resumable folder, ``OUT/seed<S>/<model>/`` (data.h5,
log.json, the last model): a re-run reuses finished iterations and seeds. The study's
settings are in ``OUT/<name>_study.json``; a folder of other settings is refused.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

from latent_sindy.atomic import write_atomic
from latent_sindy.configs import to_json
from latent_sindy.errors import UserError

__all__ = [
    "MODELS",
    "LoopScale",
    "loop_wall",
    "mean_interval",
    "pick_scale",
    "run_loops",
    "run_seed",
    "scale_reader",
    "sized_config",
    "study_latent",
]

Say = Callable[[str], None]

#: The dynamics compared, in the report's order.
MODELS = ("sindy", "linear", "mlp")


@dataclass(frozen=True)
class LoopScale:
    """One ``--scale`` of a model-based study: the loop, the models and the planner."""

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
    """The learned latent's size; a "geodesic" latent's coordinates (its latent is twice
    that, positions and rates, and the action held); a "keypoints" latent's keypoints."""
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
    sigma: float = 0.3
    """MPPI's exploration noise, in the action's units."""
    seed_hold: int = 1
    """Steps each random action of the seed episodes is held (``ModelBasedConfig``)."""
    foreground_weight: float = 10.0
    """Extra weight of the moving pixels in the image terms (the cartpole's pole is a line of
    about one pixel at 32x32; with 10 the latent held more of the state and planned better,
    RESULTS.md)."""
    eval_episodes: int = 2
    """Test episodes after each fit, without exploration noise, kept out of the data."""
    episodes_per_iteration: int = 1
    """Planned episodes between two fits."""
    latent: str = "learned"
    """"learned": an autoencoder's latent, trained with the dynamics; "read": a pose read
    from the frames by the world's hand-made reader (the dmc world's ``ColourPoseReader``);
    "geodesic": the frames' geodesic coordinates (``latent_dim`` of them), learned from the
    random episodes' frames alone (:class:`~latent_sindy.models.geodesic_reader.GeodesicReader`,
    no world knowledge); "keypoints": keypoints of what moves (``latent_dim`` of them),
    learned from the random episodes' frames alone by transporting one frame's features into
    another (:class:`~latent_sindy.models.keypoint_reader.KeypointReader`, no world
    knowledge). With "read", "geodesic" and "keypoints" the dynamics and the reward head are
    fitted on that latent from scratch at each fit (SINDy in the windowed form over
    ``window`` steps, order ``order``, STLSQ's ``min_share``)."""
    order: int = 3
    min_share: float = 0.03
    select: bool = True
    """With "read", "geodesic" and "keypoints": SINDy's fit checked on held-out episodes at
    each fit and replaced where its rollouts diverge (``ReadLatentConfig.select``); False:
    the fit above unchecked (the hand-made reader's scales, as they were measured)."""
    sparsest_within: float | None = None
    """With ``select``: at each fit, the sparsest SINDy fit within this factor of the best
    held-out error (``ReadLatentConfig.sparsest_within``); None: the checked fit."""
    support: float = 10.0
    """The read latent's planner gives up this much reward a step for each standardised unit
    a predicted latent lies outside the training latents in view (``ReadLatentConfig``);
    with it a horizon of 20 planned better than 12 (RESULTS.md)."""


class _Say:
    """The loop's progress as lines for ``say``."""

    def __init__(self, say: Say, name: str) -> None:
        self.say = say
        self.name = name

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


def pick_scale(scales: dict[str, Any], scale: str, seeds: tuple[int, ...] | None,
               world: str) -> Any:
    """The scale named ``scale`` of a world's ``scales`` (UserError naming ``world``'s
    scales otherwise), with ``seeds`` in place of its own where given."""
    if scale not in scales:
        raise UserError(f"--scale {scale}: the {world} world's scales are {', '.join(scales)}")
    s = scales[scale]
    return dataclasses.replace(s, seeds=tuple(seeds)) if seeds else s


def sized_config(config: Any, default: Any, s: LoopScale,
                 given: Any = None) -> Any:
    """A world's settings ``config`` (with ``size`` and ``frames`` fields) with the scale's
    image size and frames, except those ``given`` (the fields a --world-config set, whatever
    their value); ``given`` None (a Python caller's config): a size or frames other than
    ``default``'s wins."""
    if given is None:
        given = [k for k in ("size", "frames") if getattr(config, k) != getattr(default, k)]
    size = config.size if "size" in given else s.size
    frames = config.frames if "frames" in given else s.frames
    return dataclasses.replace(config, size=size, frames=frames)


def _check_folder(out: Path, settings: dict[str, Any], name: str) -> None:
    path = out / f"{name}_study.json"
    if path.is_file():
        try:
            was = json.loads(path.read_text())
        except (OSError, ValueError) as e:
            raise UserError(f"{path} is damaged ({e}): delete {out} to start again") from e
        if was != settings:
            changed = sorted(k for k in set(was) | set(settings) if was.get(k) != settings.get(k))
            raise UserError(f"{out} holds a {name} study of other settings "
                            f"({', '.join(changed)}): use its settings (the seeds may change), "
                            "or another --out")
    else:
        out.mkdir(parents=True, exist_ok=True)
        write_atomic(path, lambda f: f.write(json.dumps(settings, indent=1)), binary=False)


def run_loops(world: Any, s: LoopScale, scale: str, out: Path, device: str, threads: int,
              say: Say, workers: int = 1, *, name: str, header: str,
              steps_per_action: int = 1, reader: Callable[[], Any] | None = None
              ) -> dict[str, Any]:
    """Every (seed, model) loop of the scale ``s`` (named ``scale``) in ``world`` (a world
    object with its settings in ``config``, picklable: loops may run in worker processes) in
    ``out`` (finished ones reused), ``workers`` loops at a time (1: one after another in
    this process; more: in worker processes that end with this one, each loop's numbers the
    same as in this process): the study's settings and, per model and seed, the log of its
    loop and its wall time. ``name``: the world's, for the settings file and messages;
    ``header``: the first line said (the world, the scale, the images); ``reader``: makes
    the reader of a ``latent="read"``, ``"geodesic"`` or ``"keypoints"`` scale
    (:func:`scale_reader`)."""
    from latent_sindy.executors import ExecutorOptions, make_executor
    from latent_sindy.progress import say_stderr
    from latent_sindy.training.config import resolve_device

    if workers < 1:
        raise UserError(f"--workers {workers}: use 1 or more (loops run at once)")
    on = resolve_device(device)
    loop = {k: v for k, v in dataclasses.asdict(s).items() if k not in ("about", "seeds")}
    settings = {"scale": scale, "world": to_json(world.config), "loop": loop}
    _check_folder(out, settings, name)
    jobs = [(seed, kind) for seed in s.seeds for kind in MODELS]
    workers = min(workers, len(jobs))
    say(f"{header}; models {', '.join(MODELS)}; seeds {', '.join(map(str, s.seeds))}; "
        f"device {on}; {workers} loop(s) at a time")
    runs: dict[str, dict[int, dict[str, Any]]] = {m: {} for m in MODELS}
    ex = make_executor("local", ExecutorOptions(workers=workers))
    # each job its own wall time; a worker process says its lines on its stderr
    tell = say if ex.slots == 1 else say_stderr
    order = reversed(jobs) if ex.slots == 1 else jobs  # (one worker runs the last first)
    pending = {ex.submit(run_seed, world, s, seed, kind, out, str(on), threads, tell,
                         steps_per_action, reader): (seed, kind) for seed, kind in order}
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
            "interval": "mean ± t(0.975, n-1)·sd/√n over seeds"}


def scale_reader(s: LoopScale, frames: int, hand_made: Callable[[], Any] | None = None,
                 out: Path | None = None) -> Callable[[], Any] | None:
    """What makes the reader of scale ``s`` on observations of ``frames`` stacked frames: the
    geodesic coordinates (``s.latent_dim`` of them) for a "geodesic" scale, keypoints
    (``s.latent_dim`` of them) for a "keypoints" one, the world's ``hand_made`` reader for
    a "read" one, None for a learned latent. A keypoint reader's fit is kept in the study's
    folder ``out`` (``readers/``): the seed's loops of every model share it, in any process,
    and a stopped study resumes it."""
    if s.latent == "geodesic":
        from latent_sindy.models.geodesic_reader import GeodesicReader

        return partial(GeodesicReader, frames=frames, dim=s.latent_dim)
    if s.latent == "keypoints":
        from latent_sindy.models.keypoint_reader import KeypointReader

        return partial(KeypointReader, frames=frames, parts=s.latent_dim,
                       store=None if out is None else out / "readers")
    return hand_made if s.latent == "read" else None


def study_latent(out: Path, seed: int) -> tuple[dict[str, Any], LoopScale, Callable[[], Any],
                                                 Any]:
    """What a model-based study in ``out`` (finished or running) learned its latent from, at
    ``seed``: its settings (``*_study.json``), its scale, its reader made as the study made it
    (a keypoint fit loads from ``out/readers``) and the seed's episodes (the first model's
    ``data.h5``). UserError where ``out`` is no study, its latent is a world's own reader, or
    the seed has no episodes there."""
    from latent_sindy.data import read_sequences

    found = sorted(out.glob("*_study.json"))
    if len(found) != 1:
        raise UserError(f"{out}: expected one *_study.json (a model-based study's folder), "
                        f"found {len(found)}")
    settings = json.loads(found[0].read_text())
    loop = settings["loop"]
    s = LoopScale("", (seed,), **loop)
    make = scale_reader(s, loop["frames"], None, out)
    if make is None:
        raise UserError(f"{out}: its latent is {loop['latent']!r}; a geodesic or keypoints "
                        "scale's latent is learned from the frames, the others are not")
    data = next((read_sequences(p) for kind in MODELS
                 if (p := out / f"seed{seed}" / kind / "data.h5").is_file()), None)
    if data is None:
        raise UserError(f"{out}: no episodes of seed {seed} there (seed{seed}/<model>/data.h5)")
    return settings, s, make, data


def run_seed(world: Any, s: LoopScale, seed: int, kind: str, out: Path, device: str,
             threads: int, say: Say, steps_per_action: int = 1,
             reader: Callable[[], Any] | None = None) -> dict[str, Any]:
    """One (seed, model) loop of the study in ``out/seed<S>/<kind>`` (resumed where it
    stopped): its log and wall time (:func:`loop_wall`) and this call's seconds."""
    import torch

    from latent_sindy import LatentSINDy
    from latent_sindy.control import MPPIConfig
    from latent_sindy.model_based import ModelBasedConfig, compare_models
    from latent_sindy.models import DYNAMICS_KINDS, AutoencoderConfig, LossWeights, ModelConfig

    t0 = time.perf_counter()
    torch.set_num_threads(threads)
    if s.latent in ("read", "geodesic", "keypoints"):
        from latent_sindy.read_latent import ReadLatent, ReadLatentConfig

        if reader is None:
            raise UserError(f"a scale of a {s.latent} latent needs its reader of the frames "
                            "from the world's study")
        fits = ReadLatentConfig(dynamics=kind, order=s.order, window=s.window,
                                min_share=s.min_share, select=s.select,
                                sparsest_within=s.sparsest_within,
                                horizon=s.horizon, reward_width=s.reward_head,
                                reader_episodes=s.seed_episodes,  # (the random ones)
                                support=s.support)

        def maker(iteration: int) -> Any:
            return ReadLatent(reader(), fits, seed=seed * 1000 + iteration)
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
        seed_episodes=s.seed_episodes, seed_hold=s.seed_hold, iterations=s.iterations,
        episodes_per_iteration=s.episodes_per_iteration,
        episode_steps=s.episode_steps, steps_per_action=steps_per_action,
        warm_updates=s.warm_updates, seed=seed, batch_size=s.batch_size,
        prune_rate=s.prune_rate, prune_to=s.prune_to, eval_episodes=s.eval_episodes,
        mppi=MPPIConfig(samples=s.samples, horizon=s.horizon, sigma=s.sigma,
                        lambda_=s.lambda_, shift="repeat"))
    result = compare_models(world, {kind: maker}, cfg, out=out / f"seed{seed}",
                            progress=lambda name: _Say(say, f"seed {seed} {name}"),
                            fit_settings={"epochs": s.epochs, "window": s.window})[kind]
    return {"log": result.log, "wall_s": loop_wall(result.log),
            "this_call_s": time.perf_counter() - t0}


def loop_wall(log: dict[str, Any]) -> float:
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
