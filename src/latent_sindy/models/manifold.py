"""Geodesic coordinates of points on a curve or surface in a high-dimensional space (Isomap).

Frames of one moving thing lie on a curve in pixel space (a surface for two motions, a circle
for a turning one); distances along it are distances of the thing's path, so coordinates that
keep them are coordinates of the motion, found from the frames alone:

1. landmarks spread over the points by farthest-point sampling (:func:`farthest_points`);
2. a graph of each landmark's nearest neighbours, joined by a minimum spanning tree so that
   it is connected, each edge shortened by what pixel noise adds to it (:func:`noise_floor`);
3. shortest paths along the graph (Floyd-Warshall) and classical scaling of those distances
   (Tenenbaum et al. 2000), the leading ``dim`` axes kept;
4. any other point's coordinates interpolated from its nearest landmarks
   (:meth:`Manifold.transform`), or read on the nearest landmarks' tangents
   (:meth:`Manifold.project`: noise across the curve does not move them), with how far the
   point is from the landmarks (:meth:`Manifold.covers`: a point beyond the frames the
   landmarks were spread over gets no coordinate one can trust).

    >>> manifold = geodesic_coordinates(points, dim=2, seed=0)   # points (N, K)
    >>> coords = manifold.transform(points)                        # (N, 2)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

__all__ = ["LANDMARKS", "NEIGHBOURS", "Manifold", "farthest_points", "geodesic_coordinates",
           "noise_floor", "principal_front"]

#: Landmarks the geodesic coordinates are computed on (the others are interpolated).
LANDMARKS = 1000
#: Each landmark's graph neighbours.
NEIGHBOURS = 10
#: The nearest neighbours, and the points they are taken of, that :func:`noise_floor` reads.
FLOOR_NEIGHBOURS = 8
FLOOR_SAMPLE = 2000

@dataclass
class Manifold:
    """Geodesic coordinates on landmarks, and their interpolation elsewhere."""

    landmarks: torch.Tensor   # (L, K)
    coords: torch.Tensor      # (L, dim)
    eigenvalues: torch.Tensor  # the scaling's leading eigenvalues (L,), largest first
    covering: float = math.inf
    """The farthest any of the points the landmarks were spread over lies from its nearest
    landmark (the farthest-point sampling's last distance)."""
    metric: torch.Tensor | None = None
    """R (K, K): distances are ‖R (x − x')‖, the points mapped to x Rᵀ before anything else
    (the landmarks are stored mapped); None: Euclidean."""
    _gradients: torch.Tensor | None = field(default=None, init=False, repr=False)

    def mapped(self, points: torch.Tensor) -> torch.Tensor:
        """``points`` (N, K) in float64, mapped by :attr:`metric` where there is one."""
        return _mapped(points, self.metric)

    def transform(self, points: torch.Tensor, chunk: int = 4096) -> torch.Tensor:
        """(N, dim): inverse-distance weighting of the nearest landmarks' coordinates."""
        out = []
        k = min(NEIGHBOURS, len(self.landmarks))
        for part in self.mapped(points).split(chunk):
            d = torch.cdist(part, self.landmarks)
            near, j = d.topk(k, largest=False)
            w = 1.0 / (near + 1e-12)
            w = w / w.sum(1, keepdim=True)
            out.append((w.unsqueeze(-1) * self.coords[j]).sum(1))
        return torch.cat(out)

    def covers(self, points: torch.Tensor, slack: float = 2.0, chunk: int = 4096
               ) -> torch.Tensor:
        """(N,) bool: the points within ``slack`` times :attr:`covering` of a landmark
        (the others lie beyond what the landmarks were spread over)."""
        near = torch.cat([torch.cdist(part, self.landmarks).min(1).values
                          for part in self.mapped(points).split(chunk)])
        return near <= slack * self.covering

    def project(self, points: torch.Tensor, near: int = 3, chunk: int = 4096
                ) -> torch.Tensor:
        """(N, dim): each point's coordinates read on its ``near`` nearest landmarks'
        tangents (a landmark's coordinates plus the gradient of the coordinates along the
        tangent plane of its neighbours, :meth:`gradients`, times the point's offset),
        weighted towards the nearest. Pixel noise across the curve moves the coordinates of
        :meth:`transform` (which landmarks are nearest changes); here only its share along
        the tangents does."""
        grads = self.gradients()
        out = []
        for x in self.mapped(points).split(chunk):
            d, j = torch.cdist(x, self.landmarks).topk(min(near, len(self.landmarks)),
                                                       largest=False)
            w = torch.softmax(-(d / d[:, :1].clamp_min(1e-12)).square(), 1)
            est = self.coords[j] + torch.einsum("nmk,nmkd->nmd", x[:, None] - self.landmarks[j],
                                                grads[j])
            out.append((w.unsqueeze(-1) * est).sum(1))
        return torch.cat(out)

    def gradients(self, neighbours: int = NEIGHBOURS) -> torch.Tensor:
        """(L, K, dim): on each landmark, the coordinates' gradient within the tangent plane
        of its ``neighbours`` nearest landmarks (their offsets' leading ``dim`` principal
        directions), by least squares of the neighbours' coordinate differences."""
        if self._gradients is None:
            dim = self.coords.shape[1]
            k = min(neighbours + 1, len(self.landmarks))
            nb = torch.cdist(self.landmarks, self.landmarks).topk(k, largest=False).indices
            dx = self.landmarks[nb] - self.landmarks[:, None]       # (L, k, K)
            ds = self.coords[nb] - self.coords[:, None]             # (L, k, dim)
            tangent = torch.linalg.svd(dx, full_matrices=False)[2][:, :dim]  # (L, dim, K)
            along = dx @ tangent.transpose(1, 2)                    # (L, k, dim)
            g = torch.linalg.lstsq(along, ds).solution              # (L, dim, dim)
            self._gradients = tangent.transpose(1, 2) @ g           # (L, K, dim)
        return self._gradients


def _mapped(points: torch.Tensor, metric: torch.Tensor | None) -> torch.Tensor:
    """``points`` (N, K) in float64, as x Rᵀ with ``metric`` R (K, K) (None: as they are)."""
    x = points.double()
    return x if metric is None else x @ metric.T


def farthest_points(points: torch.Tensor, count: int, first: int = 0) -> torch.Tensor:
    """Indices of ``count`` points spread over ``points`` (N, K): each the farthest from
    those chosen before it, from ``first``."""
    chosen = [first]
    nearest = (points - points[first]).square().sum(1)
    for _ in range(min(count, len(points)) - 1):
        j = int(nearest.argmax())
        chosen.append(j)
        nearest = torch.minimum(nearest, (points - points[j]).square().sum(1))
    return torch.tensor(chosen)


def _spanning_tree(d: torch.Tensor) -> list[tuple[int, int]]:
    """The edges of a minimum spanning tree of the complete graph of distances ``d`` (Prim)."""
    n = len(d)
    inside = torch.zeros(n, dtype=torch.bool)
    inside[0] = True
    best = d[0].clone()
    parent = torch.zeros(n, dtype=torch.long)
    edges = []
    for _ in range(n - 1):
        cost = best.masked_fill(inside, math.inf)
        j = int(cost.argmin())
        edges.append((int(parent[j]), j))
        inside[j] = True
        closer = d[j] < best
        best = torch.where(closer, d[j], best)
        parent = torch.where(closer, torch.full_like(parent, j), parent)
    return edges


def noise_floor(points: torch.Tensor, dim: int, neighbours: int = FLOOR_NEIGHBOURS,
                sample: int = FLOOR_SAMPLE, seed: int = 0) -> float:
    """The squared distance that noise alone puts between any two of ``points`` (N, K) on a
    ``dim``-dimensional manifold: on a densely sampled manifold the j-th nearest neighbour
    lies j^(1/dim) spacings away, so its squared distance is a + b j^(2/dim), and a, the
    line's intercept through the medians over ``sample`` points of each j up to
    ``neighbours``, is what noise adds to every squared distance (about 0 without noise)."""
    # (a point repeated, as a frame in several overlapping windows, counts once)
    x = torch.unique(points.double(), dim=0)
    gen = torch.Generator().manual_seed(seed)
    pick = torch.randperm(len(x), generator=gen)[:sample]
    k = min(neighbours, len(x) - 1)
    if k < 2:
        return 0.0
    near = torch.cat([torch.cdist(part, x).topk(k + 1, largest=False).values[:, 1:]
                      for part in x[pick].split(512)])
    median = near.square().median(0).values  # (k,)
    rank = torch.arange(1, k + 1, dtype=x.dtype) ** (2.0 / dim)
    line = torch.stack([torch.ones_like(rank), rank], 1)
    a = torch.linalg.lstsq(line, median[:, None]).solution[0, 0]
    return float(a.clamp_min(0.0))


def geodesic_coordinates(points: torch.Tensor, dim: int, landmarks: int = LANDMARKS,
                         neighbours: int = NEIGHBOURS, seed: int = 0,
                         denoise: bool = True, metric: torch.Tensor | None = None
                         ) -> Manifold:
    """Isomap coordinates (``dim`` of them) of ``points`` (N, K) on ``landmarks`` spread by
    farthest-point sampling from a first point chosen by ``seed``, distances measured as
    ‖R (x − x')‖ with ``metric`` R (K, K) (None: Euclidean). With ``denoise``, each
    graph edge is shortened by what noise adds to it (:func:`noise_floor`): noise lengthens
    every edge alike, so a path through densely sampled stretches (many short edges) would
    count it more often than one through sparse stretches, and the coordinate would stretch
    where the frames are many."""
    metric = None if metric is None else metric.double()
    x = _mapped(points, metric)
    floor = noise_floor(x, dim, seed=seed) if denoise else 0.0
    first = int(torch.randint(len(x), (1,), generator=torch.Generator().manual_seed(seed)))
    idx = farthest_points(x, landmarks, first)
    lm = x[idx]
    d = torch.cdist(lm, lm)
    if floor > 0:
        d = (d.square() - floor).clamp_min(0.0).sqrt()
    n = len(lm)
    graph = torch.full_like(d, math.inf)
    k = min(neighbours + 1, n)
    near, j = d.topk(k, largest=False)
    graph.scatter_(1, j, near)
    graph = torch.minimum(graph, graph.T)
    for a, b in _spanning_tree(d):
        graph[a, b] = graph[b, a] = d[a, b]
    graph.fill_diagonal_(0.0)
    for m in range(n):  # Floyd-Warshall
        graph = torch.minimum(graph, graph[:, m:m + 1] + graph[m:m + 1, :])
    centre = torch.eye(n, dtype=x.dtype) - 1.0 / n
    b = -0.5 * centre @ graph.square() @ centre
    values, vectors = torch.linalg.eigh(b)
    values, vectors = values.flip(0), vectors.flip(1)
    coords = vectors[:, :dim] * values[:dim].clamp_min(0).sqrt()
    covering = max(float(torch.cdist(part, lm).min(1).values.max()) for part in x.split(4096))
    return Manifold(lm, coords, values, covering, metric)


def principal_front(x: torch.Tensor, components: int, seed: int = 0
                    ) -> tuple[torch.Tensor, torch.Tensor]:
    """The mean (K,) and the leading ``components`` principal axes (K, q) of ``x`` (N, K),
    by a randomised decomposition seeded by ``seed`` (q = min(components, N, K))."""
    mean = x.mean(0)
    q = min(components, *x.shape)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        _, _, v = torch.pca_lowrank(x - mean, q=q, center=False, niter=4)
    return mean, v
