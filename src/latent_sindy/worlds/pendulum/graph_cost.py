"""A latent cost that is not flat where the quadratic one is: the distance to the goal along
the data, measured over a nearest-neighbour graph of encoded training images.

The pendulum's images lie on a closed loop in the latent space (angle) thickened by the rate.
A quadratic cost to the goal's code, ‖z − z_goal‖², is a smooth function on that loop, so at
the far side (hanging) it is flat: a small swing either way changes it to second order only,
and MPPI's samples from hanging all cost alike (measured in docs/world.md). The distance
*along* the loop grows like |θ| instead, with a kink at the far side, so any swing from
hanging lowers it to first order, as Pendulum-v1's own θ² does. No true state is used: the
graph's nodes are the codes of the training images, its edges join each code to its
``neighbours`` nearest (and a spanning tree keeps it connected), and Dijkstra's shortest
paths from the goal's code give every node's distance. A latent z costs
``weight · (d(n) + ‖z − n‖)²``, n its nearest node. With ``grid`` > 0 that distance is
tabulated once on a grid of ``grid`` points per latent axis over the nodes' box and read by
multilinear interpolation (plus the distance to the box outside it): MPPI asks for H·K
latents per command, and comparing each with every node costs more than the rollout.

    >>> cost = GraphDistanceCost(codes, z_goal, neighbours=8, nodes=600, seed=0)
    >>> cost(z)                 # z (..., nz) -> (...)
    >>> cost.distance(z)        # the distance itself, in latent units
    >>> GraphDistanceCost(codes, z_goal, grid=32)  # the same, read from a table
"""

from __future__ import annotations

import heapq

import numpy as np
import torch
from torch import Tensor

from latent_sindy.errors import UserError

__all__ = ["GraphDistanceCost", "graph_distances"]


def graph_distances(points: np.ndarray, source: int, neighbours: int) -> np.ndarray:
    """Shortest-path distances (N,) from ``points[source]`` over the symmetric graph joining
    each of ``points`` (N, d) to its ``neighbours`` nearest, plus a minimum spanning tree so
    that every point is reached (Euclidean edge lengths)."""
    n = len(points)
    gap = np.sqrt(((points[:, None] - points[None]) ** 2).sum(-1))  # (N, N)
    near = np.argsort(gap, axis=1)[:, 1:neighbours + 1]  # (N, k), self left out
    edges: list[dict[int, float]] = [{} for _ in range(n)]
    for i, row in enumerate(near):
        for j in row:
            edges[i][int(j)] = edges[int(j)][i] = float(gap[i, j])
    # Prim's tree: clusters the k nearest neighbours leave apart are joined by short edges
    inside = np.zeros(n, bool)
    inside[0] = True
    best = gap[0].copy()
    parent = np.zeros(n, int)
    for _ in range(n - 1):
        j = int(np.argmin(np.where(inside, np.inf, best)))
        inside[j] = True
        edges[j][int(parent[j])] = edges[int(parent[j])][j] = float(gap[j, parent[j]])
        closer = gap[j] < best
        best[closer] = gap[j][closer]
        parent[closer] = j
    dist = np.full(n, np.inf)
    dist[source] = 0.0
    queue = [(0.0, source)]
    while queue:
        d, i = heapq.heappop(queue)
        if d > dist[i]:
            continue
        for j, w in edges[i].items():
            if d + w < dist[j]:
                dist[j] = d + w
                heapq.heappush(queue, (dist[j], j))
    return dist


class GraphDistanceCost:
    """``weight · d(z)²``: d the distance from latent z to the goal along the data's graph.

    Args:
        codes: (N, nz) latent codes of training images (the data's shape in latent space).
        z_goal: (nz,) the goal image's code; joined to the graph as one more node.
        neighbours: edges per node (k of the k-nearest-neighbour graph).
        nodes: at most this many codes are kept (drawn with ``seed``): the cost compares
            every predicted latent with every node.
        weight: scale of the squared distance.
        grid: points per latent axis of the distance's table (0: no table, exact).
    """

    def __init__(self, codes: np.ndarray | Tensor, z_goal: np.ndarray | Tensor,
                 neighbours: int = 8, nodes: int = 600, weight: float = 1.0,
                 seed: int = 0, grid: int = 0) -> None:
        codes = np.asarray(codes, np.float64)
        goal = np.asarray(z_goal, np.float64).reshape(-1)
        if codes.ndim != 2 or codes.shape[1] != goal.size or len(codes) <= neighbours:
            raise UserError(f"GraphDistanceCost needs codes (N, {goal.size}) with N > "
                            f"neighbours = {neighbours}, got shape {codes.shape}")
        if not (np.all(np.isfinite(codes)) and np.all(np.isfinite(goal))):
            raise UserError("GraphDistanceCost: the codes and the goal must be finite")
        if neighbours < 1 or nodes <= neighbours or not weight > 0:
            raise UserError(f"GraphDistanceCost: neighbours {neighbours} >= 1, nodes {nodes} "
                            f"> neighbours and weight {weight} > 0, please")
        if len(codes) > nodes:
            codes = codes[np.random.default_rng(seed).choice(len(codes), nodes, replace=False)]
        points = np.vstack([goal[None], codes])  # node 0 is the goal
        self.nodes = torch.tensor(points, dtype=torch.float32)  # (N + 1, nz)
        self.node_distance = torch.tensor(graph_distances(points, 0, neighbours),
                                          dtype=torch.float32)  # (N + 1,)
        self.weight = float(weight)
        self.table: Tensor | None = None
        if grid:
            if grid < 2 or grid ** goal.size > 2 ** 22:
                raise UserError(f"GraphDistanceCost grid {grid}: use 2 or more points per "
                                f"axis, at most 2^22 in all ({goal.size} latent axes)")
            self._tabulate(grid)

    def exact_distance(self, z: Tensor) -> Tensor:
        """The distance (...) of latents z (..., nz) from the nodes themselves."""
        flat = z.reshape(-1, z.shape[-1]).to(self.nodes.dtype)  # (M, nz)
        out = torch.empty(len(flat))
        for k in range(0, len(flat), 8192):  # chunks: (8192, N + 1) at most
            gap, nearest = torch.cdist(flat[k:k + 8192], self.nodes).min(1)
            out[k:k + 8192] = self.node_distance[nearest] + gap
        return out.reshape(z.shape[:-1])

    def _tabulate(self, grid: int) -> None:
        lo, hi = self.nodes.min(0).values, self.nodes.max(0).values  # (nz,)
        pad = 0.05 * (hi - lo) + 1e-6
        self.low, self.high = lo - pad, hi + pad
        self.cell = (self.high - self.low) / (grid - 1)  # (nz,)
        axes = [self.low[i] + self.cell[i] * torch.arange(grid) for i in range(len(lo))]
        points = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1)  # (g, ..., g, nz)
        self.table = self.exact_distance(points)  # (g, ..., g)
        nz = len(lo)
        self._corners = torch.tensor([[(c >> i) & 1 for i in range(nz)]
                                      for c in range(2 ** nz)])  # (2^nz, nz) of 0/1
        self._strides = torch.tensor([grid ** (nz - 1 - i) for i in range(nz)])  # (nz,)

    def distance(self, z: Tensor) -> Tensor:
        """The distance (...) to the goal along the graph of latents z (..., nz)."""
        if self.table is None:
            return self.exact_distance(z)
        flat = z.reshape(-1, z.shape[-1]).to(self.nodes.dtype)  # (M, nz)
        finite = torch.isfinite(flat).all(-1)  # (M,): a diverged rollout costs inf
        flat = torch.where(finite[:, None], flat, self.low)
        inside = torch.maximum(torch.minimum(flat, self.high), self.low)  # (M, nz)
        outside = (flat - inside).norm(dim=-1)  # (M,): 0 within the table's box
        pos = (inside - self.low) / self.cell  # (M, nz) in cells
        g = self.table.shape[0]
        base = pos.floor().clamp(0, g - 2)  # (M, nz)
        frac = pos - base  # (M, nz) in [0, 1]
        idx = base.long() @ self._strides  # (M,)
        out = torch.zeros(len(flat))
        table = self.table.reshape(-1)
        for corner in self._corners:  # 2^nz corners of each point's cell
            w = torch.where(corner.bool(), frac, 1 - frac).prod(-1)  # (M,)
            out += w * table[idx + corner @ self._strides]
        out = torch.where(finite, out + outside, torch.inf)
        return out.reshape(z.shape[:-1])

    def __call__(self, z: Tensor) -> Tensor:
        return self.weight * self.distance(z).square()
