"""The face variables (a, n) of :class:`latent_sindy.worlds.push.library.FaceFrame` for the
fused SINDy control kernel (:mod:`latent_sindy.control._sindy_kernel`), as numba cfuncs of its
derived-variable signature, one per dtype.

Imported only when a SINDy step of a face-frame library first runs on the CPU; numba caches
the compiled functions on disk.
"""

import numba
import numpy as np

from latent_sindy.control.derived import CFUNC_FLAGS, derived_signature


@numba.njit(fastmath={"contract"}, nogil=True, cache=True, boundscheck=False,
            error_model="numpy")
def _face_variables(feat, n, inputs, params, first):
    """Rows first and first + 1 of feat (rows, block): with ψ = feat[inputs[0]], (c, s) the
    rows inputs[1:] and (f, sense, offset) = params, a = wrap_2π(f ψ - sense atan2(s, c) -
    offset) / f and n = ψ - a, for the first n samples."""
    psi = feat[inputs[0], :n]
    fc = feat[inputs[1], :n]
    fs = feat[inputs[2], :n]
    fa = feat[first, :n]
    fn = feat[first + 1, :n]
    freq, sense, offset = params[0], params[1], params[2]
    two_pi = 2.0 * np.pi
    for k in range(n):
        x = freq * psi[k] - (sense * np.arctan2(fs[k], fc[k]) + offset) + np.pi
        a = (x - two_pi * np.floor(x / two_pi) - np.pi) / freq
        fa[k] = a
        fn[k] = psi[k] - a


@numba.cfunc(derived_signature("float32"), **CFUNC_FLAGS)
def _face_variables_float32(feat, rows, block, n, inputs, n_inputs, params, n_params, first):
    _face_variables(numba.carray(feat, (rows, block)), n, numba.carray(inputs, (n_inputs,)),
                    numba.carray(params, (n_params,)), first)


@numba.cfunc(derived_signature("float64"), **CFUNC_FLAGS)
def _face_variables_float64(feat, rows, block, n, inputs, n_inputs, params, n_params, first):
    _face_variables(numba.carray(feat, (rows, block)), n, numba.carray(inputs, (n_inputs,)),
                    numba.carray(params, (n_params,)), first)


#: The kernel's derive argument for a face frame, per dtype.
FACE_VARIABLES_CFUNC = {"float32": _face_variables_float32, "float64": _face_variables_float64}
