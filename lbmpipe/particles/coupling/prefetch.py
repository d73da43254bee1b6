"""A cache-prefetch hint for the link passes, as a numba intrinsic (llvmlite ``llvm.prefetch``).

The link passes (``ladd``) are bound by the latency of scattered accesses to the populations
``f``; a hint issued ``PREFETCH_AHEAD`` links ahead keeps more of those misses in flight than the
out-of-order window does. A hint has no effect on results.
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

#: links ahead whose population the link passes prefetch (measured: the gather of f* 25-35 %
#: faster at 16; 8 and 64 gain less)
PREFETCH_AHEAD = 16


@intrinsic
def prefetch(typingctx, arr, i, j, write):
    """Hint the cache to fetch ``arr[i, j]`` (for writing if the literal ``write`` is 1); no effect
    on results. The link passes are bound by the latency of scattered accesses to ``f``, and a
    hint issued a few links ahead keeps more of them in flight than the out-of-order window.

    Inputs: ``arr`` a 2-D array, ``i``, ``j`` integer indices (not bounds-checked: a prefetch of
    any address is harmless), ``write`` the literal 0 or 1. Output: none (locality hint 3, data)."""
    rw = int(getattr(write, "literal_value", 0))
    sig = types.void(arr, i, j, write)

    def codegen(context, builder, signature, args):
        aty = signature.args[0]
        ary = context.make_array(aty)(context, builder, args[0])
        idx = [context.cast(builder, args[q], signature.args[q], types.intp) for q in (1, 2)]
        ptr = cgutils.get_item_pointer(context, builder, aty, ary, idx, wraparound=False)
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]),
                                            "llvm.prefetch.p0")
        builder.call(fn, [builder.bitcast(ptr, i8p), ir.Constant(i32, rw), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def prefetch1(typingctx, arr, j):
    """Read hint for ``arr[j]`` of a 1-D array (the owner map), as ``prefetch`` for 2-D arrays; no
    effect on results. Inputs: ``arr`` a 1-D array, ``j`` an integer index (not bounds-checked).
    Output: none (locality hint 3, data)."""
    sig = types.void(arr, j)

    def codegen(context, builder, signature, args):
        aty = signature.args[0]
        ary = context.make_array(aty)(context, builder, args[0])
        idx = [context.cast(builder, args[1], signature.args[1], types.intp)]
        ptr = cgutils.get_item_pointer(context, builder, aty, ary, idx, wraparound=False)
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]),
                                            "llvm.prefetch.p0")
        builder.call(fn, [builder.bitcast(ptr, i8p), ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen
