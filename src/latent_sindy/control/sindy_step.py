"""A SINDy step for control: one fused CPU kernel over the active library terms.

MPPI rolls K samples through the dynamics over H steps per command. A pruned SINDy model's
step ``z + Θ_S(z, u) C_S`` touches |S| active terms but only nnz(C_S) nonzero coefficients
(a term is often active in one or two latent states). In torch every term costs a gather and
a multiply over all K samples and the coefficients a dense (K, |S|) @ (|S|, nz) product; here
one numba kernel (:mod:`latent_sindy.control._sindy_kernel`) does it in a single pass over
cache-sized blocks of samples, for one step or a whole horizon:

    out_i = z_i + b_i + Σ_{(s, i, c) ∈ nnz(C_S)} c · θ_s,   θ_s = Π_k F[term_s[k]]

with F = [z, u, derived, trig] for the block (the derived variables of a library with a
``DerivedVariables`` node, from the numba function the node supplies; only the sines and
cosines some term uses, of states, actions or derived variables, from the kernel's own
vectorisable sine; a cosine is a sine shifted by π/2) and b the constant term's
coefficients. A model with a ``circle`` (a, b) (a pose latent's angle
features) then has (out_a, out_b) divided by their norm, in the same pass, before the next
step reads them: the projection of ``LatentDynamics.step`` (for a model with ``turn``,
after turning (z_a, z_b) by the angle out_a - z_a). Terms are sorted
lexicographically so a term reuses its predecessor's partial product over their common
prefix (x0 x1 x2 after x0 x1: one multiply). Everything runs feature-major (nz, K): ``step``
returns a transposed view, so the next step's input is contiguous again, and ``rollout`` a
permuted one. Results equal the model's own step to float rounding (checked on a probe batch
when the step is built; tested for orders 1-4, libraries with trig of states and of actions,
and pose latents with and without the circle).

On devices other than the CPU, and for derived variables whose node supplies no numba
function, the model's sparse torch step (projection included) runs instead.

    >>> step = SindyKernelStep(model)  # model: SindyDynamics (pruned) or its compile_sparse()
    >>> z_next = step(z, u)  # z (K, nz), u (K, nu) -> (K, nz)
    >>> zs = step.rollout(z0, actions)  # (K, nz), (K, H, nu) -> (K, H+1, nz)
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np
import torch
from torch import Tensor

from latent_sindy.models.dynamics import CompiledSindy, SindyDynamics

__all__ = ["SindyKernelStep"]

_FLOATS = (torch.float32, torch.float64)

#: Samples per block of the kernel: features, partial products and outputs of one block stay
#: in cache (measured fastest at K = 1000 on the development machine; BENCHMARKS.md).
BLOCK = 512


@functools.cache
def _kernel() -> Callable[..., None]:
    """The numba kernel: numba is imported on first use, which compiles the kernel once per
    dtype and layout (about a second; numba caches it on disk for later processes)."""
    from latent_sindy.control._sindy_kernel import sindy_rollout_kernel

    return sindy_rollout_kernel


class SindyKernelStep:
    """Frozen, fused evaluation of ``z + Θ_S(z, u) C_S`` over the active terms S.

    Built from a :class:`SindyDynamics` (compiled to its active terms first: a snapshot, so
    build again after further training or pruning) or a :class:`CompiledSindy`.
    ``n_terms`` is |S| and ``n_coefficients`` the number of nonzero coefficients; ``circle``
    is the model's (the pair kept on the unit circle after every step, or None).

    Made for control: no gradient flows through it, and its scratch buffers make one object
    unsafe to call from two threads at once. The first call on the CPU compiles the kernel
    (about a second; numba caches it on disk for later processes).
    """

    def __init__(self, model: SindyDynamics | CompiledSindy) -> None:
        sparse = model.compile_sparse() if isinstance(model, SindyDynamics) else model
        if not isinstance(sparse, CompiledSindy):
            raise TypeError(f"SindyKernelStep needs a SINDy model, got {type(model).__name__}")
        self._sparse = sparse
        nz, nu = sparse.nz, sparse.nu
        self.nz, self.nu = nz, nu
        self.circle = sparse.circle
        self._circle = (-1, -1) if sparse.circle is None else sparse.circle  # the kernel's ca, cb
        self._turn = bool(sparse.turn)
        # The library's feature layout: [z, u, derived, 1, trig...], trig column k being
        # library.trig[k] = (index into [z, u, derived], "sin" | "cos", frequency).
        library = sparse.library
        one = library.constant_column
        table = library.table.cpu()  # (|S|, width)
        coef = sparse.coef.detach().cpu().double()  # (|S|, nz)
        self.n_terms = int(table.shape[0])
        # Our features drop the constant and keep only the trig columns some term uses.
        trig_rows = sorted({int(i) for i in table.flatten() if i > one})
        trig = [library.trig[r - one - 1] for r in trig_rows]
        trig_var = np.array([var for var, _, _ in trig], dtype=np.int64)
        trig_scale = np.array([freq for _, _, freq in trig], dtype=np.float64)
        trig_shift = np.array([0.0 if kind == "sin" else np.pi / 2 for _, kind, _ in trig])
        remap = {r: one + k for k, r in enumerate(trig_rows)} | {i: i for i in range(one)}
        products = [tuple(sorted(remap[int(i)] for i in row if i != one)) for row in table]
        bias = torch.zeros(nz, dtype=torch.float64)
        order = sorted(range(self.n_terms), key=lambda s: products[s])
        terms = []
        start = []
        ptr = [0]
        rows = []
        coefs = []
        prev = ()
        for s in order:
            p = products[s]
            if not p:  # the constant term: its coefficients are a bias
                bias += coef[s]
                continue
            pairs = enumerate(zip(p, prev, strict=False))
            common = next((k for k, (a, b) in pairs if a != b), min(len(p), len(prev)))
            start.append(max(1, common))
            terms.append(p)
            prev = p
            nonzero = coef[s].nonzero().flatten()
            rows += nonzero.tolist()
            coefs += coef[s, nonzero].tolist()
            ptr.append(len(rows))
        width = max((len(p) for p in terms), default=1)
        self.n_coefficients = len(rows)
        self._n_features = one + len(trig_rows)
        self._order = width
        # Kernel arguments: integer tables as they are, floats kept in float64 and cast per dtype.
        self._trig_var = trig_var
        # Derived variables: the node's cfunc per dtype, what it reads and its parameters.
        derived = library.derived
        self._node = node = derived.node if derived is not None else None
        self._n_derived = len(node.names) if node is not None else 0
        self._derive_inputs = np.array(derived.inputs if derived is not None else (),
                                       dtype=np.int64)
        self._derive_params = np.array(node.numba_parameters() if node is not None else (),
                                       dtype=np.float64)
        self._torch_only = node is not None and any(
            node.numba_function(d) is None for d in ("float32", "float64"))
        self._tables = (
            np.array([p + (0,) * (width - len(p)) for p in terms],
                     dtype=np.int64).reshape(-1, width),
            np.array([len(p) for p in terms], dtype=np.int64), np.array(start, dtype=np.int64),
            np.array(ptr, dtype=np.int64), np.array(rows, dtype=np.int64))
        self._floats64 = (trig_scale, trig_shift, bias.numpy(),
                          np.array(coefs, dtype=np.float64))
        self._args: dict[torch.dtype, tuple[np.ndarray, ...]] = {}
        self._check()

    def _kernel_args(self, dtype: torch.dtype) -> tuple[np.ndarray, ...]:
        """The kernel's arguments after (z0t, ut, out) in ``dtype``, scratch included."""
        args = self._args.get(dtype)
        if args is None:
            np_dtype = torch.empty(0, dtype=dtype).numpy().dtype
            trig_scale, trig_shift, bias, coefs, derive_params = (
                a.astype(np_dtype) for a in (*self._floats64, self._derive_params))
            terms, degree, start, ptr, rows = self._tables
            tiny = np_dtype.type(torch.finfo(dtype).tiny)  # as project_circle adds
            args = self._args[dtype] = (
                self._trig_var, trig_scale, trig_shift, bias, terms, degree, start, ptr, rows,
                coefs, *self._circle, tiny, self._turn, self._derive(np_dtype.name),
                self._derive_inputs, derive_params, self._n_derived,
                np.empty((self._n_features, BLOCK), np_dtype),
                np.empty((self._order, BLOCK), np_dtype))
        return args

    def _derive(self, dtype: str) -> int:
        """The kernel's derive argument in ``dtype``: the address of the node's cfunc (the
        world's module holds the cfunc), or 0 for none."""
        return 0 if self._node is None else self._node.numba_function(dtype).address

    def __call__(self, z: Tensor, u: Tensor) -> Tensor:
        """One step: z (K, nz), u (K, nu) -> (K, nz) (a transposed view)."""
        if not z.is_cpu or z.dtype not in _FLOATS or self._torch_only:
            return self._sparse.step(z, u)
        return self._run(z.T, u.T.unsqueeze(0))[0].T

    step = __call__

    def rollout(self, z0: Tensor, actions: Tensor) -> Tensor:
        """Open-loop prediction like :meth:`LatentDynamics.rollout`, in one kernel call:
        z0 (K, nz), actions (K, H, nu) -> (K, H+1, nz) with z0 at index 0 (a permuted view)."""
        if not z0.is_cpu or z0.dtype not in _FLOATS or self._torch_only:
            return self._sparse.rollout(z0, actions)
        K, H = actions.shape[:2]
        if actions.shape[2] != self.nu or z0.shape != (K, self.nz):
            raise ValueError(f"rollout expects z0 (K, {self.nz}) and actions (K, H, {self.nu}), "
                             f"got {tuple(z0.shape)} and {tuple(actions.shape)}")
        out = torch.empty(H + 1, self.nz, K, dtype=z0.dtype)  # (H+1, nz, K)
        out[0] = z0.T
        self._run(z0.T, actions.permute(1, 2, 0), out[1:])
        return out.permute(2, 0, 1)

    def _run(self, z0t: Tensor, ut: Tensor, out: Tensor | None = None) -> Tensor:
        """The kernel on z0t (nz, K), ut (H, nu, K) (views, any strides) -> out (H, nz, K)."""
        if z0t.requires_grad or ut.requires_grad:
            z0t = z0t.detach()
            ut = ut.detach()
        if ut.dtype != z0t.dtype:
            ut = ut.to(z0t.dtype)
        if out is None:
            out = torch.empty(ut.shape[0], self.nz, z0t.shape[1], dtype=z0t.dtype)
        _kernel()(z0t.numpy(), ut.numpy(), out.numpy(), *self._kernel_args(z0t.dtype))
        return out

    @torch.no_grad()
    def _check(self) -> None:
        """Compare with the model's own step (its circle's projection included) on a probe
        batch: guards the feature layout and the kernel's projection."""
        if self._torch_only:  # no kernel: the step is the model's
            return
        gen = torch.Generator().manual_seed(0)
        z = torch.randn(7, self.nz, generator=gen) * 0.5
        u = torch.randn(7, self.nu, generator=gen) * 0.5
        like = self._sparse.coef
        want = self._sparse.step(z.to(like), u.to(like)).to(z)
        got = self(z, u)
        scale = 1.0 + want.abs().max()
        if not bool(((want - got).abs() <= 1e-4 * scale).all()):
            raise RuntimeError(
                "SindyKernelStep disagrees with CompiledSindy.step (max difference "
                f"{float((want - got).abs().max()):.3g}): the library's feature layout "
                "[z, u, derived, 1, trig...] or the step's circle projection has changed; update "
                "latent_sindy/control/sindy_step.py"
            )
