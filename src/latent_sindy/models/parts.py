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
#: The shares tried in turn until the varying pixels fall into parts: where two parts'
#: paths come near, the pixels they both light join them, and only the pixels that vary
#: most (each path's core) fall apart.
ACTIVE_SHARES = (ACTIVE, 0.05, 0.1, 0.2, 0.3)
#: The most varying pixels the graph is built on (the largest variances).
MOST_PIXELS = 3000
#: Each pixel is joined to those of this many others whose intensities correlate most with
#: it (at least :data:`LINKED`) that also count it among theirs.
NEIGHBOURS = 8
LINKED = 0.3
#: The parts kept must hold this share of the varying pixels' variance.
HELD = 0.6
#: Pixels outside the parts found varying by at least this share of the largest variance
#: are joined to the part they vary with, in up to this many rounds.
FAINT = 0.001
FAINT_ROUNDS = 20


def moving_parts(sequences: torch.Tensor, parts: int) -> list[torch.Tensor] | None:
    """Pixel indices of each of ``parts`` independently moving parts of ``sequences``
    (n, F, pixels), largest variance first; None where the varying pixels do not fall into
    ``parts`` sets that hold :data:`HELD` of their variance at any of
    :data:`ACTIVE_SHARES` (the pixels varying less then join the part they vary with)."""
    x = sequences.double().flatten(0, 1)
    var = x.var(0)
    for share in ACTIVE_SHARES:  # paths that touch join the parts: their cores apart
        groups = _parts_above(x, var, share, parts)
        if groups is not None:
            return _with_faint_pixels(x, var, groups)
    return None


def _parts_above(x: torch.Tensor, var: torch.Tensor, share: float, parts: int
                 ) -> list[torch.Tensor] | None:
    """The ``parts`` sets of the pixels varying by at least ``share`` of the largest
    variance (the connected sets of mutual links), None where they do not hold
    :data:`HELD` of those pixels' variance."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    active = torch.nonzero(var >= share * var.max()).ravel()
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


def _with_faint_pixels(x: torch.Tensor, var: torch.Tensor, groups: list[torch.Tensor]
                       ) -> list[torch.Tensor]:
    """``groups`` with the pixels outside them that vary by at least :data:`FAINT` of the
    largest variance (where a part goes rarely, as a damped pendulum's widest swings, or
    where two parts' paths come near) joined to the part whose pixels they vary with: the
    mean of a pixel's :data:`NEIGHBOURS` strongest correlations with a part's pixels at
    least :data:`LINKED`, and with no other part's; in :data:`FAINT_ROUNDS` rounds (a pixel
    joined draws in the ones beyond it)."""
    taken = torch.cat(groups)
    faint = torch.nonzero(var >= FAINT * var.max()).ravel()
    faint = faint[~torch.isin(faint, taken)]
    if len(faint) > MOST_PIXELS:
        faint = faint[var[faint].argsort(descending=True)[:MOST_PIXELS]]

    def unit(cols: torch.Tensor) -> torch.Tensor:
        a = x[:, cols] - x[:, cols].mean(0)
        return a / a.norm(dim=0).clamp_min(1e-300)

    groups = list(groups)
    for _ in range(FAINT_ROUNDS):
        if len(faint) == 0:
            break
        f = unit(faint)
        scores = torch.stack([(f.T @ unit(g)).topk(min(NEIGHBOURS, len(g)), dim=1).values
                              .mean(1) for g in groups])  # (parts, faint)
        best, which = scores.max(0)
        others = scores.clone()
        others[which, torch.arange(len(faint))] = -1.0
        join = (best >= LINKED) & (others.max(0).values < LINKED)
        if not join.any():
            break
        for c in range(len(groups)):
            groups[c] = torch.cat([groups[c], faint[join & (which == c)]])
        faint = faint[~join]
    return groups
