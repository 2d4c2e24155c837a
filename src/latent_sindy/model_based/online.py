"""Model-based reinforcement learning from pixels, PlaNet's loop: seed episodes of random
actions, then per iteration fit a latent model with a reward head on all the data so far,
run episodes planned by MPPI against the predicted reward (with exploration noise), and add
them to the data. Any world (:class:`~latent_sindy.control.world.World`) whose ``env.step``
returns a reward; any estimator with ``fit(data)`` and ``planner(mppi, seed=, objective=)``
(:class:`latent_sindy.LatentSINDy` with ``ModelConfig(reward_head=...)``).

    def make(iteration):
        return LatentSINDy(model=ModelConfig(reward_head=64, ...), seed=iteration)
    result = model_based(world, make, ModelBasedConfig(seed_episodes=5, iterations=10,
                                                       episode_steps=100), out="runs/mbrl")
    result.log["episodes"]     # per episode: iteration, kind, return, env_steps so far

Refits are warm-started by default (``warm_updates``, :mod:`.warm_start`): the first
iteration fits from scratch with the fit settings, each later one continues the last model
and optimiser for ``warm_updates`` mini-batch updates on windows drawn from all the data so
far, keeping the first fit's normaliser; ``warm_updates=0`` fits every iteration from
scratch. Every fit takes mini-batches of ``batch_size`` windows (32), not a size chosen
from the data, so a refit costs the same however much data there is; and a SINDy model is
pruned before each warm refit (``prune_rate`` of its active terms, down to ``prune_to``),
so its active terms fall across the refits, as the log's ``active_terms`` records.

With ``eval_episodes`` each iteration also plans that many test episodes without noise,
kept out of the data: their returns (the log's ``evaluation``) are what published tables
report.

With ``out`` the folder holds the data so far (``data.h5``), the log (``log.json``, the
settings, every episode's return and each iteration's times, equations and active terms)
and, when warm-started, the last iteration's model and optimiser (``model_<iteration>.pt``,
read back with ``torch.load(weights_only=True)``), all written after the seed episodes and
after every iteration, the log last; run again with the same settings (more iterations
allowed), it goes on after the last iteration written (a kill -9 loses the iteration in
progress only). Every draw is seeded from ``seed`` and the episode's number, and each fit
from ``make_estimator(iteration)``'s seed, so a resumed run gives an uninterrupted run's
returns.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from latent_sindy.atomic import write_atomic
from latent_sindy.configs import to_json
from latent_sindy.control.collect import collect_random
from latent_sindy.control.episodes import Observation, run_loop
from latent_sindy.control.mppi import MPPIConfig
from latent_sindy.control.world import World
from latent_sindy.data import SequenceData, concatenate, read_sequences, write_sequences
from latent_sindy.errors import UserError
from latent_sindy.model_based.warm_start import (
    WarmState,
    first_fit,
    load_state,
    save_state,
    warm_fit,
)
from latent_sindy.progress import Progress, Silent

__all__ = ["LOG_FORMAT", "ModelBasedConfig", "ModelBasedResult", "model_based"]

LOG_FORMAT = "latent-sindy-model-based"


@dataclass(frozen=True)
class ModelBasedConfig:
    """The loop's settings (PlaNet's where it has them: 5 seed episodes, one planned
    episode per iteration, exploration noise 0.3)."""

    seed_episodes: int = 5
    """Episodes of uniformly random actions before the first fit."""
    seed_hold: int = 1
    """Steps each random action of the seed episodes is held (1: a new one every step;
    independent draws mostly cancel, so a system stays near where it rests)."""
    iterations: int = 10
    """Fit-and-plan rounds after the seed episodes."""
    episodes_per_iteration: int = 1
    """Planned episodes collected after each fit."""
    episode_steps: int = 100
    """Actions an episode (every episode has this many: the data's T)."""
    explore: float = 0.3
    """Standard deviation of the Gaussian noise added to each planned action, as a share of
    the action box's half-width (the noisy action clamped into the box)."""
    validation_every: int = 5
    """Every this-many-th episode (the 5th, 10th, ...) goes to the validation split, which
    picks each fit's kept weights; the others train. 0: all train."""
    steps_per_action: int = 1
    """Environment steps an action counts for (a world's action repeat), for the log's
    ``env_steps``."""
    seed: int = 0
    """Seeds the tasks, the random actions, the exploration noise and the planner."""
    warm_updates: int = 100
    """Mini-batch updates of each refit after the first, continuing the last iteration's
    model and optimiser (PlaNet trains 100 updates an episode); 0: every iteration fits
    from scratch with the fit settings."""
    batch_size: int | None = 32
    """Windows per mini-batch of every fit and refit, fixed so that a refit's cost does not
    grow with the data (the fit settings' ``batch_size`` wins where they give one); None:
    chosen from the data, as a plain fit does."""
    prune_rate: float = 0.3
    """Share of a SINDy model's active terms each warm refit prunes before its updates (the
    smallest by the fit's ``--prune`` measure, after those below its ``--prune-below``); 0: refits
    prune only on the fit's own schedule."""
    prune_to: int = 48
    """Active SINDy terms below which the refits' pruning by share stops (``--prune-below`` may
    still remove terms)."""
    eval_episodes: int = 0
    """Episodes planned after each fit without exploration noise and not added to the data
    (the test episodes PlaNet and CURL report), from the same starts every iteration; their
    returns are the log's ``evaluation`` per iteration, beside ``fit_env_steps``, the
    environment steps of the data the fit saw."""
    mppi: MPPIConfig = field(default_factory=lambda: MPPIConfig(
        samples=300, horizon=12, sigma=0.3, lambda_=1.0, shift="repeat"))
    """The planner's settings (λ on the scale of a horizon's summed reward)."""

    def __post_init__(self) -> None:
        for name in ("seed_episodes", "seed_hold", "iterations", "episodes_per_iteration",
                     "episode_steps", "validation_every", "steps_per_action", "warm_updates",
                     "eval_episodes"):
            v = getattr(self, name)
            least = 1 if name in ("seed_episodes", "seed_hold", "episode_steps",
                                  "steps_per_action") else 0
            if isinstance(v, bool) or not isinstance(v, int) or v < least:
                raise UserError(f"model_based {name} {v!r}: use an integer >= {least}")
        if not (0 <= self.explore < float("inf")):
            raise UserError(f"model_based explore {self.explore!r}: use a number >= 0")
        b = self.batch_size
        if b is not None and (isinstance(b, bool) or not isinstance(b, int) or b < 1):
            raise UserError(f"model_based batch_size {b!r}: use an integer >= 1 (or None: "
                            "chosen from the data)")
        if not 0 <= self.prune_rate < 1:
            raise UserError(f"model_based prune_rate {self.prune_rate!r}: use a share in "
                            "[0, 1) (0: no pruning between refits)")
        if isinstance(self.prune_to, bool) or not isinstance(self.prune_to, int) or (
                self.prune_to < 0):
            raise UserError(f"model_based prune_to {self.prune_to!r}: use an integer >= 0")


@dataclass
class ModelBasedResult:
    """What :func:`model_based` ends with: all the data, the log (as ``log.json``), and the
    estimator of the last fit made in this call (None where none was: a finished run)."""

    data: SequenceData
    log: dict[str, Any]
    estimator: Any = None

    @property
    def returns(self) -> list[float]:
        return [e["return"] for e in self.log["episodes"]]


class _Recorder:
    """An episode of a world stepped by :func:`run_loop`, recording what the data need."""

    def __init__(self, world: World, env: Any, image: np.ndarray) -> None:
        self.world = world
        self.env = env
        self.frames = [image]
        self.states = [world.state(env)]
        self.actions: list[np.ndarray] = []
        self.rewards: list[float] = []

    def done(self) -> bool:
        return False

    def step(self, action: np.ndarray) -> tuple[Observation, bool]:
        u = np.asarray(action, np.float32).reshape(len(self.world.action_low))
        obs, reward, terminated, truncated, _ = self.env.step(u)
        if isinstance(reward, bool) or not isinstance(reward, int | float | np.number) or (
                not np.isfinite(reward)):
            raise UserError(f"world {self.world.name}: env.step gave the reward {reward!r}, "
                            "not a finite number: model-based learning needs a reward")
        self.actions.append(u)
        self.rewards.append(float(reward))
        self.frames.append(self.world.image(obs))
        self.states.append(self.world.state(self.env))
        return Observation(self.frames[-1], self.states[-1]), bool(terminated or truncated)


class _Exploring:
    """A planner of the reward as a policy, with Gaussian exploration noise on its actions."""

    def __init__(self, planner: Any, std: np.ndarray, rng: np.random.Generator,
                 low: np.ndarray, high: np.ndarray) -> None:
        self.planner = planner
        self.std = std
        self.rng = rng
        self.low = low
        self.high = high

    def reset(self, goal: Observation | None, seed: int | None = None) -> None:
        self.planner.reset(None, seed)

    def act(self, observation: Observation) -> np.ndarray:
        u = self.planner.act(observation.image)
        noisy = np.clip(u + self.std * self.rng.standard_normal(len(u)), self.low, self.high)
        if callable(getattr(self.planner, "note_action", None)):
            self.planner.note_action(noisy)  # (a planner that reads the last action)
        return noisy.astype(np.float32)


def _labels(first: int, n: int, every: int) -> np.ndarray:
    """Split labels of episodes first..first+n-1: every ``every``-th one validation."""
    k = np.arange(first, first + n)
    return (((k + 1) % every == 0) if every else np.zeros(n, bool)).astype(np.uint8)


def _planned(world: World, env: Any, planner: Any, cfg: ModelBasedConfig, index: int,
             template: SequenceData, test: bool = False) -> SequenceData:
    """Episode ``index``, planned: one sequence, with the context of ``template``; ``test``:
    the index-th test start, without exploration noise."""
    rng = np.random.default_rng([cfg.seed, index] + ([1] if test else []))
    low, high = np.asarray(world.action_low, float), np.asarray(world.action_high, float)
    image = world.reset(env, world.sample_task(rng), cfg.seed * 100_003 + index + test * 50_021)
    rec = _Recorder(world, env, image)
    policy = _Exploring(planner, (0.0 if test else cfg.explore) * (high - low) / 2, rng, low,
                        high)
    n = run_loop(policy, rec, Observation(image, rec.states[0]), None, cfg.episode_steps,
                 cfg.seed * 1000 + index)
    if n < cfg.episode_steps:
        raise UserError(f"world {world.name} ended episode {index} after {n} of "
                        f"{cfg.episode_steps} actions: use episodes no longer than its own")
    return template.subset([0]).replace(
        images=np.stack(rec.frames)[None], actions=np.stack(rec.actions)[None],
        states=np.stack(rec.states).astype(np.float32)[None],
        rewards=np.asarray(rec.rewards, np.float32)[None],
        split=_labels(index, 1, cfg.validation_every))


def _entry(data: SequenceData, index: int, iteration: int, kind: str, env_steps: int,
           seconds: float) -> dict[str, Any]:
    return {"episode": index, "iteration": iteration, "kind": kind,
            "return": float(data.rewards[index].astype(np.float64).sum()),
            "env_steps": env_steps, "seconds": round(seconds, 3)}


def model_based(world: World, make_estimator: Callable[[int], Any], cfg: ModelBasedConfig,
                out: str | Path | None = None, progress: Progress | None = None,
                fit_settings: dict[str, Any] | None = None) -> ModelBasedResult:
    """Run the loop of the module docstring in ``world``; ``make_estimator(iteration)``
    gives an unfitted estimator for iteration 1, 2, ... (fitted with ``fit(data,
    **fit_settings)``); ``out``: the folder that makes it resumable."""
    progress = progress or Silent()
    settings = json.loads(json.dumps(to_json(cfg)))
    folder = Path(out) if out is not None else None
    data, log = _resume(folder, settings) if folder is not None else (None, None)
    per_action = cfg.steps_per_action
    if data is None:
        t0 = time.perf_counter()
        data = collect_random(world, cfg.seed_episodes, cfg.episode_steps, cfg.seed,
                              cfg.seed_hold)
        if data.rewards is None:
            raise UserError(f"world {world.name}: its env.step gives no numeric rewards: "
                            "model-based learning needs them")
        data = data.replace(split=_labels(0, data.n, cfg.validation_every))
        seconds = (time.perf_counter() - t0) / data.n
        log = {"format": LOG_FORMAT, "version": 1, "settings": settings, "done": 0,
               "episodes": [_entry(data, i, 0, "random", (i + 1) * cfg.episode_steps
                                   * per_action, seconds) for i in range(data.n)],
               "iterations": []}
        _save(folder, data, log)
    estimator = None
    state = None
    if cfg.warm_updates and 0 < log["done"] < cfg.iterations:
        state = load_state(_state_path(folder, log["done"]), log["done"])
    progress.start(cfg.iterations, min(log["done"], cfg.iterations))
    env = world.make_env() if log["done"] < cfg.iterations else None
    try:
        for iteration in range(log["done"] + 1, cfg.iterations + 1):
            progress.note(f"iteration {iteration}: fitting on {data.n} episodes"
                          + (" (warm-started)" if state is not None else ""))
            t0 = time.perf_counter()
            estimator, state = _fit(make_estimator(iteration), data, fit_settings or {}, cfg,
                                    state)
            fit_s = time.perf_counter() - t0
            latent = _latent(estimator)
            if latent is not None and latent.get("summary"):
                progress.note(f"iteration {iteration}: {latent['summary']}")
            planner = estimator.planner(cfg.mppi, seed=cfg.seed * 1000 + iteration,
                                        objective="reward")
            parts = [data]
            entries = []
            for _ in range(cfg.episodes_per_iteration):
                index = data.n + len(entries)
                t1 = time.perf_counter()
                parts.append(_planned(world, env, planner, cfg, index, data))
                steps = (index + 1) * cfg.episode_steps * per_action
                entries.append(_entry(parts[-1], 0, iteration, "planned", steps,
                                      time.perf_counter() - t1) | {"episode": index})
            t1 = time.perf_counter()
            seen = data.n * cfg.episode_steps * per_action
            tests = [_planned(world, env, planner, cfg, k, data, test=True)
                     for k in range(cfg.eval_episodes)]
            test_s = time.perf_counter() - t1
            data = concatenate(parts)
            log["episodes"] += entries
            active = _active(estimator)
            log["iterations"].append({
                "iteration": iteration, "fit_seconds": round(fit_s, 3),
                "plan_seconds": round(sum(e["seconds"] for e in entries), 3),
                "updates": None if state is None else state.updates,
                "batch_size": None if state is None else state.batch_size,
                "pruned": None if state is None else state.pruned,
                "equations": _equations(estimator), "active_terms": active,
                **({} if latent is None else {"latent": latent}),
                "fit_env_steps": seen, "eval_seconds": round(test_s, 3),
                "evaluation": [float(t.rewards.astype(np.float64).sum()) for t in tests]})
            log["done"] = iteration
            _save(folder, data, log, state)
            mean = float(np.mean([e["return"] for e in entries])) if entries else None
            test = log["iterations"][-1]["evaluation"]
            progress.update(iteration, {"return": mean, "evaluation": float(np.mean(test))
                                        if test else None, "env_steps": float(
                log["episodes"][-1]["env_steps"]), "sindy/active": active,
                "fit_seconds": fit_s})
    finally:
        if env is not None and hasattr(env, "close"):
            env.close()
        progress.close()
    return ModelBasedResult(data, log, estimator)


def _fit(estimator: Any, data: SequenceData, settings: dict[str, Any], cfg: ModelBasedConfig,
         state: WarmState | None) -> tuple[Any, WarmState | None]:
    """The iteration's fit: from scratch (the first, or every one without warm starts), or
    continued from ``state``."""
    if cfg.batch_size is not None:
        settings = {"batch_size": cfg.batch_size} | settings
    if not cfg.warm_updates:
        return estimator.fit(data, **settings), None
    if not callable(getattr(estimator, "train_config", None)):
        raise UserError(f"warm-started refits continue a LatentSINDy's training; "
                        f"{type(estimator).__name__} has none: use warm_updates=0")
    if state is None:
        return first_fit(estimator, data, settings)
    return warm_fit(estimator, data, settings, state, cfg.warm_updates, cfg.prune_rate,
                    cfg.prune_to)


def _active(estimator: Any) -> int | None:
    """The SINDy model's active terms (nonzero coefficients); None for other dynamics."""
    try:
        return int(np.count_nonzero(estimator.coefficients()))
    except (UserError, AttributeError, NotImplementedError):
        return None


def _latent(estimator: Any) -> dict[str, Any] | None:
    """What the estimator's latent is, where it says (a read latent: what its reader found,
    :meth:`~latent_sindy.read_latent.ReadLatent.latent_record`); None otherwise."""
    record = getattr(estimator, "latent_record", None)
    return record() if callable(record) else None


def _state_path(folder: Path, iteration: int) -> Path:
    return folder / f"model_{iteration}.pt"


def _equations(estimator: Any) -> list[str] | None:
    try:
        return list(estimator.equations())
    except (UserError, AttributeError, NotImplementedError):
        return None  # (an MLP's dynamics have none to show)


def _save(folder: Path | None, data: SequenceData, log: dict[str, Any],
          state: WarmState | None = None) -> None:
    """The data and the iteration's model, then the log: a kill before the log leaves
    episodes the log does not count, which a resume drops, and a model of an iteration it
    does not count, which a resume ignores (the earlier model is removed after the log)."""
    if folder is None:
        return
    folder.mkdir(parents=True, exist_ok=True)
    write_sequences(folder / "data.h5", data)
    if state is not None:
        save_state(_state_path(folder, log["done"]), state, log["done"])
    write_atomic(folder / "log.json", lambda f: f.write(json.dumps(log, indent=1)),
                 binary=False)
    for old in folder.glob("model_*.pt"):
        if old.name != _state_path(folder, log["done"]).name:
            old.unlink(missing_ok=True)


def _resume(folder: Path, settings: dict[str, Any]
            ) -> tuple[SequenceData | None, dict[str, Any] | None]:
    """The data and log of ``folder`` where a run of the same settings wrote them (its
    iterations may differ), else (None, None) for a new folder; UserError for another
    run's."""
    path = folder / "log.json"
    if not path.is_file():
        if folder.exists() and any(folder.iterdir()):
            raise UserError(f"{folder} holds files but no log.json: choose an empty folder")
        return None, None
    try:
        log = json.loads(path.read_text())
        if log.get("format") != LOG_FORMAT:
            raise ValueError("not a model-based log")
        count = len(log["episodes"])
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise UserError(f"{path} is damaged ({e}): delete {folder} to start again") from e
    was = {k: v for k, v in log["settings"].items() if k != "iterations"}
    now = {k: v for k, v in settings.items() if k != "iterations"}
    if was != now:
        changed = sorted(k for k in set(was) | set(now) if was.get(k) != now.get(k))
        raise UserError(f"{folder} holds a run of other settings ({', '.join(changed)}): "
                        "use its settings (only iterations may change), or another folder")
    data = read_sequences(folder / "data.h5")
    if data.n < count:
        raise UserError(f"{folder / 'data.h5'} holds {data.n} episodes, its log {count}: "
                        f"delete {folder} to start again")
    data = data.subset(np.arange(count))  # (episodes of an iteration its log missed: dropped)
    return data, {**log, "settings": {**log["settings"], "iterations": settings["iterations"]}}
