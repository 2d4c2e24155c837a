"""Closed-loop pushing with a trained run: encode the image, plan with MPPI, push, repeat.

Each episode encodes the goal image (the camera's view with the block at the goal), then at
every step encodes the current image, asks MPPI for a push in latent space (or in image
space: the cost decodes every predicted latent and compares it with the goal image; or in
pose space: a model's pose head reads the block's pose from every predicted latent and from
the encoded goal image, :data:`.controller.COSTS`), executes it in the PyBullet world and
looks again, until the block is at the goal or the step limit is reached: the project's one
closed loop (:func:`~latent_sindy.control.episodes.run_loop`), with the :class:`Controller`
as its policy (``act(observation)``: the camera image and the block's true pose) and this
world's record of each push (:class:`_Pushes`).

    latent-sindy control runs/sindy2 --task paper --episodes 1
    latent-sindy control runs/sindy2 --task random --episodes 20 --space image --max-steps 30
    latent-sindy control runs/sindy2_pose --task random --episodes 20 --space pose
"""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from latent_sindy.atomic import atomic_path, check_memory, check_output_dir, write_atomic
from latent_sindy.configs import to_json
from latent_sindy.control.episodes import Observation, run_loop
from latent_sindy.data.windows import Normalizer
from latent_sindy.stats import wilson_interval
from latent_sindy.worlds.push.config import PushEnvConfig
from latent_sindy.worlds.push.controller import ControlConfig, Controller, check_space


@dataclass
class EpisodeResult:
    """What one episode did; errors in metres and degrees, times in milliseconds."""

    episode: int
    seed: int
    start: list[float]
    goal: list[float]
    success: bool
    """Course criterion (position within the success distance) reached."""
    steps_to_goal: int | None
    strict_success: bool
    """Strict criterion (0.02 m and 10 degrees by default) reached."""
    steps_to_strict: int | None
    steps: int
    final_distance: float
    final_angle_error_deg: float
    left_workspace: bool
    plan_ms_mean: float
    plan_ms_max: float
    discarded: int
    """MPPI samples given zero weight because their rollout or cost was not finite."""
    pushes_executed: int = 0
    """Pushes the arm could carry out (the others were out of its reach)."""
    pushes_replaced: int = 0
    """Planned pushes out of the arm's reach replaced by a sampled push within it."""
    reach_ms_mean: float = 0.0
    """Time per step asking the world's reach (not in the planning time)."""
    actions: list[list[float]] = field(default_factory=list)


def _episode_options(env, settings: ControlConfig, seed: int) -> tuple[int, dict]:
    """The reset seed and options of an episode; random tasks never start at the goal."""
    if settings.task == "paper":
        return seed, {"task": "paper"}
    for k in range(100):
        s = seed * 1000 + k
        _, info = env.reset(seed=s)
        if not info["is_success"]:
            return s, {"start": info["pose"], "goal": info["goal"]}
    raise RuntimeError("could not draw a random task whose start is away from the goal")


class _Pushes:
    """An episode in the PyBullet world as the closed loop steps it: carries out each push
    and keeps what the results record (criteria met, plan and reach times, pushes executed
    and replaced, frames)."""

    def __init__(self, env, controller: Controller, info: dict, until: str,
                 frames: list | None) -> None:
        self.env = env
        self.controller = controller
        self.info = info
        self.frames = frames
        self.key = "is_success" if until == "course" else "is_success_strict"
        self.steps_goal = 0 if info["is_success"] else None
        self.steps_strict = 0 if info["is_success_strict"] else None
        self.plan_ms: list[float] = []
        self.reach_ms: list[float] = []
        self.actions: list[list[float]] = []
        self.discarded = self.steps = self.executed = self.replaced = 0
        self.left = False

    def done(self) -> bool:
        return bool(self.info[self.key])

    def step(self, action: np.ndarray) -> tuple[Observation, bool]:
        push = self.controller.last
        self.plan_ms.append(push.plan.seconds * 1e3)
        self.reach_ms.append(push.reach_s * 1e3)
        self.replaced += push.replaced
        self.discarded += push.plan.discarded
        self.actions.append([float(a) for a in action])
        obs, _, terminated, _, info = self.env.step(action)
        self.info = info
        self.steps = self.steps + 1
        self.executed += bool(info["push_executed"])
        if self.frames is not None:
            self.frames.append(self.env.render())
        if info["is_success"] and self.steps_goal is None:
            self.steps_goal = self.steps
        if info["is_success_strict"] and self.steps_strict is None:
            self.steps_strict = self.steps
        self.left = bool(terminated)
        return Observation(obs, info["pose"]), self.left


def run_episode(env, controller: Controller, episode: int, settings: ControlConfig,
                frames: list | None = None) -> EpisodeResult:
    """One closed-loop episode in `env` (a PandaPushEnv); appends rendered frames if asked."""
    seed = int(np.random.default_rng([settings.seed, episode]).integers(2**31))
    reset_seed, options = _episode_options(env, settings, seed)
    obs, info = env.reset(seed=reset_seed, options=options)
    start, goal = info["pose"].tolist(), info["goal"].tolist()
    goal_view = Observation(env.goal_observation(), info["goal"])
    if frames is not None:
        frames.append(env.render())
    run = _Pushes(env, controller, info, settings.until, frames)
    run_loop(controller, run, Observation(obs, info["pose"]), goal_view, settings.max_steps,
             seed)
    info = run.info
    plan_ms = run.plan_ms
    reach_ms = run.reach_ms
    return EpisodeResult(
        episode=episode, seed=reset_seed, start=start, goal=goal,
        success=run.steps_goal is not None, steps_to_goal=run.steps_goal,
        strict_success=run.steps_strict is not None, steps_to_strict=run.steps_strict,
        steps=run.steps, final_distance=float(info["distance"]),
        final_angle_error_deg=float(math.degrees(info["angle_error"])),
        left_workspace=run.left,
        plan_ms_mean=float(np.mean(plan_ms)) if plan_ms else 0.0,
        plan_ms_max=float(np.max(plan_ms)) if plan_ms else 0.0,
        discarded=run.discarded, pushes_executed=run.executed, pushes_replaced=run.replaced,
        reach_ms_mean=float(np.mean(reach_ms)) if reach_ms else 0.0, actions=run.actions)


def summarize(results: list[EpisodeResult]) -> dict[str, float]:
    """Success rates with 95 % Wilson intervals, mean steps to goal (successful episodes),
    final errors, executed pushes, planning time."""
    ok = [r for r in results if r.success]
    ok_strict = [r for r in results if r.strict_success]
    plan = [r.plan_ms_mean for r in results if r.steps]
    n = len(results)
    pushes = sum(r.steps for r in results)
    lo, hi = wilson_interval(len(ok), n)
    slo, shi = wilson_interval(len(ok_strict), n)
    return {
        "episodes": n,
        "success_rate": len(ok) / n,
        "success_ci_low": lo,
        "success_ci_high": hi,
        "strict_success_rate": len(ok_strict) / n,
        "strict_ci_low": slo,
        "strict_ci_high": shi,
        "final_angle_error_deg_mean": float(np.mean([abs(r.final_angle_error_deg)
                                                     for r in results])),
        "executed_rate": sum(r.pushes_executed for r in results) / pushes if pushes else math.nan,
        "replaced_rate": sum(r.pushes_replaced for r in results) / pushes if pushes else math.nan,
        "steps_to_goal_mean": float(np.mean([r.steps_to_goal for r in ok])) if ok else math.nan,
        "steps_to_strict_mean": (float(np.mean([r.steps_to_strict for r in ok_strict]))
                                 if ok_strict else math.nan),
        "final_distance_mean": float(np.mean([r.final_distance for r in results])),
        "plan_ms_mean": float(np.mean(plan)) if plan else math.nan,
        "discarded_total": int(sum(r.discarded for r in results)),
        "left_workspace": int(sum(r.left_workspace for r in results)),
    }


def format_summary(summary: dict[str, float], title: str) -> str:
    s = summary
    return "\n".join([
        title,
        f"  success (course)   {s['success_rate']:6.1%}   (95% CI {s['success_ci_low']:.0%}-"
        f"{s['success_ci_high']:.0%})   mean steps to goal {s['steps_to_goal_mean']:.1f}",
        f"  success (strict)   {s['strict_success_rate']:6.1%}   (95% CI {s['strict_ci_low']:.0%}-"
        f"{s['strict_ci_high']:.0%})   mean steps {s['steps_to_strict_mean']:.1f}",
        f"  final distance     {100 * s['final_distance_mean']:.1f} cm (mean)",
        f"  planning           {s['plan_ms_mean']:.1f} ms per step (mean; one-time warm-up "
        f"{s.get('warmup_ms', math.nan):.0f} ms not included)",
        f"  pushes executed    {s['executed_rate']:6.1%}   (planned out of reach, replaced "
        f"{s.get('replaced_rate', math.nan):.1%})",
        f"  discarded samples  {s['discarded_total']}   left workspace "
        f"{s['left_workspace']} episode(s)",
    ])


def model_memory_per_sample(model, space: str) -> int:
    """Bytes one sample of one planning step holds besides MPPI's own arrays: a decoded image
    in image space (float32), nothing more in latent space."""
    if space != "image":
        return 0
    with torch.no_grad():
        out = model.decode(torch.zeros(1, model.config.observation.latent_dim))
    return 4 * out.numel() * 3  # decoder output and the cost's copies


def run_control(model, normalizer: Normalizer, env_config: PushEnvConfig,
                settings: ControlConfig, out: str | os.PathLike,
                progress: Callable[[Iterable, int], Iterable] | None = None,
                ) -> tuple[list[EpisodeResult], dict]:
    """Run every episode, write results.json, results.csv and episode GIFs into `out`."""
    from latent_sindy.worlds.push.panda_push import PandaPushEnv

    out = check_output_dir(out, "--out")
    mppi = settings.mppi
    check_memory(mppi.memory_bytes(env_config.action_dim, model.config.observation.latent_dim)
                 + mppi.samples * mppi.horizon * model_memory_per_sample(model, settings.space),
                 f"MPPI with --samples {mppi.samples} --horizon {mppi.horizon}",
                 "lower --samples or --horizon")
    check_space(model, settings.space)  # refused before the folder is made
    out.mkdir(parents=True, exist_ok=True)
    env = PandaPushEnv(env_config, render_mode="rgb_array")
    controller = Controller(model, normalizer, settings, env_config)
    results = []
    episodes: Iterable[int] = range(settings.episodes)
    if progress is not None:
        episodes = progress(episodes, settings.episodes)
    try:
        for i in episodes:
            frames: list | None = [] if i < settings.gif_episodes else None
            results.append(run_episode(env, controller, i, settings, frames))
            if frames:
                save_gif(frames, out / f"episode_{i:03d}.gif")
    finally:
        env.close()
        controller.close()
    summary = {**summarize(results), "warmup_ms": 1e3 * controller.warmup_s}
    record = {"settings": to_json(settings), "summary": summary,
              "episodes": [asdict(r) for r in results]}
    write_atomic(out / "results.json", lambda f: f.write(json.dumps(record, indent=1)), False)
    rows = [{k: v for k, v in asdict(r).items() if k != "actions"} for r in results]
    _write_csv(out / "results.csv", rows)
    return results, summary


def save_gif(frames: list[np.ndarray], path: Path, ms_per_frame: int = 500) -> None:
    import imageio.v3 as iio

    with atomic_path(path) as tmp:
        iio.imwrite(tmp, np.stack(frames), extension=".gif", duration=ms_per_frame, loop=0)


def _write_csv(path: Path, rows: list[dict]) -> None:
    def write(f) -> None:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)

    write_atomic(path, write, binary=False)
