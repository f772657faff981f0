"""Two LLVM intrinsics numba does not expose: a fused multiply-add (torch's vectorised CPU
kernels use FMA for ``add(alpha=)``, ``lerp`` and friends, so the kernels must too to stay
bit-identical) and an atomic signed int64 minimum (the nearest-depth-wins splat)."""
from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic


@intrinsic
def fma(typingctx, a, b, c):
    """a * b + c rounded once (float32 or float64, all three the same type)."""
    if not (isinstance(a, types.Float) and a == b == c):
        return None

    def codegen(context, builder, sig, args):
        return builder.fma(*args)

    return a(a, b, c), codegen


@intrinsic
def atomic_min_i64(typingctx, arr, idx, val):
    """arr[idx] = min(arr[idx], val) atomically (1-D int64 array, signed)."""
    if not (isinstance(arr, types.Array) and arr.dtype == types.int64 and arr.ndim == 1):
        return None

    def codegen(context, builder, sig, args):
        aryty, idxty, valty = sig.args
        ary = context.make_array(aryty)(context, builder, args[0])
        i = context.cast(builder, args[1], idxty, types.intp)
        v = context.cast(builder, args[2], valty, types.int64)
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [i])
        builder.atomic_rmw("min", ptr, v, "monotonic")
        return context.get_dummy_value()

    return types.void(arr, idx, val), codegen


_ = ir  # llvmlite is numba's dependency; imported for clarity of where fma comes from
