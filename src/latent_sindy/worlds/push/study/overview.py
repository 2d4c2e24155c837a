"""The report's first screen: which model, and how well.

One row per model, best first: its dynamics and what it observes, its active dynamics terms,
its open-loop prediction error, and its closed-loop success on the random tasks (latent MPPI)
under both criteria, each with the 95 % Wilson interval of every seed's episodes pooled. And
how the study's numbers reproduce, as sentences about this study.

    from latent_sindy.worlds.push.study.overview import overview, overview_table
    view = overview(study)                        # rows, best first
    header, rows = overview_table(view, seeds=1)  # the report's short table
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from latent_sindy.stats import wilson_interval
from latent_sindy.study.evaluation import Stat
from latent_sindy.worlds.push.study.catalogue import ModelSpec
from latent_sindy.worlds.push.study.results import Study
from latent_sindy.worlds.push.study.table import format_stat, pooled_counts

__all__ = ["CONDITION", "ModelRow", "Overview", "Success", "overview", "overview_table",
           "reproduction_notes"]

#: The closed-loop condition the first screen reports: the most episodes, every model.
CONDITION = "random/latent"


@dataclass(frozen=True)
class Success:
    """Successes ``k`` of ``n`` episodes (all seeds pooled) and their 95 % Wilson interval."""

    k: int
    n: int

    @property
    def rate(self) -> float:
        return self.k / self.n if self.n else math.nan

    @property
    def interval(self) -> tuple[float, float]:
        return wilson_interval(self.k, self.n)

    def text(self) -> str:
        """"94% (84–98%)"; "—" without episodes."""
        if self.n == 0:
            return "—"
        lo, hi = self.interval
        return f"{100 * self.rate:.0f}% ({100 * lo:.0f}–{100 * hi:.0f}%)"


@dataclass(frozen=True)
class ModelRow:
    """One model on the first screen."""

    name: str
    label: str
    dynamics: str
    """"sindy", "linear" or "mlp"."""
    description: str
    """The dynamics in a word or two, e.g. "SINDy poly-2", "SINDy face", "MLP"."""
    observes: str
    """"image", "moments" (the image's moments) or "state" (the true pose: a reference row)."""
    active: Stat | None
    """Active dynamics terms (SINDy, linear) or dynamics parameters (dense models)."""
    candidates: Stat | None
    """Candidate coefficients of a SINDy or linear model; None for a dense network."""
    error: Stat | None
    coarse: Success
    strict: Success


@dataclass(frozen=True)
class Overview:
    rows: tuple[ModelRow, ...]
    """Best first: strict success, then coarse success; models without episodes last."""
    error_key: str
    error_label: str
    """What the prediction error measures, with its unit."""
    error_short: str
    """The same in a few words, for an axis."""
    error_column: str
    """The same in fewer, for the short table's column."""


def _error_key(study: Study) -> tuple[str, str, str, str]:
    """The block position error at the longest of 10, 5, 1 pushes that every measured model
    has (it is on the same footing for image and state models; a diverged one counts), else
    the test loss."""
    measured = [st for m in study.models if (st := study.stats.get(m))]
    for h in (10, 5, 1):
        key = f"pos_err/h{h}"
        if measured and all(key in st and st[key].mean is not None for st in measured):
            pushes = f"{h} push{'es' * (h > 1)}"
            return (key, f"block position error after {pushes} (cm)",
                    f"position error, {pushes} (cm)", f"error, {pushes} (cm)")
    return "loss/test", "test loss", "test loss", "test loss"


def _finite(s: Stat | None) -> bool:
    return s is not None and s.mean is not None and math.isfinite(s.mean)


def describe(spec: ModelSpec) -> tuple[str, str]:
    """The dynamics and what the model observes, in a word or two each: ("SINDy poly-2",
    "image"), ("SINDy face", "moments"), ("MLP", "state")."""
    dyn = spec.model.dynamics
    obs = spec.model.observation
    if dyn.kind == "sindy":
        library = getattr(dyn, "library", "poly")
        kind = f"SINDy {library}" + (f"-{dyn.order}" if library in ("poly", "push") else "")
    else:
        kind = {"linear": "linear", "mlp": "MLP"}.get(dyn.kind, dyn.kind)
    if spec.window > 1:
        kind += f", H={spec.window}"
    if obs.kind == "state":
        return kind, "state"
    return kind, "moments" if getattr(obs, "encoder_kind", "") == "moments" else "image"


def overview(study: Study) -> Overview:
    """The first screen's rows, best first."""
    key, *labels = _error_key(study)
    rows = []
    for spec in study.specs:
        m = spec.name
        stats = study.stats.get(m, {})
        runs = [study.per_seed[s][m] for s in study.config.seeds
                if m in study.per_seed.get(s, {})]
        episodes = f"control/{CONDITION}/episodes"
        coarse = Success(*pooled_counts(runs, f"control/{CONDITION}/success_rate", episodes))
        strict = Success(*pooled_counts(runs, f"control/{CONDITION}/strict_success_rate",
                                        episodes))
        active = stats.get("sindy/active")
        candidates = stats.get("sindy/coefficients")
        if not _finite(active):  # a dense network: all its parameters
            active = stats.get("params/dynamics")
            candidates = None
        rows.append(ModelRow(m, spec.label, spec.model.dynamics.kind, *describe(spec), active,
                             candidates, stats.get(key), coarse, strict))

    def rank(r: ModelRow) -> tuple[bool, float, float]:
        return (r.coarse.n == 0, -r.strict.rate if r.strict.n else 0.0,
                -r.coarse.rate if r.coarse.n else 0.0)

    return Overview(tuple(sorted(rows, key=rank)), key, *labels)


def _terms(row: ModelRow, seeds: int) -> tuple[str, str]:
    """("active / candidates", "sparsity"): ("63 / 171", "63.2%"), ("21136", "dense")."""
    if not _finite(row.active):
        return "n/a", "n/a"
    active = format_stat(row.active, "int", seeds)
    if not _finite(row.candidates):
        return active, "dense"
    total = row.candidates.mean
    if row.active.mean >= total:
        return f"{active} / {total:.0f}", "dense"
    return f"{active} / {total:.0f}", f"{100 * (1 - row.active.mean / total):.1f}%"


def overview_table(view: Overview, seeds: int) -> tuple[list[str], list[list[str]]]:
    """The short table: header and one row per model, numbered as in the overview figure."""
    header = ["#", "model", "dynamics", "input", "active terms", "sparsity", view.error_column,
              "success, 0.1 m", "success, 2 cm & 10°"]
    fmt = "num2" if view.error_key.startswith("pos_err") else "loss"
    rows = [[str(i), r.label, r.description, r.observes, *_terms(r, seeds),
             format_stat(r.error, fmt, seeds), r.coarse.text(), r.strict.text()]
            for i, r in enumerate(view.rows, start=1)]
    return header, rows


def reproduction_notes(view: Overview) -> list[str]:
    """How the report's numbers reproduce, with this study's widest interval as the example."""
    notes = [
        "Bit for bit on the same machine: a re-run with the same seeds, thread count and "
        "package versions gives the same data, trained weights, equations, errors and "
        "closed-loop episodes, so every number here but the timings.",
        "Within their intervals elsewhere: on another CPU the same seed trains along another "
        "floating-point path, so the weights, losses, sparsity, equations and prediction "
        "errors differ and every planned episode can end otherwise; the success rates are "
        "samples of episodes, to be compared through their 95% intervals, not digit by digit.",
        "Timings (planning ms per step, training seconds, wall time) measure the machine and "
        "its load, not the model.",
    ]
    widest = max(((r, crit, s) for r in view.rows for crit, s in
                  (("0.1 m", r.coarse), ("2 cm and 10°", r.strict)) if s.n),
                 key=lambda t: t[2].interval[1] - t[2].interval[0], default=None)
    if widest is not None:
        r, crit, s = widest
        lo, hi = s.interval
        notes[1] += (f" The widest interval here: {r.label}'s success within {crit}, {s.k} of "
                     f"{s.n} episodes, {100 * lo:.0f}–{100 * hi:.0f}%.")
    return notes
