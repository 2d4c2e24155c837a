"""Geodesic coordinates of points on a curve or surface in a high-dimensional space (Isomap).

Frames of one moving thing lie on a curve in pixel space (a surface for two motions, a circle
for a turning one); distances along it are distances of the thing's path, so coordinates that
keep them are coordinates of the motion, found from the frames alone:

1. landmarks spread over the points by farthest-point sampling (:func:`farthest_points`);
2. a graph of each landmark's nearest neighbours, joined by a minimum spanning tree so that
   it is connected;
3. shortest paths along the graph (Floyd-Warshall) and classical scaling of those distances
   (Tenenbaum et al. 2000), the leading ``dim`` axes kept;
4. any other point's coordinates interpolated from its nearest landmarks
   (:meth:`Manifold.transform`).

    >>> manifold = geodesic_coordinates(points, dim=2, seed=0)   # points (N, K)
    >>> coords = manifold.transform(points)                        # (N, 2)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

__all__ = ["LANDMARKS", "NEIGHBOURS", "Manifold", "farthest_points", "geodesic_coordinates",
           "principal_front"]

#: Landmarks the geodesic coordinates are computed on (the others are interpolated).
LANDMARKS = 1000
#: Each landmark's graph neighbours.
NEIGHBOURS = 10

@dataclass
class Manifold:
    """Geodesic coordinates on landmarks, and their interpolation elsewhere."""

    landmarks: torch.Tensor   # (L, K)
    coords: torch.Tensor      # (L, dim)
    eigenvalues: torch.Tensor  # the scaling's leading eigenvalues (L,), largest first

    def transform(self, points: torch.Tensor, chunk: int = 4096) -> torch.Tensor:
        """(N, dim): inverse-distance weighting of the nearest landmarks' coordinates."""
        out = []
        k = min(NEIGHBOURS, len(self.landmarks))
        for part in points.split(chunk):
            d = torch.cdist(part.double(), self.landmarks)
            near, j = d.topk(k, largest=False)
            w = 1.0 / (near + 1e-12)
            w = w / w.sum(1, keepdim=True)
            out.append((w.unsqueeze(-1) * self.coords[j]).sum(1))
        return torch.cat(out)


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


def geodesic_coordinates(points: torch.Tensor, dim: int, landmarks: int = LANDMARKS,
                         neighbours: int = NEIGHBOURS, seed: int = 0) -> Manifold:
    """Isomap coordinates (``dim`` of them) of ``points`` (N, K) on ``landmarks`` spread by
    farthest-point sampling from a first point chosen by ``seed``."""
    x = points.double()
    first = int(torch.randint(len(x), (1,), generator=torch.Generator().manual_seed(seed)))
    idx = farthest_points(x, landmarks, first)
    lm = x[idx]
    d = torch.cdist(lm, lm)
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
    return Manifold(lm, coords, values)


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
