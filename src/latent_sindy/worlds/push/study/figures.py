"""The study's figures as PNG files: the paper's Fig. 6-10 and ours.

Drawn with matplotlib's object API (no pyplot, so no global backend or open figures):

* :func:`loss_histories` (Fig. 6/7): training and validation objective per epoch, a line per model;
* :func:`rollout_strip` (Fig. 8): ground truth and model rollouts (single- and multi-step
  SINDy-2, then other models) from the same first image and actions;
* :func:`coefficient_map` (Fig. 9/10): M ⊙ Ψ, rows latent states, columns candidate terms;
* :func:`horizon_plot`: prediction error against horizon, a line per model (image MSE, or
  the block position error);
* :func:`control_bars`: closed-loop success rates and planning time per model;
* :func:`overview_figure`: the report's first figure, success under both criteria with
  intervals, and active terms against prediction error, per model.

Every file is written atomically (a reader never sees half a PNG).

    from latent_sindy.worlds.push.study import figures
    figures.coefficient_map(run.model.dynamics, "SINDy order 2", Path("figures/coef.png"))
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import FormatStrFormatter, LogLocator, NullFormatter

from latent_sindy.atomic import atomic_path
from latent_sindy.models.dynamics import SindyDynamics
from latent_sindy.plots import loss_histories
from latent_sindy.worlds.push.study.overview import Overview

__all__ = ["coefficient_map", "control_bars", "horizon_plot", "loss_histories", "overview_figure",
           "rollout_strip"]

#: Most columns a coefficient map shows (each labelled with its term's name).
MAX_COLUMNS = 240


def _figure(nrows: int = 1, ncols: int = 1, **kw) -> tuple[Figure, np.ndarray]:
    fig = Figure(figsize=kw.pop("figsize", (6.5, 4)))
    return fig, fig.subplots(nrows, ncols, squeeze=False, **kw)


def _save(fig: Figure, path: Path, dpi: int = 110) -> Path:
    with atomic_path(path) as tmp:  # the same suffix: savefig infers the format from it
        fig.savefig(tmp, dpi=dpi)
    return path


def rollout_strip(rows: Sequence[tuple[str, np.ndarray]], path: Path) -> Path:
    """Image rows (label, frames (T+1, C, S, S) in pixel values), one column per time step."""
    n_rows, n_cols = len(rows), len(rows[0][1])
    fig, axes = _figure(n_rows, n_cols, figsize=(1.1 * n_cols + 1.6, 1.2 * n_rows + 0.3))
    for i, (label, frames) in enumerate(rows):
        for t in range(n_cols):
            ax = axes[i, t]
            img = np.clip(frames[t], 0, 255).astype(np.uint8)
            img = img[0] if img.shape[0] == 1 else img.transpose(1, 2, 0)
            ax.imshow(img, cmap="gray", vmin=0, vmax=255)
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(f"t={t}", fontsize=8)
        axes[i, 0].set_ylabel(label, fontsize=8, rotation=0, ha="right", va="center")
    fig.tight_layout()
    return _save(fig, path)


def coefficient_map(dyn: SindyDynamics, title: str, path: Path) -> Path:
    """M ⊙ Ψ as a signed heat map (rows latent states, columns candidate terms, labelled).

    A library of at most ``MAX_COLUMNS`` terms (orders 1-2) is shown whole. A larger one
    (orders 3-4) shows its active columns only (terms some state uses), and of those, when
    there are more than ``MAX_COLUMNS``, the strongest by Σ_states |coefficient|.
    """
    coef = dyn.coefficients().detach().cpu().numpy().T  # (nz, p)
    mask = dyn.mask.cpu().numpy().T  # (nz, p)
    names = dyn.names
    p = coef.shape[1]
    if p <= MAX_COLUMNS:
        cols = np.arange(p)
        shown = "all terms"
    else:
        active = np.flatnonzero(mask.any(axis=0))
        cols = active
        shown = f"the {len(active)} active terms of {p}"
        if len(active) > MAX_COLUMNS:
            strength = np.abs(coef[:, active]).sum(axis=0)
            cols = np.sort(active[np.argsort(-strength, kind="stable")[:MAX_COLUMNS]])
            shown = f"the {MAX_COLUMNS} strongest of {len(active)} active terms (of {p})"
        if len(cols) == 0:
            cols = np.arange(1)
            shown = f"no active term of {p}"
    data = np.ma.masked_where(~mask[:, cols], coef[:, cols])
    lim = float(np.abs(coef).max()) or 1.0
    width, height = min(30.0, max(6.0, 0.11 * len(cols) + 2)), 4.2
    fig, ax = _figure(figsize=(width, height))
    ax = ax[0, 0]
    # fixed margins: tight_layout measures every rotated label, seconds for 240 columns
    fig.subplots_adjust(left=0.5 / width, right=1 - 1.0 / width, top=1 - 0.35 / height,
                        bottom=0.85 / height)
    cmap = matplotlib.colormaps["RdBu_r"].with_extremes(bad="#eeeeee")  # pruned: grey
    im = ax.imshow(data, aspect="auto", cmap=cmap, vmin=-lim, vmax=lim, interpolation="nearest")
    rows = [f"z{j}" for j in range(coef.shape[0])]
    if getattr(dyn, "turn", False):  # z_a's coefficients are the turn ω; z_b has none
        a, b = dyn.circle
        rows[a] = "ω"
        rows[b] = f"(z{b})"
    ax.set_yticks(range(coef.shape[0]), rows, fontsize=6)
    ax.set_xticks(range(len(cols)), [names[i] for i in cols], rotation=90,
                  fontsize=7 if len(cols) <= 60 else 5)
    ax.set_title(f"{title}: {dyn.n_active()} active coefficients of {dyn.n_candidates()} "
                 f"({100 * dyn.sparsity():.1f}% sparse); showing {shown}", fontsize=9)
    fig.colorbar(im, ax=ax, fraction=0.02, pad=0.01)
    return _save(fig, path)


def horizon_plot(curves: Mapping[str, tuple[list[float], list[float]]],
                 labels: Mapping[str, str], path: Path,
                 references: Mapping[str, list[float]] | None = None, *,
                 ylabel: str = "image MSE (normalised pixels)",
                 title: str = "open-loop prediction error on test trajectories",
                 yscale: str = "log", cap: float = 100.0) -> Path:
    """Prediction error against horizon: {model: (means, stds)} per horizon 1..T.

    ``references`` ({label: errors per horizon}) are drawn dashed in grey, for scale (e.g.
    the model-free baselines); a reference of one value is a constant. The y axis stops at
    ``cap`` times the largest one-step error, so that one exploding rollout does not flatten the
    others; a model that leaves the plot (or diverges) says where.
    """
    fig, ax = _figure()
    ax = ax[0, 0]
    first = [m[0] for m, _ in curves.values() if m and np.isfinite(m[0])]
    top = cap * max(first) if first else np.inf
    for name, (mean, std) in curves.items():
        m = np.asarray(mean, dtype=float)
        s = np.nan_to_num(np.asarray(std, dtype=float))
        h = np.arange(1, len(m) + 1)
        out = ~(np.isfinite(m) & (m <= top))
        label = labels[name]
        if out.any():
            label += f" (leaves the plot at h={int(h[out][0])})"
        ok = np.isfinite(m)
        ax.plot(h[ok], m[ok], marker="o", ms=3, label=label)
        ax.fill_between(h[ok], np.maximum(m[ok] - s[ok], m[ok] * 0.5), m[ok] + s[ok], alpha=0.15)
    steps = max((len(m) for m, _ in curves.values()), default=1)
    for (label, errors), style in zip((references or {}).items(), ("--", ":", "-."), strict=False):
        if np.ndim(errors) == 0:
            errors = [float(errors)] * steps
        ax.plot(np.arange(1, len(errors) + 1), errors, style, color="0.4", label=label)
    ax.set(xlabel="prediction horizon (pushes)", ylabel=ylabel, title=title, yscale=yscale)
    if np.isfinite(top):
        ax.set_ylim(top=top)
    if yscale == "linear":
        ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return _save(fig, path)


def control_bars(models: Sequence[str], labels: Mapping[str, str],
                 bars: Mapping[str, Mapping[str, float]], plan_ms: Mapping[str, float],
                 path: Path) -> Path:
    """Left: success rate per model for each condition; right: latent planning ms per step."""
    fig, axes = _figure(1, 2, figsize=(12, 4), width_ratios=(2, 1))
    ax, ax2 = axes[0]
    x = np.arange(len(models))
    width = 0.8 / max(len(bars), 1)
    for k, (cond, values) in enumerate(bars.items()):
        ax.bar(x + (k - (len(bars) - 1) / 2) * width,
               [100 * np.nan_to_num(values.get(m, np.nan)) for m in models], width, label=cond)
    ax.set_xticks(x, [labels[m] for m in models], rotation=20, fontsize=8)
    ax.set(ylabel="success rate (%)", ylim=(0, 105), title="closed-loop success")
    ax.legend(fontsize=7)
    ax.grid(axis="y", alpha=0.3)
    ax2.bar(x, [plan_ms.get(m, np.nan) for m in models], color="gray")
    ax2.set_xticks(x, [labels[m] for m in models], rotation=20, fontsize=8)
    ax2.set(ylabel="ms per control step", title="latent MPPI planning time")
    ax2.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    return _save(fig, path)


#: Marker of each dynamics kind in :func:`overview_figure`.
_MARKERS = {"sindy": "o", "linear": "s", "mlp": "^"}


def overview_figure(view: Overview, path: Path) -> Path:
    """Left: closed-loop success on the random tasks per model, under the 0.1 m criterion and
    the strict one, with 95 % Wilson intervals (best at the top). Right: active dynamics terms
    (a dense network: its parameters) against the prediction error, a point per model,
    numbered as the rows. 1150 px wide, short enough to share a screen with the table."""
    rows = view.rows
    n = len(rows)
    height = min(2.8, max(2.2, 0.8 + 0.11 * n))
    fig, axes = _figure(1, 2, figsize=(11.5, height), width_ratios=(1.2, 1))
    ax, ax2 = axes[0]
    y = np.arange(n)[::-1].astype(float)  # row 1 at the top
    for off, crit, style in ((0.17, "coarse", dict(fmt="o", mfc="white", color="C0")),
                             (-0.17, "strict", dict(fmt="o", color="C3"))):
        succ = [getattr(r, crit) for r in rows]
        has = np.array([s.n > 0 for s in succ])
        rate = np.array([100 * s.rate for s in succ])
        lo = np.array([100 * s.interval[0] for s in succ])
        hi = np.array([100 * s.interval[1] for s in succ])
        label = "within 0.1 m" if crit == "coarse" else "within 2 cm and 10°"
        xerr = np.maximum(0.0, [rate[has] - lo[has], hi[has] - rate[has]])  # rounding at 0, 1
        ax.errorbar(rate[has], y[has] + off, xerr=xerr,
                    ms=3.5, elinewidth=1, capsize=1.5, label=label, **style)
    ax.set_yticks(y, [f"{i} {r.label}" for i, r in enumerate(rows, start=1)], fontsize=6)
    ax.set_ylim(-0.7, n - 0.3)
    ax.set_xlim(-2, 102)
    ax.set_xlabel("success on random tasks, latent MPPI (%, 95% interval)", fontsize=7)
    ax.tick_params(axis="x", labelsize=7)
    ax.grid(axis="x", alpha=0.3)
    ax.legend(fontsize=6, ncol=2, loc="lower left", bbox_to_anchor=(0, 1), frameon=False,
              borderaxespad=0.2)

    left_out = []
    for i, r in enumerate(rows, start=1):
        x = None if r.active is None else r.active.mean
        e = None if r.error is None else r.error.mean
        if x is None or e is None or not (np.isfinite(x) and np.isfinite(e) and x > 0 and e > 0):
            left_out.append(str(i))
            continue
        color = "C1" if r.observes == "state" else "C0"
        ax2.errorbar(x, e, yerr=np.nan_to_num(r.error.std or 0.0), fmt=_MARKERS.get(
            r.dynamics, "D"), color=color, ms=4, elinewidth=0.8, capsize=1.5)
        ax2.annotate(str(i), (x, e), xytext=(3, 2), textcoords="offset points", fontsize=6)
    ax2.set_xscale("log")
    ax2.margins(0.08)
    errors = [r.error.mean for r in rows if r.error is not None and r.error.mean
              and np.isfinite(r.error.mean) and r.error.mean > 0]
    if errors and max(errors) > 4 * min(errors):
        ax2.set_yscale("log")
        ax2.yaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        ax2.yaxis.set_major_formatter(FormatStrFormatter("%g"))
        ax2.yaxis.set_minor_formatter(NullFormatter())
    missing = f"; not shown: {', '.join(left_out)}" if left_out else ""
    ax2.set_xlabel(f"active dynamics terms (dense: parameters){missing}", fontsize=7)
    ax2.set_ylabel(view.error_short, fontsize=7)
    ax2.tick_params(labelsize=7)
    ax2.grid(alpha=0.3, which="both")
    kinds = [Line2D([], [], ls="", marker=mk, color="0.4", ms=4, label=k)
             for k, mk in (("SINDy", "o"), ("linear", "s"), ("MLP", "^"))]
    kinds += [Line2D([], [], ls="", marker="o", color=c, ms=4, label=lab)
              for c, lab in (("C0", "sees images"), ("C1", "sees the true state"))]
    ax2.legend(handles=kinds, fontsize=6, ncol=5, loc="lower left", bbox_to_anchor=(0, 1),
               frameon=False, handletextpad=0.2, columnspacing=0.8, borderaxespad=0.2)
    fig.tight_layout(pad=0.4, w_pad=1.0)
    return _save(fig, path, dpi=100)
