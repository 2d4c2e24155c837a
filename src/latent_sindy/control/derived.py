"""The contract of a world's derived-variable function with the fused SINDy kernel.

A library node of derived variables (:class:`latent_sindy.sindy.grammar.DerivedVariables`)
supplies, for planning on the CPU, a numba ``cfunc`` of :func:`derived_signature`, compiled
with :data:`CFUNC_FLAGS`; the kernel (:mod:`latent_sindy.control.sindy_step`) calls it by its
address, so it stays generic.
"""

from numba import types
from numba.core.typing import Signature

__all__ = ["CFUNC_FLAGS", "derived_signature"]

#: Compiler flags for a derived-variable cfunc, those of the kernel.
CFUNC_FLAGS = {"fastmath": {"contract"}, "nogil": True, "cache": True, "error_model": "numpy"}


def derived_signature(dtype: str) -> Signature:
    """The signature of a derived-variable cfunc for the kernel in ``dtype`` ("float32" or
    "float64")::

        derive(feat, rows, block, n, inputs, n_inputs, params, n_params, first) -> None

    ``feat`` points to the (rows, block) C-contiguous feature scratch of the running block (its
    first n columns are the samples; rows 0 .. nz + nu - 1 hold [z, u]); ``inputs`` to the
    n_inputs indices into [z, u] of the variables the node reads (its ``inputs()``), ``params``
    to its ``numba_parameters()`` in ``dtype``. It writes the derived variables into rows
    first, first + 1, .. (first = nz + nu), columns 0 .. n - 1. In a cfunc,
    ``numba.carray(feat, (rows, block))`` makes the arrays.
    """
    dt = getattr(types, dtype)
    return types.void(types.CPointer(dt), types.int64, types.int64, types.int64,
                      types.CPointer(types.int64), types.int64, types.CPointer(dt), types.int64,
                      types.int64)
