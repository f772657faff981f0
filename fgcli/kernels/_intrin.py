"""LLVM operations numba does not expose: a fused multiply-add (torch's vectorised CPU
kernels use FMA for ``add(alpha=)``, ``lerp`` and friends, so the kernels must too to stay
bit-identical), an atomic signed int64 minimum (the nearest-depth-wins splat), 32-bit
indexed loads for the gathers (``mad32``, ``ld32``, ``ld_pair``) and SSE4.1's mpsadbw
(the block search)."""
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


@intrinsic
def umax16(typingctx, buf, q, src, j):
    """buf[q:q + 16] = max(buf[q:q + 16], src[j:j + 16]) as one 16-lane vector operation
    (1-D C-contiguous uint32 arrays; no bounds checks)."""
    if not all(isinstance(a, types.Array) and a.dtype == types.uint32 and a.ndim == 1
               and a.layout == "C" for a in (buf, src)):
        return None

    def codegen(context, builder, sig, args):
        bty, qty, sty, jty = sig.args
        v = ir.VectorType(ir.IntType(32), 16)
        pb = builder.bitcast(_flat_ptr(context, builder, bty, args[0], args[1], qty),
                             v.as_pointer())
        ps = builder.bitcast(_flat_ptr(context, builder, sty, args[2], args[3], jty),
                             v.as_pointer())
        a = builder.load(pb, align=4)
        b = builder.load(ps, align=4)
        builder.store(builder.select(builder.icmp_unsigned(">", b, a), b, a), pb, align=4)
        return context.get_dummy_value()

    return types.void(buf, q, src, j), codegen


def _host_features() -> list[str]:
    """LLVM's feature list of this CPU on x86-64 (``+sse4.1``, ``+avx2``, ...), else []."""
    import platform

    if platform.machine().lower() not in ("x86_64", "amd64"):
        return []
    try:
        import llvmlite.binding as ll

        return ll.get_host_cpu_features().flatten().split(",")
    except Exception:  # noqa: BLE001 - no feature list: use the portable kernel
        return []


# x86-64 with SSE4.1 (every x86-64 CPU since ~2008): sad_search8 can be compiled; with
# AVX2 (since ~2013) it takes two block rows per instruction
_FEATURES = _host_features()
HAVE_MPSADBW = "+sse4.1" in _FEATURES
HAVE_AVX2 = HAVE_MPSADBW and "+avx2" in _FEATURES


def _sad_search_typing(win, cur, order):
    return (isinstance(win, types.Array) and win.dtype == types.uint8 and win.ndim == 1
            and isinstance(cur, types.Array) and cur.dtype == types.uint8 and cur.ndim == 1
            and isinstance(order, types.Array) and order.dtype == types.int32
            and order.ndim == 1 and order.layout == "C")


def _sad_search_codegen(wide: bool):
    """sad_search8's code: SSE4.1 mpsadbw on one block row (wide False) or AVX2's on two
    at once (its two 128-bit lanes are two independent mpsadbw; the lanes' sums are added
    at the end)."""
    def codegen(context, builder, sig, args):
        wty, woty, wsty, cty, coty, csty, oty = sig.args
        warr = context.make_array(wty)(context, builder, args[0])
        carr = context.make_array(cty)(context, builder, args[3])
        oarr = context.make_array(oty)(context, builder, args[6])
        i64 = ir.IntType(64)
        i32 = ir.IntType(32)
        i8 = ir.IntType(8)
        woff = context.cast(builder, args[1], woty, types.int64)
        wst = context.cast(builder, args[2], wsty, types.int64)
        coff = context.cast(builder, args[4], coty, types.int64)
        cst = context.cast(builder, args[5], csty, types.int64)
        n = 2 if wide else 1  # block rows per instruction
        vin = ir.VectorType(i8, 16 * n)
        vsad = ir.VectorType(ir.IntType(16), 8 * n)
        v16d = ir.VectorType(i32, 16)
        name = "llvm.x86.avx2.mpsadbw" if wide else "llvm.x86.sse41.mpsadbw"
        fn = cgutils.get_or_insert_function(builder.module,
                                            ir.FunctionType(vsad, [vin, vin, i8]), name)
        red = cgutils.get_or_insert_function(builder.module, ir.FunctionType(i32, [v16d]),
                                             "llvm.vector.reduce.smin.v16i32")
        wbase = builder.bitcast(warr.data, i8.as_pointer())
        cbase = builder.bitcast(carr.data, i8.as_pointer())
        obase = builder.bitcast(oarr.data, i32.as_pointer())

        def k64(v):
            return ir.Constant(i64, v)

        def load16(base, off):
            ptr = builder.bitcast(builder.gep(base, [off]), ir.VectorType(i8, 16).as_pointer())
            return builder.load(ptr, align=1)

        def idx(lst):
            return ir.Constant(ir.VectorType(i32, len(lst)), lst)

        def group(vs, k):  # rows k .. k + n - 1 in one vector (lane j: row k + j)
            return vs[k] if n == 1 else builder.shuffle_vector(vs[k], vs[k + 1],
                                                               idx(list(range(32))))

        # every window row (bytes 0..15 and 8..23) and block row loaded once
        rows = []
        for k in range(23):
            roff = builder.add(woff, builder.mul(wst, k64(k)))
            rows.append((load16(wbase, roff), load16(wbase, builder.add(roff, k64(8)))))
        blk = [load16(cbase, builder.add(coff, builder.mul(cst, k64(r)))) for r in range(8)]
        w0 = [group([r[0] for r in rows], k) for k in range(24 - n)]
        w1 = [group([r[1] for r in rows], k) for k in range(24 - n)]
        bg = [group(blk, r) for r in range(0, 8, n)]
        # imm 0: window bytes i..i+3 against block bytes 0..3; imm 5: window bytes 4+i..7+i
        # against block bytes 4..7 (i = 0..7: the offsets); AVX2's high lane reads bits 3-5
        imm0 = ir.Constant(i8, 0)
        imm5 = ir.Constant(i8, 5 | (5 << 3) if wide else 5)
        shift = ir.Constant(v16d, [14] * 16)
        acc = ir.Constant(v16d, [0x7FFFFFFF] * 16)
        for dy in range(16):
            lo = ir.Constant(vsad, None)  # offsets 0..7 (per lane)
            hi = ir.Constant(vsad, None)  # offsets 8..15
            for j, r in enumerate(range(0, 8, n)):
                a0, a1, b = w0[dy + r], w1[dy + r], bg[j]
                lo = builder.add(lo, builder.add(builder.call(fn, [a0, b, imm0]),
                                                 builder.call(fn, [a0, b, imm5])))
                hi = builder.add(hi, builder.add(builder.call(fn, [a1, b, imm0]),
                                                 builder.call(fn, [a1, b, imm5])))
            if wide:  # the two lanes' sums
                lo = builder.add(builder.shuffle_vector(lo, lo, idx(list(range(8)))),
                                 builder.shuffle_vector(lo, lo, idx(list(range(8, 16)))))
                hi = builder.add(builder.shuffle_vector(hi, hi, idx(list(range(8)))),
                                 builder.shuffle_vector(hi, hi, idx(list(range(8, 16)))))
            sad = builder.shuffle_vector(lo, hi, idx(list(range(16))))
            optr = builder.bitcast(builder.gep(obase, [k64(16 * dy)]), v16d.as_pointer())
            key = builder.or_(builder.shl(builder.zext(sad, v16d), shift),
                              builder.load(optr, align=4))
            acc = builder.select(builder.icmp_signed("<", key, acc), key, acc)
        return builder.call(red, [acc])

    return codegen


@intrinsic
def sad_search8(typingctx, win, woff, wstride, cur, coff, cstride, order):
    """mpsadbw block search: the least key ``SAD(dy, dx) << 14 | order[16 dy + dx]``
    (int32) over the 16 x 16 offsets of an 8x8 block of bytes ``cur[coff + cstride r +
    c]`` against ``win[woff + wstride (dy + r) + dx + c]`` (r, c = 0..7; dy, dx = 0..15).
    1-D uint8 win and cur (a frame's rows in place, or copies): 23 window rows of 24
    bytes read (byte 23 never used) and 8 block rows of 16 (the first 8 used); order 1-D
    int32 (256 values below 2**14).

    Per window offset row dy, per block row four mpsadbw (each: eight offsets of one
    4-byte half) and two adds give the 16 SADs (exact: at most 8 * 8 * 255 < 2**16); each
    window row and block row is loaded once; the keys' running element-wise minimum stays
    in a register and one horizontal minimum ends it. With AVX2 (HAVE_AVX2) two block
    rows per instruction (1080p level: 5.4 -> 2.6 ms), else SSE4.1's (sad_search8_sse41).
    x86 only: use when HAVE_MPSADBW."""
    if not _sad_search_typing(win, cur, order):
        return None
    sig = types.int32(win, woff, wstride, cur, coff, cstride, order)
    return sig, _sad_search_codegen(HAVE_AVX2)


@intrinsic
def sad_search8_sse41(typingctx, win, woff, wstride, cur, coff, cstride, order):
    """sad_search8 with SSE4.1's mpsadbw only (what it compiles to without AVX2; the tests
    run both)."""
    if not _sad_search_typing(win, cur, order):
        return None
    sig = types.int32(win, woff, wstride, cur, coff, cstride, order)
    return sig, _sad_search_codegen(False)


_ = ir  # llvmlite is numba's dependency; imported for clarity of where fma comes from
