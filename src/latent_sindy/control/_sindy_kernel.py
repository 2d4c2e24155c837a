"""The numba kernel behind :class:`latent_sindy.control.sindy_step.SindyKernelStep`.

Imported only when a SINDy step first runs on the CPU (importing numba takes a moment).
Every loop over samples is innermost and contiguous, so LLVM vectorises it. Of the fast-math
flags only ``contract`` (fused multiply-add) is on: NaN and inf must propagate, since MPPI
discards diverging samples by them. Division follows numpy's error model (IEEE results, no
ZeroDivisionError check), which lets the projection's divisions vectorise.

A library's derived variables (:class:`latent_sindy.sindy.grammar.DerivedVariables`) come from
a numba ``cfunc`` their node supplies (:mod:`latent_sindy.control.derived`), which the
kernel calls once per block and step through its address (an integer argument): the kernel
stays generic, one compiled kernel serves every derived-variable function, numba's disk cache
keeps it, and a call costs what it did before (a jitted function as argument would make numba
compile the kernel in every process; a cfunc object as argument costs ~30 µs of dispatch per
call).
"""

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

_jit = numba.njit(fastmath={"contract"}, nogil=True, cache=True, boundscheck=False,
                  error_model="numpy")

@intrinsic
def _call_derived(typingctx, address, feat, n, inputs, params, first):
    """Call the cfunc at ``address`` (of :func:`derived_signature`) on the arrays' data:
    feat (rows, block) C-contiguous, inputs (n_inputs,) int64, params (n_params,)."""
    sig = types.void(address, feat, n, inputs, params, first)

    def codegen(context, builder, signature, args):
        address, feat, n, inputs, params, first = args
        _, feat_t, _, inputs_t, params_t, _ = signature.args
        fa, ia, pa = (cgutils.create_struct_proxy(t)(context, builder, value=v)
                      for t, v in ((feat_t, feat), (inputs_t, inputs), (params_t, params)))
        rows, block = cgutils.unpack_tuple(builder, fa.shape, 2)
        (n_inputs,), (n_params,) = (cgutils.unpack_tuple(builder, a.shape, 1) for a in (ia, pa))
        argv = [fa.data, rows, block, n, ia.data, n_inputs, pa.data, n_params, first]
        fnty = ir.FunctionType(ir.VoidType(), [a.type for a in argv])
        builder.call(builder.inttoptr(address, fnty.as_pointer()), argv)
        return context.get_dummy_value()

    return sig, codegen


@numba.njit(fastmath={"contract"}, inline="always", cache=True)
def _sin(x):
    """sin(x) in float64 arithmetic, vectorisable (no libm call): x = qπ + r with |r| <= π/2,
    then the odd Taylor polynomial to r¹⁷ (truncation error < 5e-14 on |r| <= π/2) with the
    sign (-1)^q."""
    q = np.floor(x * 0.3183098861837907 + 0.5)
    r = (x - q * 3.140625) - q * 0.000967653589793116  # π in two parts: exact q·3.140625
    r2 = r * r
    p = -7.647163731819816e-13 + r2 * 2.8114572543455206e-15
    p = -2.505210838544172e-08 + r2 * (1.6059043836821613e-10 + r2 * p)
    p = -0.0001984126984126984 + r2 * (2.7557319223985893e-06 + r2 * p)
    p = r + r * r2 * (-0.16666666666666666 + r2 * (0.008333333333333333 + r2 * p))
    return p * (1.0 - 2.0 * (q - 2.0 * np.floor(q * 0.5)))


@_jit
def sindy_rollout_kernel(z0t, ut, out, trig_var, trig_scale, trig_shift, bias, terms, degree,
                         start, ptr, rows, coefs, ca, cb, tiny, turn, derive, derive_inputs,
                         derive_params, n_derived, feat, prods):
    """out[t] (nz, K) = z_{t+1} for t < H, z_{t+1} = z_t + bias + Σ_j coefs[j] θ_term(j),
    then for ca >= 0 the pair (z_ca, z_cb) divided by sqrt(z_ca² + z_cb² + tiny) (onto the unit
    circle, before the next step reads it; ca = cb = -1: no projection). With ``turn`` the
    pair is first the step's start pair turned by ω = out_ca - z_ca: (z_ca + i z_cb) e^{iω}.

    z0t (nz, K) the start states and ut (H, nu, K) the actions, any strides (a zero stride
    repeats one start state); out (H, nz, K). Feature rows are [z, u, derived, trig]: for
    n_derived > 0 rows nz + nu .. nz + nu + n_derived - 1 are the library's derived variables,
    which the cfunc at address ``derive`` (of :func:`derived_signature`; 0 for none) writes
    from the rows ``derive_inputs`` with ``derive_params``. The next trig row i is
    sin(trig_scale[i] feat[trig_var[i]] + trig_shift[i]), of a state (trig_var < nz), an
    action or a derived variable, and a cosine for shift π/2. terms (S, order): feature
    indices of the non-constant active terms in lexicographic order, degree (S,), start (S,)
    the first product level to recompute (lower levels are shared with term s-1); the nonzero
    coefficients of term s are coefs[ptr[s]:ptr[s+1]], for outputs rows[ptr[s]:ptr[s+1]].
    feat (nf, block) and prods (order, block) are scratch (prods[0], which no product uses,
    holds the projection's norms). Each block of samples runs the whole horizon while it is
    in cache.
    """
    nz, K = z0t.shape
    H, nu = ut.shape[0], ut.shape[1]
    block = feat.shape[1]
    base = nz + nu + n_derived
    for k0 in range(0, K, block):
        n = min(block, K - k0)
        for i in range(nz):
            src = z0t[i, k0:k0 + n]
            f = feat[i, :n]
            for k in range(n):
                f[k] = src[k]
        for t in range(H):
            if t > 0:
                for i in range(nz):
                    src = out[t - 1, i, k0:k0 + n]
                    f = feat[i, :n]
                    for k in range(n):
                        f[k] = src[k]
            for i in range(nu):
                src = ut[t, i, k0:k0 + n]
                f = feat[nz + i, :n]
                for k in range(n):
                    f[k] = src[k]
            if n_derived:
                _call_derived(derive, feat, n, derive_inputs, derive_params, nz + nu)
            for i in range(trig_var.shape[0]):
                src = feat[trig_var[i], :n]
                f = feat[base + i, :n]
                scale = trig_scale[i]
                shift = trig_shift[i]
                for k in range(n):
                    f[k] = _sin(src[k] * scale + shift)
            for i in range(nz):
                src = feat[i, :n]
                o = out[t, i, k0:k0 + n]
                b = bias[i]
                for k in range(n):
                    o[k] = src[k] + b
            for s in range(terms.shape[0]):
                d = degree[s]
                for level in range(start[s], d):  # partial products not shared with term s-1
                    prev = feat[terms[s, 0], :n] if level == 1 else prods[level - 1, :n]
                    fac = feat[terms[s, level], :n]
                    p = prods[level, :n]
                    for k in range(n):
                        p[k] = prev[k] * fac[k]
                theta = feat[terms[s, 0], :n] if d == 1 else prods[d - 1, :n]
                for j in range(ptr[s], ptr[s + 1]):
                    o = out[t, rows[j], k0:k0 + n]
                    c = coefs[j]
                    for k in range(n):
                        o[k] += c * theta[k]
            if turn:
                oa = out[t, ca, k0:k0 + n]
                ob = out[t, cb, k0:k0 + n]
                za = feat[ca, :n]
                zb = feat[cb, :n]
                for k in range(n):
                    w = oa[k] - za[k]
                    cw = _sin(w + 1.5707963267948966)
                    sw = _sin(w)
                    oa[k] = za[k] * cw - zb[k] * sw
                    ob[k] = zb[k] * cw + za[k] * sw
            if ca >= 0:  # separate loops: one that writes both rows does not vectorise
                oa = out[t, ca, k0:k0 + n]
                ob = out[t, cb, k0:k0 + n]
                r = prods[0, :n]
                for k in range(n):
                    r[k] = np.sqrt(oa[k] * oa[k] + ob[k] * ob[k] + tiny)
                for k in range(n):
                    oa[k] = oa[k] / r[k]
                for k in range(n):
                    ob[k] = ob[k] / r[k]
