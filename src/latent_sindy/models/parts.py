"""The parts of a video that move independently, found from its pixels alone.

Two things that move independently (two pendulums side by side) light two sets of pixels;
within a set, pixels the same thing passes over together vary together, and across sets
they do not. :func:`moving_parts` joins each pixel that varies to the pixels whose
intensities correlate most with it and keeps the connected sets: each is one part, whose
pixels alone are a video of one motion (:mod:`~latent_sindy.models.manifold` then finds its
coordinate).

    >>> groups = moving_parts(sequences, parts=2)  # (n, F, pixels); None: not separable
    >>> [g.shape for g in groups]                     # pixel indices of each part
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["moving_parts"]

#: A pixel varies where its variance is at least this share of the largest pixel's.
ACTIVE = 0.02
#: The most varying pixels the graph is built on (the largest variances).
MOST_PIXELS = 3000
#: Each pixel is joined to those of this many others whose intensities correlate most with
#: it (at least :data:`LINKED`) that also count it among theirs.
NEIGHBOURS = 8
LINKED = 0.3
#: The parts kept must hold this share of the varying pixels' variance.
HELD = 0.6


def moving_parts(sequences: torch.Tensor, parts: int) -> list[torch.Tensor] | None:
    """Pixel indices of each of ``parts`` independently moving parts of ``sequences``
    (n, F, pixels), largest variance first; None where the varying pixels do not fall into
    ``parts`` sets that hold :data:`HELD` of their variance."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    x = sequences.double().flatten(0, 1)
    var = x.var(0)
    active = torch.nonzero(var >= ACTIVE * var.max()).ravel()
    if len(active) > MOST_PIXELS:
        active = active[var[active].argsort(descending=True)[:MOST_PIXELS]]
    if len(active) < 2 * parts:
        return None
    a = x[:, active] - x[:, active].mean(0)
    a = a / a.norm(dim=0).clamp_min(1e-300)
    corr = (a.T @ a).fill_diagonal_(-1.0)
    k = min(NEIGHBOURS, len(active) - 1)
    strength, near = corr.topk(k, dim=1)
    rows = torch.arange(len(active)).repeat_interleave(k)
    keep = strength.ravel() >= LINKED
    linked = coo_matrix((np.ones(int(keep.sum())), (rows[keep].numpy(),
                                                    near.ravel()[keep].numpy())),
                        shape=(len(active), len(active))).tocsr()
    mutual = linked.multiply(linked.T)  # a link both pixels choose: a pixel lit in a few
    # frames correlates with others by chance, and only one way
    count, label = connected_components(mutual, directed=False)
    label = torch.as_tensor(label)
    weight = torch.zeros(count, dtype=torch.float64).index_add_(0, label, var[active])
    order = weight.argsort(descending=True)[:parts]
    if len(order) < parts or weight[order].sum() < HELD * weight.sum():
        return None
    return [active[label == c] for c in order]
