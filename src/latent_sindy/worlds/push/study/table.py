"""The paper's Table I beside ours, as Markdown and CSV (rows metrics, columns models).

Rows the paper reports come twice, "(paper)" then "(ours)"; the rows we add (success rates,
planning time, discarded samples, prediction error) only as ours. Our values are mean ± std
over the seeds (see :func:`latent_sindy.study.evaluation.aggregate`).

    from latent_sindy.worlds.push.study.table import table1_rows, write_table1
    write_table1(out_dir, models, labels, stats, seeds=2)  # table1.md, table1.csv
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from latent_sindy.atomic import write_atomic
from latent_sindy.stats import wilson_interval
from latent_sindy.study.evaluation import Stat, mean_std

__all__ = ["PAPER", "ROWS", "SWEEP_COLUMNS", "Row", "format_stat", "pooled_counts", "sweep_rows",
           "table1_rows", "write_sweep_table", "write_table1"]

#: The paper's Table I by column (SINDy orders 1-4, E2C); sparsity in percent.
PAPER: dict[str, dict[str, float | None]] = {
    "sindy1": {"loss/train": 0.0232, "loss/val": 0.0376, "loss/test": 0.0631,
               "control/paper/latent/steps_to_goal_mean": 15, "sindy/sparsity": 98.3},
    "sindy2": {"loss/train": 0.0255, "loss/val": 0.0409, "loss/test": 0.0597,
               "control/paper/latent/steps_to_goal_mean": 15, "sindy/sparsity": 96.3},
    "sindy3": {"loss/train": 0.0206, "loss/val": 0.0355, "loss/test": 0.0647,
               "control/paper/latent/steps_to_goal_mean": 15, "sindy/sparsity": 96.0},
    "sindy4": {"loss/train": 0.0587, "loss/val": 0.0804, "loss/test": 0.1018,
               "control/paper/latent/steps_to_goal_mean": 15, "sindy/sparsity": 94.6},
    "linear": {"loss/train": 0.0286, "loss/val": 0.0574, "loss/test": 0.2212,
               "control/paper/latent/steps_to_goal_mean": 5, "sindy/sparsity": None},
}


@dataclass(frozen=True)
class Row:
    """One metric of the table: its key in the metric dictionaries, label and format."""

    key: str
    label: str
    fmt: str  # "loss", "pct" (a fraction shown in %), "pct100" (already in %), "num", "num2"
    #           (2 decimals), "int", "r2" (3 decimals)
    in_paper: bool = False
    ci: str | None = None
    """Metric prefix of a 95% interval (``<ci>_ci_low``, ``_ci_high``) shown with one seed."""


ROWS: tuple[Row, ...] = (
    Row("loss/train", "training loss", "loss", True),
    Row("loss/val", "validation loss", "loss", True),
    Row("loss/test", "test loss", "loss", True),
    Row("control/paper/latent/steps_to_goal_mean", "steps to goal (paper task, latent MPPI)",
        "num", True),
    Row("sindy/sparsity", "sparsity", "pct100", True),
    Row("sindy/active", "active coefficients", "int"),
    Row("control/paper/latent/success_rate", "success, paper task, latent MPPI", "pct",
        ci="control/paper/latent/success"),
    Row("control/random/latent/success_rate", "success, random tasks, latent MPPI (course)",
        "pct", ci="control/random/latent/success"),
    Row("control/random/latent/strict_success_rate",
        "success, random tasks, latent MPPI (strict)", "pct",
        ci="control/random/latent/strict"),
    Row("control/random/latent/steps_to_goal_mean", "steps to goal, random tasks, latent MPPI",
        "num"),
    Row("control/random/latent/final_distance_mean",
        "final distance to goal, random tasks, latent MPPI (m)", "loss"),
    Row("control/random/latent/executed_rate", "pushes executed, random tasks, latent MPPI",
        "pct"),
    Row("control/paper/image/success_rate", "success, paper task, image-space MPPI", "pct",
        ci="control/paper/image/success"),
    Row("control/random/image/success_rate", "success, random tasks, image-space MPPI (course)",
        "pct", ci="control/random/image/success"),
    Row("control/latent/plan_ms_mean", "planning ms per step, latent MPPI", "num"),
    Row("control/image/plan_ms_mean", "planning ms per step, image-space MPPI", "num"),
    Row("control/discarded_total", "discarded MPPI samples (NaN/inf), all episodes", "int"),
    Row("pred_err/h1", "prediction error, 1 step (test, image MSE)", "loss"),
    Row("pred_err/hmax", "prediction error, last horizon (test, image MSE)", "loss"),
    Row("state_err/h1", "prediction error, 1 step (test, state MSE)", "loss"),
    Row("state_err/hmax", "prediction error, last horizon (test, state MSE)", "loss"),
    Row("probe/x", "latent probe R², block x (test, linear)", "r2"),
    Row("probe/y", "latent probe R², block y (test, linear)", "r2"),
    Row("probe/angle", "latent probe R², block angle (cos, sin of 2πθ/period; mean)", "r2"),
    Row("probe/kernel/x", "latent probe R², block x (test, kernel ridge)", "r2"),
    Row("probe/kernel/y", "latent probe R², block y (test, kernel ridge)", "r2"),
    Row("probe/kernel/angle", "latent probe R², block angle (test, kernel ridge; mean)", "r2"),
    Row("pos_err/recon", "block position error, reconstruction (test, cm)", "num2"),
    *(Row(f"pos_err/h{h}", f"block position error after {h} push{'es' * (h > 1)} (test, cm)",
          "num2") for h in (1, 5, 10)),
    *(Row(f"pos_err/still/h{h}",
          f"block position error after {h} push{'es' * (h > 1)}, nothing moves (test, cm)",
          "num2") for h in (1, 5, 10)),
)


def _num(v: float, fmt: str) -> str:
    if fmt == "loss":
        return f"{v:.4f}" if 1e-3 <= abs(v) < 1e4 else f"{v:.2e}"
    if fmt == "pct":
        return f"{100 * v:.0f}%"
    if fmt == "pct100":  # one decimal; more where rounding would turn 99.96% into 100.0%
        digits = 1
        while digits < 4 and v < 100 and round(v, digits) >= 100:
            digits += 1
        return f"{v:.{digits}f}%"
    if fmt == "int":
        return f"{v:.0f}"
    if fmt == "r2":
        return f"{v:.3f}"
    if fmt == "num2":
        return f"{v:.2f}"
    return f"{v:.1f}"


def format_stat(s: Stat | None, fmt: str, seeds: int) -> str:
    """``mean ± std`` (± left out for one seed); "n/a" not applicable, "—" no result,
    "diverged" for an infinite value."""
    if s is None or s.mean is None:
        return "n/a"
    if math.isnan(s.mean):
        return "—"
    if math.isinf(s.mean):
        return "diverged"
    text = _num(s.mean, fmt)
    if seeds > 1:
        text += f" ± {_num(s.std, fmt)}"
        if s.n < seeds:
            text += f" ({s.n}/{seeds} seeds)"
    return text


def _ours(stats: Mapping[str, Stat], row: Row) -> Stat | None:
    s = stats.get(row.key)
    if s is not None and row.fmt == "pct100" and s.mean is not None:
        return Stat(100 * s.mean, 100 * s.std, s.n)
    return s


def _interval(stats: Mapping[str, Stat], row: Row, seeds: int) -> str:
    """" (lo–hi%)" for a row with an interval, measured with one seed; else ""."""
    if row.ci is None or seeds != 1:
        return ""
    lo, hi = stats.get(f"{row.ci}_ci_low"), stats.get(f"{row.ci}_ci_high")
    if lo is None or hi is None or lo.mean is None or hi.mean is None or not (
            math.isfinite(lo.mean) and math.isfinite(hi.mean)):
        return ""
    return f" ({100 * lo.mean:.0f}–{100 * hi.mean:.0f}%)"


def _paper(model: str, row: Row) -> str:
    if model not in PAPER:
        return "—"
    v = PAPER[model].get(row.key)
    return "n/a" if v is None else _num(v, row.fmt) if row.fmt != "num" else f"{v:g}"


def table1_rows(models: Sequence[str], stats: Mapping[str, Mapping[str, Stat]],
                seeds: int) -> list[list[str]]:
    """Markdown/HTML rows: [label, one cell per model]; paper rows precede our rows."""
    rows = []
    for row in ROWS:
        if row.in_paper:
            rows.append([f"{row.label} (paper)", *(_paper(m, row) for m in models)])
        cells = [format_stat(_ours(stats.get(m, {}), row), row.fmt, seeds)
                 + _interval(stats.get(m, {}), row, seeds) for m in models]
        rows.append([f"{row.label} (ours)" if row.in_paper else row.label, *cells])
    return rows


def write_table1(out: Path, models: Sequence[str], labels: Mapping[str, str],
                 stats: Mapping[str, Mapping[str, Stat]], seeds: int) -> tuple[Path, Path]:
    """Write ``out/table1.md`` (formatted) and ``out/table1.csv`` (one row per metric, model)."""
    header = ["metric", *(labels[m] for m in models)]
    rows = table1_rows(models, stats, seeds)
    md = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    md += ["| " + " | ".join(r) + " |" for r in rows]
    note = ("\n\nOurs: mean ± sample std over seeds where several; n/a: does not apply; —: no "
            "value (the paper did not report it, or no episode reached the goal); diverged: "
            "the open-loop rollout overflowed.\n")
    write_atomic(out / "table1.md", lambda f: f.write("\n".join(md) + note), binary=False)

    def write_csv(f: IO[str]) -> None:
        w = csv.writer(f)
        w.writerow(["metric", "model", "paper", "ours_mean", "ours_std", "ours_n", "ours"])
        for row in ROWS:
            for m in models:
                s = _ours(stats.get(m, {}), row)
                paper = PAPER.get(m, {}).get(row.key) if row.in_paper else None
                w.writerow([row.label, m, "" if paper is None else paper,
                            "" if s is None or s.mean is None else s.mean,
                            "" if s is None or s.std is None else s.std,
                            0 if s is None else s.n, format_stat(s, row.fmt, seeds)])

    write_atomic(out / "table1.csv", write_csv, binary=False)
    return out / "table1.md", out / "table1.csv"


#: Columns of the sweep table: a metric, and for success rates the condition whose episodes
#: are pooled over the seeds into one Wilson interval.
SWEEP_COLUMNS: tuple[Row, ...] = (
    Row("loss/test", "test loss", "loss"),
    Row("sindy/sparsity", "sparsity", "pct100"),
    Row("pred_err/h1", "prediction error, 1 step", "loss"),
    Row("control/random/latent/success_rate", "success, random tasks", "pct",
        ci="control/random/latent"),
    Row("control/random/latent/strict_success_rate", "strict success, random tasks", "pct",
        ci="control/random/latent"),
    Row("control/paper/latent/success_rate", "success, paper task", "pct",
        ci="control/paper/latent"),
)


def pooled_counts(per_seed: Sequence[Mapping[str, float | None]], rate_key: str,
                  episodes_key: str) -> tuple[int, int]:
    """(successes, episodes) of every seed's episodes together: each seed's rate (metric
    ``rate_key``) times its episode count (``episodes_key``); seeds without both are left out."""
    k = n = 0
    for m in per_seed:
        rate = m.get(rate_key)
        episodes = m.get(episodes_key)
        if rate is None or episodes is None or not (math.isfinite(rate)
                                                    and math.isfinite(episodes)):
            continue
        k += round(rate * episodes)
        n += int(episodes)
    return k, n


def _pooled_interval(per_seed: Sequence[Mapping[str, float | None]], row: Row) -> str:
    """" [lo–hi%, k/n]": the 95 % Wilson interval of all seeds' episodes together."""
    k, n = pooled_counts(per_seed, row.key, f"{row.ci}/episodes")
    if n == 0:
        return ""
    lo, hi = wilson_interval(k, n)
    return f" [{100 * lo:.0f}–{100 * hi:.0f}%, {k}/{n}]"


def sweep_rows(models: Sequence[str], labels: Mapping[str, str],
               per_seed: Mapping[int, Mapping[str, Mapping[str, float | None]]],
               seeds: Sequence[int]) -> list[list[str]]:
    """One row per model (sweep variant): mean ± std over seeds of each column, and for
    success rates the Wilson interval of the episodes of every seed pooled."""
    rows = []
    for m in models:
        runs = [per_seed[s][m] for s in seeds if m in per_seed.get(s, {})]
        cells = [labels[m], str(len(runs))]
        for col in SWEEP_COLUMNS:
            stat = _ours({col.key: mean_std([r.get(col.key) for r in runs])}, col)
            text = format_stat(stat, col.fmt, len(seeds))
            if col.ci is not None:
                text += _pooled_interval(runs, col)
            cells.append(text)
        rows.append(cells)
    return rows


def write_sweep_table(path: Path, models: Sequence[str], labels: Mapping[str, str],
                      per_seed: Mapping[int, Mapping[str, Mapping[str, float | None]]],
                      seeds: Sequence[int]) -> Path:
    """Write the sweep's table (Markdown): a row per variant, headline metrics as columns."""
    header = ["model", "seeds", *(c.label for c in SWEEP_COLUMNS)]
    md = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    md += ["| " + " | ".join(r) + " |" for r in sweep_rows(models, labels, per_seed, seeds)]
    note = ("\n\nMean ± sample std over the seeds that finished; success rates also with the "
            "95 % Wilson interval of all those seeds' episodes pooled [low–high, successes/"
            "episodes]. n/a: does not apply; —: no value.\n")
    write_atomic(path, lambda f: f.write("\n".join(md) + note), binary=False)
    return path
