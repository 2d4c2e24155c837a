"""A SINDy step for control: only the active library terms, evaluated feature-major.

``SparseSindyDynamics.step`` builds Θ_S sample-major, (K, |S|): every library term is a
column gather from the feature matrix F (K, n_features). Here the same arithmetic runs on
the transposes, so every gather copies whole contiguous rows of K values, and the identity
and the coefficients fold into one ``addmm``:

    z_{t+1}ᵀ = z_tᵀ + C_Sᵀ Θ_Sᵀ,   Θ_Sᵀ[s] = Π_k Fᵀ[table[s, k]]    (Fᵀ: (n_features, K))

Fᵀ lives in a buffer reused across calls, holding only the sines and cosines that some term
uses. The step returns the transposed result as a (K, nz) view, so the next step's ``zᵀ`` is
contiguous again. Results equal the model's own step to float rounding (checked on a probe
batch when the step is built).

    >>> step = SparseSindyStep(model)  # model: SindyDynamics (pruned) or its compile_sparse()
    >>> z_next = step(z, u)  # z (K, nz), u (K, nu) -> (K, nz)
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from latent_sindy.models.dynamics import SindyDynamics, SparseSindyDynamics

__all__ = ["SparseSindyStep"]


class SparseSindyStep:
    """Frozen, feature-major evaluation of ``z + Θ_S(z, u) C_S`` over the active terms S.

    Built from a :class:`SindyDynamics` (compiled to its active terms first: a snapshot, so
    build again after further training or pruning) or a :class:`SparseSindyDynamics`.
    The library's feature vector is ``F = [z, u, 1, sin z, cos z]`` (see
    :mod:`latent_sindy.sindy.library`); ``n_terms`` is |S|.

    Made for control: no gradient flows through it (inputs are detached when autograd is on),
    and its buffers make one object unsafe to call from two threads at once.
    """

    def __init__(self, model: SindyDynamics | SparseSindyDynamics) -> None:
        sparse = model.compile_sparse() if isinstance(model, SindyDynamics) else model
        if not isinstance(sparse, SparseSindyDynamics):
            raise TypeError(f"SparseSindyStep needs a SINDy model, got {type(model).__name__}")
        nz, nu = sparse.nz, sparse.nu
        one = nz + nu  # library row of the constant; sin z_i at one + 1 + i, cos at + nz
        table = sparse.library.table  # (|S|, order) indices into the library's F
        # Our Fᵀ keeps only the sines and cosines some active term uses: remap the table.
        used = torch.zeros(one + 1 + 2 * nz, dtype=torch.bool)
        used[table.flatten()] = True
        remap = torch.arange(one + 1 + 2 * nz)
        self._trig: list[tuple[Callable[..., Tensor], Tensor | None]] = []
        n_features = one + 1
        for fn, first in ((torch.sin, one + 1), (torch.cos, one + 1 + nz)):
            variables = used[first : first + nz].nonzero().flatten()  # (n_vars,)
            if variables.numel():
                remap[first + variables] = n_features + torch.arange(variables.numel())
                n_features += variables.numel()
                self._trig.append((fn, None if variables.numel() == nz else variables))
        table = remap[table]
        # Terms of highest degree first, so slot k multiplies a leading block of rows only.
        degree = (table != one).sum(1)
        perm = torch.argsort(degree, descending=True, stable=True)
        table, degree = table[perm], degree[perm]
        self.nz, self.nu = nz, nu
        self.n_terms = int(table.shape[0])
        self._n_features = n_features
        cols = table.T.contiguous()  # (order, |S|)
        self._first = cols[0]  # (|S|,)
        # Slot k > 0 multiplies the rows of degree > k, a leading block: (rows, their feature
        # indices). Past 3/4 of all rows, all rows (lower degrees pad with the constant 1.0:
        # exact) cost less than the slicing.
        self._slots: list[tuple[int | None, Tensor]] = []
        for k in range(1, cols.shape[0]):
            n = int((degree > k).sum())
            if n > 0:
                full = n > 0.75 * self.n_terms
                self._slots.append((None, cols[k]) if full else (n, cols[k, :n].contiguous()))
        self._coef_t = sparse.coef[perm].T.contiguous()  # (nz, |S|)
        self._buffers: dict[tuple, tuple[Tensor, Tensor, Tensor, list[Tensor]]] = {}
        self._check(sparse)

    def _features(self, z: Tensor) -> tuple[Tensor, Tensor, Tensor, list[Tensor]]:
        """Reused Fᵀ buffer for this batch, with views of its z, u and trig rows."""
        key = (z.shape[0], z.dtype, z.device)
        views = self._buffers.get(key)
        if views is None:
            nz, nu = self.nz, self.nu
            with torch.inference_mode(False):  # a normal tensor: usable in and out of it
                f = z.new_empty(self._n_features, z.shape[0])  # (n_features, K)
            f[nz + nu] = 1.0
            trig, row = [], nz + nu + 1
            for _, variables in self._trig:
                n = nz if variables is None else variables.numel()
                trig.append(f[row : row + n])
                row += n
            views = self._buffers[key] = (f, f[:nz], f[nz : nz + nu], trig)
        return views

    def __call__(self, z: Tensor, u: Tensor) -> Tensor:
        if torch.is_grad_enabled():  # keep the reused buffer out of autograd graphs
            z, u = z.detach(), u.detach()
        zt = z.T  # (nz, K)
        f, f_z, f_u, f_trig = self._features(z)
        f_z.copy_(zt)
        f_u.copy_(u.T)
        for (fn, variables), out in zip(self._trig, f_trig, strict=True):  # sin, cos in use
            fn(zt if variables is None else zt.index_select(0, variables), out=out)
        theta = f.index_select(0, self._first)  # (|S|, K)
        for n, cols in self._slots:  # at most order - 1 slots
            (theta if n is None else theta[:n]).mul_(f.index_select(0, cols))
        return torch.addmm(zt, self._coef_t, theta).T  # (K, nz), a transposed view

    step = __call__

    @torch.no_grad()
    def _check(self, sparse: SparseSindyDynamics) -> None:
        """Compare with the model's own step on a probe batch: guards the feature layout."""
        gen = torch.Generator().manual_seed(0)
        dtype = self._coef_t.dtype
        z = torch.randn(7, self.nz, generator=gen, dtype=dtype).to(self._coef_t.device) * 0.5
        u = torch.randn(7, self.nu, generator=gen, dtype=dtype).to(self._coef_t.device) * 0.5
        want, got = sparse.step(z, u), self(z, u)
        scale = 1.0 + want.abs().max()
        if not bool(((want - got).abs() <= 1e-4 * scale).all()):
            raise RuntimeError(
                "SparseSindyStep disagrees with SparseSindyDynamics.step (max difference "
                f"{float((want - got).abs().max()):.3g}): the library's feature layout "
                "[z, u, 1, sin z, cos z] has changed; update latent_sindy/control/sindy_step.py"
            )
