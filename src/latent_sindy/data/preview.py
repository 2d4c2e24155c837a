"""A picture of a trajectory file: a grid of camera images, one row per trajectory (colour
for three channels, else the first channel in grey).

    latent-sindy preview data/push.h5 --out data/push.png
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from latent_sindy.atomic import atomic_path
from latent_sindy.data import SPLITS, SequenceData
from latent_sindy.errors import UserError


def save_preview(data: SequenceData, out: str | os.PathLike, rows: int = 6) -> Path:
    """Save a PNG grid of the first `rows` sequences (every frame), labelled with the first
    two states where the data have states. Colour images (C = 3) show as colour, any other
    channel count as its first channel in grey."""
    if data.n == 0:
        raise UserError(f"{data.source} holds no sequences: there is nothing to preview")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = max(1, min(rows, data.n))
    cols = data.steps + 1
    fig, axes = plt.subplots(rows, cols, figsize=(1.1 * cols, 1.25 * rows), squeeze=False)
    for r in range(rows):
        for t in range(cols):
            ax = axes[r, t]
            img = data.images[r, t]  # (C, H, W)
            top = data.pixel_scale()
            if img.shape[0] == 3:
                ax.imshow(np.moveaxis(img, 0, -1), interpolation="nearest")
            else:  # gray, or channels that are no colours (stacked frames, masks)
                ax.imshow(img[0], cmap="gray", vmin=0, vmax=top, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if data.states is not None:  # the first two states under each frame
                ax.set_xlabel(",".join(f"{v:.2f}" for v in data.states[r, t, :2]), fontsize=6,
                              labelpad=1)
            if r == 0:
                ax.set_title(f"t={t}", fontsize=7)
        axes[r, 0].set_ylabel(f"#{r} {SPLITS[data.split_ids[r]]}", fontsize=7)
    names = ", ".join(data.state_names[:2])
    c = data.frame_shape[0]
    fig.suptitle(f"{Path(data.source).name}: first {rows} of {data.n} sequences"
                 + ("" if c in (1, 3) else f", channel 0 of {c}")
                 + (f" (labels: {names})" if names else ""), fontsize=8)
    fig.tight_layout()
    out = Path(out)
    try:
        with atomic_path(out) as tmp:
            fig.savefig(tmp, dpi=110, format="png")
    finally:
        plt.close(fig)
    return out
