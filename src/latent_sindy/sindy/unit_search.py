"""A sparse law of coordinates known only up to their unit and zero.

Coordinates learned from images (the frames' geodesic coordinates) are an affine function of
the moving thing's own coordinate, z = (q − b) / a, and nothing in the frames says what a and
b are. A law with a sine in it (a pendulum's θ̈ = −ω² sin θ) is sparse at one unit and zero
only; at any other, the sine needs polynomial terms beside it. :func:`search_law` therefore
searches each latent's unit a and zero b together with its law:

1. on a grid of units and zeros, the best law of each size (1 to :data:`MAX_TERMS` terms:
   every subset of the library's columns where they are few, forward selection otherwise),
   each fitted by least squares on the training samples and scored on held-out ones;
2. the best grid point of the best laws of each size refined by Nelder-Mead (from a
   simplex of the grid's steps, begun again once where it stopped);
3. the sparsest law kept that a law of one term more does not beat by a margin (:data:`GAIN`,
   and three standard errors over the sequences) when each sequence is held out in turn
   (cross-validation over the sequences of both splits), with a
   sine kept only where its argument turns through a quarter turn or more over the data (a
   sine that does not is a line, and the plain term is preferred). A law with no sine of a
   latent says nothing of its unit: the coordinate's own is kept.

Every latent's unit and zero is searched in turn with the others' held (twice for several
latents). Nothing here knows what is filmed: the library is the caller's.

    >>> law = search_law(library, sines, phase, top, phase_val, top_val)
    >>> law.unit, law.zero, law.coef     # q = a z + b per latent; coefficients (p, nz)
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from latent_sindy.errors import UserError

__all__ = ["GAIN", "MAX_TERMS", "UnitLaw", "search_law"]

#: Most terms a law of one latent may have.
MAX_TERMS = 3
#: A law of one more term is kept where it lowers the held-out error by this share or more,
#: by :data:`FLOOR` of the held-out z̈'s variance, and by three standard errors (errors as
#: shares of the held-out variance, so that laws at other units compare). On the video
#: family's draws a true term lowered it by 98 % or more, a term that only took up a warp of
#: the coordinate by 2–11 % (RESULTS.md).
GAIN = 0.2
FLOOR = 1e-6
#: Units tried on the grid (times the coordinate's given unit), and zeros (in its units).
UNITS = tuple(float(u) for u in np.exp(np.linspace(math.log(0.25), math.log(4.0), 25)))
ZEROS = tuple(float(b) for b in np.linspace(-0.6, 0.6, 9))
#: The farthest the refinement may take a unit from the coordinate's own (a factor of
#: e^FARTHEST either way; beyond, no law is fitted).
FARTHEST = math.log(64.0)
#: The grid's steps (the log of the unit's, and the zero's): the size of the simplex the
#: refinement starts from.
UNIT_STEP = math.log(UNITS[1] / UNITS[0])
ZERO_STEP = ZEROS[1] - ZEROS[0]
#: Laws of each size refined by Nelder-Mead after the grid, a latent, on this many
#: training samples at most (evenly spaced).
REFINED = 4
REFINE_SAMPLES = 2000
#: Blocks each split is cut into where no groups are given (a group stands for a sequence).
BLOCKS = 20
#: Folds of the groups the laws of each size are compared on.
FOLDS = 10
#: Subsets of the library searched exhaustively up to this many, else forward selection.
EXHAUSTIVE = 3000

Library = Callable[[np.ndarray], np.ndarray]
"""phase (N, 2 nz) -> the library's columns (N, p)."""


@dataclass
class UnitLaw:
    """The law found: each latent's unit and zero (q = unit z + zero), the coefficients
    (p, nz) of the library on q, the held-out share of each latent's q̈ left unexplained,
    and for each latent the best law of each size (terms, held-out FVU)."""

    unit: np.ndarray
    zero: np.ndarray
    coef: np.ndarray
    fvu: np.ndarray
    paths: list[list[tuple[tuple[int, ...], float]]] = field(default_factory=list)
    gains: list[list[tuple[tuple[int, ...], float]]] = field(default_factory=list)
    """For each latent, each law of one term more weighed against the law kept so far: its
    terms and the share of that law's cross-validated error it took away (kept from
    :data:`GAIN`)."""


def _phase_at(phase: np.ndarray, unit: np.ndarray, zero: np.ndarray) -> np.ndarray:
    nz = len(unit)
    out = phase.copy()
    out[:, :nz] = unit * (phase[:, :nz] - zero)
    out[:, nz:2 * nz] = unit * phase[:, nz:2 * nz]
    return out


def _subsets(terms: list[int]) -> list[tuple[int, ...]]:
    return [s for k in range(1, MAX_TERMS + 1) for s in itertools.combinations(terms, k)]


def _best_by_size(th: np.ndarray, y: np.ndarray, thv: np.ndarray, yv: np.ndarray,
                  subsets: list[tuple[int, ...]] | None, terms: list[int]
                  ) -> list[tuple[float, tuple[int, ...]]]:
    """For each size, the :data:`REFINED` subsets with the lowest held-out FVU (the one
    with the lowest where they are found by forward selection): (fvu, subset)."""
    g, b = th.T @ th, th.T @ y
    gv, bv = thv.T @ thv, thv.T @ yv
    spread = max(float(((yv - yv.mean()) ** 2).sum()), 1e-300)
    yy = float(yv @ yv)

    def scores(chosen: np.ndarray) -> np.ndarray:  # chosen (n, k) column indices
        k = chosen.shape[1]
        gs = g[chosen[:, :, None], chosen[:, None, :]] + 1e-12 * np.trace(g) / len(g) * np.eye(k)
        c = np.linalg.solve(gs, b[chosen][..., None])[..., 0]
        rss = yy - 2 * (c * bv[chosen]).sum(1) + np.einsum(
            "ni,nij,nj->n", c, gv[chosen[:, :, None], chosen[:, None, :]], c)
        return np.where(np.isfinite(rss), rss / spread, np.inf)

    out = []
    if subsets is not None:
        for k in range(1, MAX_TERMS + 1):
            chosen = np.array([s for s in subsets if len(s) == k])
            f = scores(chosen)
            for j in np.argsort(f, kind="stable")[:REFINED]:
                out.append((float(f[j]), tuple(int(i) for i in chosen[j])))
        return out
    now: tuple[int, ...] = ()
    for _ in range(MAX_TERMS):  # forward selection
        others = [i for i in terms if i not in now]
        chosen = np.array([sorted((*now, i)) for i in others])
        f = scores(chosen)
        j = int(np.argmin(f))
        now = tuple(int(i) for i in chosen[j])
        out.append((float(f[j]), now))
    return out


def _fit(th: np.ndarray, y: np.ndarray, law: tuple[int, ...]) -> np.ndarray:
    c = np.zeros(th.shape[1])
    c[list(law)] = np.linalg.lstsq(th[:, list(law)], y, rcond=None)[0]
    return c


def search_law(library: Library, sines: Sequence[tuple[int, int, float]],
               phase: np.ndarray, top: np.ndarray, phase_val: np.ndarray,
               top_val: np.ndarray, groups: np.ndarray | None = None,
               groups_val: np.ndarray | None = None, sweeps: int | None = None,
               exclude: Sequence[int] = ()) -> UnitLaw:
    """Each latent's unit, zero and sparse law (see the module's docstring).

    Args:
        library: phase (N, 2 nz) -> columns (N, p).
        sines: the library's sine columns: (column, phase variable, frequency), the column
            being sin(frequency × that variable).
        phase: (N, 2 nz) the training samples' (z, ż); ``top``: (N, nz) their z̈.
        phase_val, top_val: held-out samples alike (the grid's laws are scored on them).
        groups, groups_val: each sample's sequence (integers; None: consecutive blocks of
            each split): the laws of each size are compared by cross-validation over the
            sequences of both splits, and a law of one term more is kept where it lowers
            their held-out error consistently.
        sweeps: passes over the latents (None: 1 for one latent, 2 for more).
        exclude: columns no law may hold (the library's constant, where the zeros searched
            stand for it).
    """
    phase, top, phase_val, top_val = (np.asarray(a, np.float64)
                                      for a in (phase, top, phase_val, top_val))
    nz = top.shape[1]
    if phase.shape[1] != 2 * nz or phase_val.shape[1] != 2 * nz or len(phase) < 10 or (
            len(phase_val) < 10):
        raise UserError(f"search_law: phase (N, 2 nz) and z'' (N, nz) with 10 samples or more "
                        f"each, got {phase.shape}, {top.shape}, {phase_val.shape}")
    if not all(np.isfinite(a).all() for a in (phase, top, phase_val, top_val)):
        raise UserError("search_law: the samples hold NaN or inf")
    p = library(phase[:2]).shape[1]
    terms = [j for j in range(p) if j not in set(exclude)]
    many = sum(math.comb(len(terms), k) for k in range(1, MAX_TERMS + 1))
    subsets = _subsets(terms) if many <= EXHAUSTIVE else None
    if groups is None or groups_val is None:
        groups = np.arange(len(phase)) * BLOCKS // len(phase)
        groups_val = BLOCKS + np.arange(len(phase_val)) * BLOCKS // len(phase_val)
    every = (np.concatenate([phase, phase_val]), np.concatenate([top, top_val]),
             np.concatenate([np.asarray(groups), np.asarray(groups_val) + np.max(groups) + 1]))
    unit = np.ones(nz)
    zero = np.zeros(nz)
    coef = np.zeros((p, nz))
    fvu = np.ones(nz)
    paths: list = [[] for _ in range(nz)]
    gains: list = [[] for _ in range(nz)]
    for _ in range(sweeps or (1 if nz == 1 else 2)):
        for i in range(nz):
            unit[i], zero[i], coef[:, i], fvu[i], paths[i], gains[i] = _search_one(
                library, sines, phase, top, phase_val, top_val, unit, zero, i, subsets, every,
                terms)
    return UnitLaw(unit, zero, coef, fvu, paths, gains)


def _search_one(library: Library, sines: Sequence[tuple[int, int, float]], phase, top,
                phase_val, top_val, unit: np.ndarray, zero: np.ndarray, i: int, subsets,
                every: tuple[np.ndarray, np.ndarray, np.ndarray], terms: list[int]):
    from scipy.optimize import minimize

    nz = len(unit)
    every_phase, every_top, groups = every

    def columns(a: float, b: float, val: bool = True) -> tuple[np.ndarray, ...]:
        u, z = unit.copy(), zero.copy()
        u[i], z[i] = a, b
        return (library(_phase_at(phase, u, z)), a * top[:, i],
                library(_phase_at(phase_val, u, z)) if val else None, a * top_val[:, i])

    few = np.linspace(0, len(phase) - 1, min(len(phase), REFINE_SAMPLES)).round().astype(int)

    found: dict[tuple[int, ...], tuple[float, float, float]] = {}
    for a in UNITS:
        for b in ZEROS:
            th, y, thv, yv = columns(unit[i] * a, zero[i] + b)
            for f, law in _best_by_size(th, y, thv, yv, subsets, terms):
                if law not in found or f < found[law][0]:
                    found[law] = (f, unit[i] * a, zero[i] + b)

    def train_fvu(x: np.ndarray, law: tuple[int, ...]) -> float:
        if not (np.isfinite(x).all() and abs(x[0] - math.log(unit[i])) <= FARTHEST):
            return math.inf  # (a simplex gone far off: no unit there to fit)
        u, z = unit.copy(), zero.copy()
        u[i], z[i] = math.exp(x[0]), x[1]
        th = library(_phase_at(phase[few], u, z))
        y = u[i] * top[few, i]
        if not np.isfinite(th).all():
            return math.inf
        c = _fit(th, y, law)
        r = y - th @ c
        return float(r @ r / max(((y - y.mean()) ** 2).sum(), 1e-300))

    candidates = []
    ranked = sorted(found.items(), key=lambda kv: kv[1][0])
    # the best of each size: on the grid a law of more terms takes up the grid's misplacement
    # of the unit and zero, and would crowd out the sparse law refinement puts right
    chosen = [kv for size in range(1, MAX_TERMS + 1)
              for kv in [kv for kv in ranked if len(kv[0]) == size][:REFINED]]
    for law, (_, a, b) in chosen:
        x = np.array([math.log(a), b])
        for _ in range(2):  # begun again from where it stopped (a simplex may collapse early)
            simplex = x + np.array([[0.0, 0.0], [UNIT_STEP, 0.0], [0.0, ZERO_STEP]])
            x = minimize(train_fvu, x, args=(law,), method="Nelder-Mead",
                         options={"xatol": 1e-5, "fatol": 1e-14, "maxiter": 300,
                                  "initial_simplex": simplex}).x
        if not np.isfinite(train_fvu(x, law)):
            continue
        a, b = math.exp(x[0]), float(x[1])
        th, y, thv, yv = columns(a, b)
        c = _fit(th, y, law)
        err = (yv - thv @ c) ** 2
        spread = max(float(((yv - yv.mean()) ** 2).sum()), 1e-300)
        excursion = {var: a * float(np.abs(every_phase[:, var] - (b if var == i else 0.0)).max())
                     for var in (i, i + nz)}
        turns = all(freq * excursion.get(var, math.inf) >= math.pi / 2
                    for col, var, freq in sines if col in law and var in excursion)
        if turns:
            candidates.append({"law": law, "unit": a, "zero": b, "coef": c,
                               "fvu": float(err.sum() / spread),
                               "sines": sum(1 for col, _, _ in sines if col in law)})
    if not candidates:
        raise UserError("search_law: no law of the library fits (every fit failed)")
    by_size: dict[int, dict] = {}
    for size in sorted({len(c["law"]) for c in candidates}):
        same = [c for c in candidates if len(c["law"]) == size]
        low = min(same, key=lambda c: c["fvu"])
        plain = [c for c in same if c["sines"] < low["sines"] and c["fvu"] <= 1.1 * low["fvu"]]
        by_size[size] = min(plain, key=lambda c: c["fvu"]) if plain else low
    sizes = sorted(by_size)
    for c in by_size.values():
        th = library(_phase_at(every_phase, *_with(unit, zero, i, c["unit"], c["zero"])))
        c["errors"] = _folded_errors(th, c["unit"] * every_top[:, i], c["law"], groups)
    chosen = by_size[sizes[0]]
    weighed = []
    for size in sizes[1:]:
        bigger = by_size[size]
        weighed.append((bigger["law"], _gain(bigger, chosen)))
        if _beats(bigger, chosen):
            chosen = bigger
    path = [(by_size[s]["law"], by_size[s]["fvu"]) for s in sizes]
    if not chosen["sines"]:  # nothing in the law fixes the unit: the coordinate's own kept
        th, y, thv, yv = columns(unit[i], chosen["zero"])
        chosen["coef"] = _fit(th, y, chosen["law"])
        err = (yv - thv @ chosen["coef"]) ** 2
        chosen["fvu"] = float(err.sum() / max(float(((yv - yv.mean()) ** 2).sum()), 1e-300))
        chosen["unit"] = unit[i]
    return chosen["unit"], chosen["zero"], chosen["coef"], chosen["fvu"], path, weighed


def _with(unit: np.ndarray, zero: np.ndarray, i: int, a: float, b: float
          ) -> tuple[np.ndarray, np.ndarray]:
    u, z = unit.copy(), zero.copy()
    u[i], z[i] = a, b
    return u, z


def _folded_errors(th: np.ndarray, y: np.ndarray, law: tuple[int, ...], groups: np.ndarray
                   ) -> np.ndarray:
    """Each group's squared error held out: the groups dealt into :data:`FOLDS` folds, each
    fold predicted by the law fitted on the others; as shares of y's variance, so that laws
    at other units compare."""
    ids = np.unique(groups)
    folds = np.searchsorted(ids, groups) % min(FOLDS, len(ids))
    err = np.empty(len(y))
    for k in np.unique(folds):
        out = folds == k
        c = _fit(th[~out], y[~out], law)
        err[out] = (y[out] - th[out] @ c) ** 2
    per_group = np.bincount(np.searchsorted(ids, groups), weights=err)
    return per_group / max(float(((y - y.mean()) ** 2).sum()), 1e-300)


def _gain(bigger: dict, smaller: dict) -> float:
    """The share of ``smaller``'s held-out error (over the groups) ``bigger`` takes away."""
    return float((smaller["errors"].sum() - bigger["errors"].sum())
                 / max(smaller["errors"].sum(), 1e-300))


def _beats(bigger: dict, smaller: dict) -> bool:
    """Whether ``bigger`` lowers the error of held-out groups by :data:`GAIN` of
    ``smaller``'s and :data:`FLOOR`, and by three standard errors of the difference over the
    groups."""
    diff = smaller["errors"] - bigger["errors"]
    if diff.sum() <= GAIN * smaller["errors"].sum() + FLOOR:
        return False
    se = diff.std(ddof=1) * math.sqrt(len(diff)) if len(diff) > 1 else 0.0
    return bool(diff.sum() > 3 * se)
