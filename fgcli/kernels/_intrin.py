"""LLVM operations numba does not expose: a fused multiply-add (torch's vectorised CPU
kernels use FMA for ``add(alpha=)``, ``lerp`` and friends, so the kernels must too to stay
bit-identical), an atomic signed int64 minimum (the nearest-depth-wins splat), 32-bit
indexed loads for the gathers (``mad32``, ``ld32``, ``ld_pair``) and SSE4.1's mpsadbw."""
from __future__ import annotations

import sys

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


@intrinsic
def mad32(typingctx, a, b, c):
    """a * b + c in 32-bit signed arithmetic, for flat indices of the 32-bit loads below.
    The caller keeps the result below 2**31 (the kernels' wrappers check the array sizes;
    an overflow is undefined, LLVM's ``nsw``)."""
    if not all(isinstance(t, types.Integer) for t in (a, b, c)):
        return None

    def codegen(context, builder, sig, args):
        x, y, z = (context.cast(builder, v, t, types.int32) for v, t in zip(args, sig.args))
        return builder.add(builder.mul(x, y, flags=["nsw"]), z, flags=["nsw"])

    return types.int32(a, b, c), codegen


def _flat_ptr(context, builder, aryty, ary, idx, idxty):
    """Pointer to element ``idx`` (cast to int32, sign-extended by the GEP) of a
    C-contiguous array's data."""
    a = context.make_array(aryty)(context, builder, ary)
    i = context.cast(builder, idx, idxty, types.int32)
    return builder.gep(a.data, [i], inbounds=True)


@intrinsic
def ld32(typingctx, arr, i):
    """arr.flat[i] (C-contiguous array, 0 <= i < arr.size < 2**31, int32 index).

    Why: numba indexes with int64, so a vectorised gather of float32 values takes 64-bit
    indices (vgatherqps: 8 lanes per instruction, index arithmetic in 8-lane int64
    vectors); a 32-bit index lets LLVM emit 16-lane vgatherdps with the index arithmetic
    in int32. No bounds or negative-index handling."""
    if not (isinstance(arr, types.Array) and arr.layout == "C" and isinstance(i, types.Integer)):
        return None

    def codegen(context, builder, sig, args):
        return builder.load(_flat_ptr(context, builder, sig.args[0], args[0], args[1],
                                      sig.args[1]))

    return arr.dtype(arr, i), codegen


@intrinsic
def ld_pair(typingctx, arr, i):
    """(arr.flat[i], arr.flat[i + 1]) of a C-contiguous float32 array through one 64-bit
    load (0 <= i, i + 1 < arr.size < 2**31, int32 index).

    Why: a bilinear tap pair (x0, x0 + 1) is one 64-bit gather element instead of two
    32-bit ones; on this machine (Zen 4, gathers cost per element) four taps as two pair
    gathers took 4.5 ms against 6.1 ms as four single gathers (6.2 M pixels)."""
    if not (isinstance(arr, types.Array) and arr.layout == "C" and arr.dtype == types.float32
            and isinstance(i, types.Integer)):
        return None

    def codegen(context, builder, sig, args):
        ptr = _flat_ptr(context, builder, sig.args[0], args[0], args[1], sig.args[1])
        i64 = ir.IntType(64)
        i32 = ir.IntType(32)
        v = builder.load(builder.bitcast(ptr, i64.as_pointer()), align=4)
        lo = builder.bitcast(builder.trunc(v, i32), ir.FloatType())
        hi = builder.bitcast(builder.trunc(builder.lshr(v, ir.Constant(i64, 32)), i32),
                             ir.FloatType())
        pair = [lo, hi] if sys.byteorder == "little" else [hi, lo]  # the first element
        return context.make_tuple(builder, sig.return_type, pair)

    return types.UniTuple(types.float32, 2)(arr, i), codegen


def _has_mpsadbw() -> bool:
    """x86-64 with SSE4.1 (every x86-64 CPU since ~2008): sad16_rows can be compiled."""
    import platform

    if platform.machine().lower() not in ("x86_64", "amd64"):
        return False
    try:
        import llvmlite.binding as ll

        return "+sse4.1" in ll.get_host_cpu_features().flatten().split(",")
    except Exception:  # noqa: BLE001 - no feature list: use the portable kernel
        return False


HAVE_MPSADBW = _has_mpsadbw()


@intrinsic
def sad16_rows(typingctx, win, woff, wstride, cur, coff, out):
    """SSE4.1 ``mpsadbw``: out[0:16] (uint16) = the sums of absolute differences of an 8x8
    block of bytes, ``cur[coff + 16 r + c]`` (rows of 16 bytes, the first 8 used), against
    ``win[woff + wstride r + dx + c]`` for the sixteen offsets dx = 0..15 (window rows of
    at least 24 bytes; byte 23 is read, never used). 1-D uint8 win and cur, uint16 out.

    Per block row four mpsadbw (each: eight offsets of one 4-byte half) and two adds, so
    one call is 32 instructions on the SADs of 16 offsets. The sums are exact (at most
    8 * 8 * 255 < 2**16). x86 only: use when HAVE_MPSADBW."""
    if not (isinstance(win, types.Array) and win.dtype == types.uint8 and win.ndim == 1
            and isinstance(cur, types.Array) and cur.dtype == types.uint8 and cur.ndim == 1
            and isinstance(out, types.Array) and out.dtype == types.uint16
            and out.ndim == 1):
        return None
    sig = types.void(win, woff, wstride, cur, coff, out)

    def codegen(context, builder, sig, args):
        wty, woty, wsty, cty, coty, oty = sig.args
        warr = context.make_array(wty)(context, builder, args[0])
        carr = context.make_array(cty)(context, builder, args[3])
        oarr = context.make_array(oty)(context, builder, args[5])
        i64 = ir.IntType(64)
        woff = context.cast(builder, args[1], woty, types.int64)
        wst = context.cast(builder, args[2], wsty, types.int64)
        coff = context.cast(builder, args[4], coty, types.int64)
        i8p = ir.IntType(8).as_pointer()
        v16 = ir.VectorType(ir.IntType(8), 16)
        v8w = ir.VectorType(ir.IntType(16), 8)
        fnty = ir.FunctionType(v8w, [v16, v16, ir.IntType(8)])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.x86.sse41.mpsadbw")
        wbase = builder.bitcast(warr.data, i8p)
        cbase = builder.bitcast(carr.data, i8p)

        def load16(base, off):
            ptr = builder.bitcast(builder.gep(base, [off]), v16.as_pointer())
            return builder.load(ptr, align=1)

        # imm 0: window bytes i..i+3 against block bytes 0..3; imm 5: window bytes
        # 4+i..7+i against block bytes 4..7 (i = 0..7: the offsets)
        lo = ir.Constant(v8w, None)  # offsets 0..7
        hi = ir.Constant(v8w, None)  # offsets 8..15
        for r in range(8):
            roff = builder.add(woff, builder.mul(wst, ir.Constant(i64, r)))
            a0 = load16(wbase, roff)
            a1 = load16(wbase, builder.add(roff, ir.Constant(i64, 8)))
            b = load16(cbase, builder.add(coff, ir.Constant(i64, 16 * r)))
            s0 = builder.call(fn, [a0, b, ir.Constant(ir.IntType(8), 0)])
            s1 = builder.call(fn, [a0, b, ir.Constant(ir.IntType(8), 5)])
            s2 = builder.call(fn, [a1, b, ir.Constant(ir.IntType(8), 0)])
            s3 = builder.call(fn, [a1, b, ir.Constant(ir.IntType(8), 5)])
            lo = builder.add(lo, builder.add(s0, s1))
            hi = builder.add(hi, builder.add(s2, s3))
        obase = builder.bitcast(oarr.data, ir.IntType(16).as_pointer())
        builder.store(lo, builder.bitcast(obase, v8w.as_pointer()), align=1)
        builder.store(hi, builder.bitcast(builder.gep(obase, [ir.Constant(i64, 8)]),
                                          v8w.as_pointer()), align=1)
        return context.get_dummy_value()

    return sig, codegen


_ = ir  # llvmlite is numba's dependency; imported for clarity of where fma comes from
