"""What a study measured: each run's result, and the study's, as the stages returned them.

The training and evaluation stage returns :class:`Evaluations`, the baseline stage
:class:`Baselines`; :class:`Study` is the plan together with those returns, handed to the
outputs (tables, figures, report). Nothing here runs anything.

    latent-sindy reproduce --scale demo --out results   # summary.json holds a Study's numbers
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from latent_sindy.study.evaluation import Stat
from latent_sindy.worlds.push.study.config import StudyPlan
from latent_sindy.worlds.push.study.scales import Condition

__all__ = ["CONTROL_METRICS", "Baselines", "Evaluations", "RunResult", "Study"]

#: What the study keeps of each closed-loop summary (control/<task>/<space>/<key>).
CONTROL_METRICS = ("episodes", "success_rate", "success_ci_low", "success_ci_high",
                   "strict_success_rate", "strict_ci_low", "strict_ci_high",
                   "steps_to_goal_mean", "steps_to_strict_mean", "final_distance_mean",
                   "final_angle_error_deg_mean", "executed_rate", "plan_ms_mean", "warmup_ms",
                   "discarded_total", "left_workspace")


@dataclass(frozen=True)
class RunResult:
    """What the study measured of one trained (model, seed)."""

    losses: dict[str, dict[str, float]]
    """Split -> loss terms on single-step windows."""
    horizon: list[float]
    """Open-loop image MSE at horizon 1..T on held-out trajectories."""
    stats: dict[str, float | None]
    """Parameter and coefficient counts, sparsity."""
    control: dict[str, dict[str, Any]]
    """Condition name -> closed-loop summary (``nonfinite_actions`` included)."""
    train_seconds: float
    seconds: float
    observation: str = "image"
    """What the model saw; the prediction error is in that space ("state_err/*" for states)."""
    probe: dict[str, float] | None = None
    """R² of the probes from the latent to each pose feature (image models): the linear one
    (x, y, cos, sin) and the kernel ridge one (``kernel/...``)."""
    position: dict[str, Any] | None = None
    """Block position errors in cm (:func:`.probe.position_errors`; state models:
    :func:`.probe.state_position_errors`)."""

    def metrics(self, conditions: tuple[Condition, ...]) -> dict[str, float | None]:
        """One flat {metric: value} dictionary (the keys of table.ROWS and more)."""
        m: dict[str, float | None] = {}
        for split in ("train", "val", "test"):
            m[f"loss/{split}"] = self.losses.get(split, {}).get("objective")
        m.update(self.stats)
        err = "pred_err" if self.observation == "image" else "state_err"
        m.update({f"{err}/h{h}": v for h, v in enumerate(self.horizon, start=1)})
        m[f"{err}/hmax"] = self.horizon[-1]
        if self.probe is not None:
            m.update({f"probe/{k}": v for k, v in self.probe.items()})
            m["probe/angle"] = (self.probe["cos"] + self.probe["sin"]) / 2
        if self.position is not None:
            m["pos_err/recon"] = self.position["recon"]
            for name, key in (("model", "pos_err"), ("still", "pos_err/still")):
                m.update({f"{key}/h{h}": v
                          for h, v in enumerate(self.position[name], start=1)})
        plan_ms: dict[str, list[float]] = {"latent": [], "image": []}
        discarded = nonfinite = 0
        for cond in conditions:
            s = self.control.get(cond.name)
            if s is None:
                continue
            for k in CONTROL_METRICS:
                m[f"control/{cond.name}/{k}"] = s.get(k, math.nan)
            if math.isfinite(s["plan_ms_mean"]):
                plan_ms[cond.space].append(s["plan_ms_mean"])
            discarded += s["discarded_total"]
            nonfinite += s["nonfinite_actions"]
        planned = {c.space for c in conditions}
        for space, values in plan_ms.items():
            m[f"control/{space}/plan_ms_mean"] = (
                sum(values) / len(values) if values else math.nan if space in planned else None)
        m["control/discarded_total"] = discarded
        m["train/seconds"] = self.train_seconds
        m["control/nonfinite_actions"] = nonfinite
        return m


@dataclass(frozen=True)
class Evaluations:
    """What the training and evaluation stage returns: every (seed, model) it finished."""

    results: dict[int, dict[str, RunResult]]
    """Seed -> model name -> what was measured of the trained run."""
    per_seed: dict[int, dict[str, dict[str, float | None]]]
    """Seed -> model name -> :meth:`RunResult.metrics`."""
    stats: dict[str, dict[str, Stat]]
    """Model name -> metric -> mean ± std over the seeds."""
    train_status: dict[str, str]
    """"<model>/seed<S>" -> "trained", "resumed", "reused" or "diverged"."""
    failures: tuple[str, ...]
    """Runs that did not finish training, with the reason (left out of the averages)."""


@dataclass(frozen=True)
class Baselines:
    """What the baseline stage returns: the numbers of predictors that learn nothing."""

    pred_err: dict[str, list[float]]
    """Prediction error against horizon of the model-free predictors (evaluation.BASELINES)."""
    position: dict[str, Any]
    """Block position error (cm) of reading the true held-out images ("reader") and of
    "nothing moves" per horizon ("still"): :func:`.probe.position_errors` without a model."""


@dataclass(frozen=True)
class Study(StudyPlan):
    """What the pipeline produced: the plan and what its stages returned, handed to the
    outputs (tables, figures, report)."""

    evaluations: Evaluations
    baselines: Baselines
    timings: dict[str, float]
    """Stage -> wall seconds."""

    @property
    def results(self) -> dict[int, dict[str, RunResult]]:
        return self.evaluations.results

    @property
    def per_seed(self) -> dict[int, dict[str, dict[str, float | None]]]:
        return self.evaluations.per_seed

    @property
    def stats(self) -> dict[str, dict[str, Stat]]:
        return self.evaluations.stats
