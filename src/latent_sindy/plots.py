"""The one loss-history plot, drawn for a single run (RUN/loss.png) and for a whole study.

    from latent_sindy.plots import loss_histories
    loss_histories({"sindy2": rows}, {"sindy2": "SINDy-2"}, Path("loss.png"))
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

__all__ = ["loss_histories"]


def loss_histories(histories: Mapping[str, list[Mapping]], labels: Mapping[str, str],
                   path: Path, dpi: int = 110) -> Path:
    """Train (left) and validation (right) objective per epoch, log scale; one line per run.

    ``histories`` maps a run's name to its metrics rows (``epoch``, ``train/objective``,
    ``val/objective``, ``sindy/pruned``); with one run, dotted lines mark SINDy prunings.
    Written atomically.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from latent_sindy.atomic import write_atomic

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True, squeeze=False)
    axes = axes[0]
    for ax, split in zip(axes, ("train", "val"), strict=True):
        for name, rows in histories.items():
            pts = [(r["epoch"], r[f"{split}/objective"]) for r in rows
                   if r.get(f"{split}/objective") is not None]
            if pts:
                ax.plot(*zip(*pts, strict=True), label=labels.get(name, name), lw=1.2)
            if len(histories) == 1:
                for r in rows:
                    if r.get("sindy/pruned"):
                        ax.axvline(r["epoch"], color="gray", lw=0.5, ls=":")
        ax.set(title=f"{'training' if split == 'train' else 'validation'} loss",
               xlabel="epoch", yscale="log")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("objective (recon + λ1 pred_x + λ2 pred_z)")
    if any(axes[1].get_lines()):
        axes[1].legend(fontsize=8)
    fig.tight_layout()
    try:
        write_atomic(path, lambda f: fig.savefig(f, format="png", dpi=dpi))
    finally:
        plt.close(fig)
    return path
