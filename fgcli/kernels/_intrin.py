"""LLVM operations numba does not expose: a fused multiply-add (torch's vectorised CPU
kernels use FMA for ``add(alpha=)``, ``lerp`` and friends, so the kernels must too to stay
bit-identical), an atomic signed int64 minimum (the nearest-depth-wins splat), an atomic
uint32 maximum (FSR 3's secondary walk), 32-bit indexed loads for the gathers (``mad32``,
``ld32``, ``ld_pair``), SSE4.1's mpsadbw (the block search), 16-lane maxima and minima
(``umax16``, ``fmin16``) and the warps' 16-lane tap fetches from windows of source rows
(``bilinear16x3``, ``nearest16``, ...: AVX-512 or AVX2)."""
from __future__ import annotations

import sys

import numpy as np

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


def _atomic(rmw, elem, doc):
    """An intrinsic f(arr, idx, val): arr[idx] = rmw(arr[idx], val) atomically (LLVM's
    ``atomicrmw``, monotonic) on a 1-D array of numba type elem."""
    @intrinsic
    def op(typingctx, arr, idx, val):
        if not (isinstance(arr, types.Array) and arr.dtype == elem and arr.ndim == 1):
            return None

        def codegen(context, builder, sig, args):
            aryty, idxty, valty = sig.args
            ary = context.make_array(aryty)(context, builder, args[0])
            i = context.cast(builder, args[1], idxty, types.intp)
            v = context.cast(builder, args[2], valty, elem)
            ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [i])
            builder.atomic_rmw(rmw, ptr, v, "monotonic")
            return context.get_dummy_value()

        return types.void(arr, idx, val), codegen

    op.__doc__ = doc
    return op


atomic_min_i64 = _atomic("min", types.int64,
                         "arr[idx] = min(arr[idx], val) atomically (1-D int64 array, signed).")
atomic_max_u32 = _atomic("umax", types.uint32,
                         "arr[idx] = max(arr[idx], val) atomically (1-D uint32 array, unsigned; "
                         "a compare-and-swap loop on x86).")


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


def _vec16_ptr(context, builder, aryty, ary, idx, idxty, lane):
    """_flat_ptr as a pointer to 16 lanes of LLVM type lane (unaligned loads and stores)."""
    return builder.bitcast(_flat_ptr(context, builder, aryty, ary, idx, idxty),
                           ir.VectorType(lane, 16).as_pointer())


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
def run16(typingctx, cont, j):
    """True when cont[j .. j + 14] are all non-zero (a 1-D C-contiguous uint8 array of at
    least j + 16 elements; int32-range j >= 0): with cont[k] set where source k + 1
    continues source k's footprint (the footprint scatters' runs), sources j .. j + 15
    are one run. One 16-byte load and a compare, where the scatters kept a prefix count of
    run starts (a serial loop over every source) to test it."""
    if not (isinstance(cont, types.Array) and cont.dtype == types.uint8 and cont.ndim == 1
            and cont.layout == "C" and isinstance(j, types.Integer)):
        return None

    def codegen(context, builder, sig, args):
        i8, i1 = ir.IntType(8), ir.IntType(1)
        p = _vec16_ptr(context, builder, sig.args[0], args[0], args[1], sig.args[1], i8)
        v = builder.load(p, align=1)
        nz = builder.icmp_unsigned("!=", v, ir.Constant(ir.VectorType(i8, 16), None))
        nz = builder.or_(nz, ir.Constant(ir.VectorType(i1, 16), [0] * 15 + [1]))
        fn = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(i1, [ir.VectorType(i1, 16)]),
            "llvm.vector.reduce.and.v16i1")
        return builder.call(fn, [nz])

    return types.boolean(cont, j), codegen


def _lanes16(elem, lane, pick, doc):
    """An intrinsic f(buf, q, src, j): buf[q:q + 16] = pick(buf[q:q + 16], src[j:j + 16])
    as one 16-lane vector operation on 1-D C-contiguous arrays of numba type elem (LLVM
    lane type lane; no bounds checks)."""
    @intrinsic
    def op(typingctx, buf, q, src, j):
        if not all(isinstance(a, types.Array) and a.dtype == elem and a.ndim == 1
                   and a.layout == "C" for a in (buf, src)):
            return None

        def codegen(context, builder, sig, args):
            bty, qty, sty, jty = sig.args
            pb = _vec16_ptr(context, builder, bty, args[0], args[1], qty, lane)
            ps = _vec16_ptr(context, builder, sty, args[2], args[3], jty, lane)
            a = builder.load(pb, align=4)
            b = builder.load(ps, align=4)
            builder.store(pick(builder, a, b), pb, align=4)
            return context.get_dummy_value()

        return types.void(buf, q, src, j), codegen

    op.__doc__ = doc
    return op


def _umax_s(bd, b, a):
    """b > a ? b : a, unsigned, as a select (scalars or vectors)."""
    return bd.select(bd.icmp_unsigned(">", b, a), b, a)


umax16 = _lanes16(types.uint32, ir.IntType(32), lambda bd, a, b: _umax_s(bd, b, a),
                  "buf[q:q + 16] = max(buf[q:q + 16], src[j:j + 16]) (uint32 arrays).")


def _host_features() -> list[str]:
    """The CPU features numba compiles for on x86-64 (``+sse4.1``, ``+avx2``, ...), else
    []: a user's NUMBA_CPU_FEATURES when set, none when NUMBA_CPU_NAME names another CPU
    than the host (a portable cache: the intrinsics below would not compile there), else
    LLVM's list of this CPU."""
    import os
    import platform

    if platform.machine().lower() not in ("x86_64", "amd64"):
        return []
    feats = os.environ.get("NUMBA_CPU_FEATURES")
    if feats is not None:
        return feats.split(",")
    if os.environ.get("NUMBA_CPU_NAME", "host") != "host":
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
# AVX-512 (Intel since Skylake-X, AMD since Zen 4): the 16-lane window fetches below
HAVE_AVX512 = "+avx512f" in _FEATURES
# the window fetches run with AVX-512 (one two-register permute per tap and row) or AVX2
# (the 16 lanes as two halves of 8, each from its own 16-column window: two one-register
# permutes and a select per tap and row); a module constant of the kernels (numba's cache
# keys compiled code by CPU)
HAVE_WINDOW16 = HAVE_AVX512 or HAVE_AVX2
# F16C (x86-64 CPUs since ~2012, every one with AVX2): float32 -> binary16 in one
# instruction (vcvtps2ph), 8 lanes at a time
HAVE_F16C = "+f16c" in _FEATURES


def _fmin_s(bd, b, a):
    """b < a ? b : a as a select (scalars or vectors)."""
    return bd.select(bd.fcmp_ordered("<", b, a), b, a)


def _vmin16_whole(builder, b, a):
    """b < a ? b : a lane by lane for <16 x float> values, as x86 min instructions (one
    512-bit one with AVX-512, two 256-bit halves with AVX): never a masked store."""
    v16 = ir.VectorType(ir.FloatType(), 16)
    if HAVE_AVX512:
        f = builder.module.declare_intrinsic(
            "llvm.x86.avx512.min.ps.512",
            fnty=ir.FunctionType(v16, [v16, v16, ir.IntType(32)]))
        return builder.call(f, [b, a, ir.Constant(ir.IntType(32), 4)])
    v8 = ir.VectorType(ir.FloatType(), 8)
    f = builder.module.declare_intrinsic("llvm.x86.avx.min.ps.256",
                                         fnty=ir.FunctionType(v8, [v8, v8]))
    halves = []
    for h in range(2):
        idx = ir.Constant(ir.VectorType(ir.IntType(32), 8), list(range(8 * h, 8 * h + 8)))
        halves.append(builder.call(f, [builder.shuffle_vector(b, b, idx),
                                       builder.shuffle_vector(a, a, idx)]))
    return builder.shuffle_vector(halves[0], halves[1],
                                  ir.Constant(ir.VectorType(ir.IntType(32), 16),
                                              list(range(16))))


# buf[q:q + 16] = min(buf[q:q + 16], src[j:j + 16]) (float32 arrays, no NaN in either: the
# caller's values are sanitised depths). As a select of the loaded values LLVM stores it
# with masked stores (vmaskmovps: the lanes where src is smaller), which stall the loads
# of the next overlapping minima on Zen 3 (depth_scatter_pair 1.4x faster with AVX's
# vminps and whole stores); without AVX the select.
_vmin16 = _vmin16_whole if "+avx" in _FEATURES else _fmin_s
fmin16 = _lanes16(types.float32, ir.FloatType(), lambda bd, a, b: _vmin16(bd, b, a),
                  "buf[q:q + 16] = min(buf[q:q + 16], src[j:j + 16]) (float32 arrays, no "
                  "NaN in either).")


def _pair16(elem, lane, vop, sop, fill, doc):
    """An intrinsic f(buf, q, sa, sb, j, d), d 0 or 1: the two 16-lane updates
    buf[q:q + 16] = op(buf[q:q + 16], sa[j:j + 16]), then buf[q + d:q + d + 16] =
    op(that, sb[j:j + 16]), in registers: one load and one store of the 16 (or 17) values
    instead of two overlapping ones, whose second load waited for the first store to leave
    the store buffer (a store-forwarding stall at each of a scatter's runs). vop / sop:
    the operation on vectors / scalars, argument order (new, old) as the sequential
    updates apply it (bit-identical, ties included); fill: its identity."""
    @intrinsic
    def op(typingctx, buf, q, sa, sb, j, d):
        if not (all(isinstance(a, types.Array) and a.dtype == elem and a.ndim == 1
                    and a.layout == "C" for a in (buf, sa, sb))
                and isinstance(d, types.Integer)):
            return None

        def codegen(context, builder, sig, args):
            bty, qty, saty, sbty, jty, dty = sig.args
            v = ir.VectorType(lane, 16)
            pe = _flat_ptr(context, builder, bty, args[0], args[1], qty)
            pb = builder.bitcast(pe, v.as_pointer())
            pa = _vec16_ptr(context, builder, saty, args[2], args[4], jty, lane)
            pz = _vec16_ptr(context, builder, sbty, args[3], args[4], jty, lane)
            old = builder.load(pb, align=4)
            x = builder.load(pa, align=4)
            y = builder.load(pz, align=4)
            m = vop(builder, x, old)
            dv = context.cast(builder, args[5], dty, types.int64)
            with builder.if_else(builder.icmp_signed("==", dv, ir.Constant(
                    ir.IntType(64), 0))) as (same, shifted):
                with same:
                    builder.store(vop(builder, y, m), pb, align=4)
                with shifted:
                    # sb's lanes one texel to the right: lane 0 the identity, lane 15 apart
                    fv = ir.Constant(v, [fill] * 16)
                    ys = builder.shuffle_vector(y, fv, ir.Constant(
                        ir.VectorType(ir.IntType(32), 16), [16] + list(range(15))))
                    builder.store(vop(builder, ys, m), pb, align=4)
                    p16 = builder.gep(pe, [ir.Constant(ir.IntType(32), 16)], inbounds=True)
                    e = builder.load(p16, align=4)
                    y15 = builder.extract_element(y, ir.Constant(ir.IntType(32), 15))
                    builder.store(sop(builder, y15, e), p16, align=4)
            return context.get_dummy_value()

        return types.void(buf, q, sa, sb, j, d), codegen

    op.__doc__ = doc
    return op


def _umax_v(bd, b, a):
    f = bd.module.declare_intrinsic("llvm.umax.v16i32",
                                    fnty=ir.FunctionType(b.type, [b.type, b.type]))
    return bd.call(f, [b, a])


# two footprint taps one texel apart (d = 1) or on the same texel (d = 0), 16 sources of
# one run: umax16 / fmin16 twice, merged in registers
umax16x2 = _pair16(types.uint32, ir.IntType(32), _umax_v, _umax_s, 0,
                   "umax16(buf, q, sa, j), then umax16(buf, q + d, sb, j), d 0 or 1.")
fmin16x2 = _pair16(types.float32, ir.FloatType(), _vmin16, _fmin_s, float("inf"),
                   "fmin16(buf, q, sa, j), then fmin16(buf, q + d, sb, j), d 0 or 1 "
                   "(AVX: x86 min instructions).")


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
    rows per instruction (2x faster), else SSE4.1's (sad_search8_sse41).
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




# ----------------------------------------------------------------------------- 16-lane fetches
# The warps' taps without gathers. A bilinear warp reads four taps per pixel and channel
# at data-dependent places; LLVM vectorises such a loop with gathers, which cost per
# element on recent x86 cores (Zen 4: mob-fgsr's warp of two 1080p frames, 16.5 ms, ran in
# 8.5 ms with the same arithmetic reading contiguous memory). Neighbouring pixels of a
# smooth flow read neighbouring texels, though: for 16 pixels in a row, the taps usually
# lie within 32 columns of two or three source rows (97-98 % of the blocks on the
# benchmark's scene, 88 % on Nuke-layout footage with ~3x its motion). Those 16 pixels'
# taps are then two 16-float loads per source row and one AVX-512 two-register permute
# (vpermi2ps) per tap and row; a block whose taps spread further is gathered (vgatherdps).
# Both give every tap's exact value, so a kernel built on them stays bit-identical.


def _v16(builder):
    i32 = ir.IntType(32)
    return i32, ir.VectorType(i32, 16), ir.VectorType(ir.FloatType(), 16)


def _fn(builder, name, ret, params):
    return cgutils.get_or_insert_function(builder.module, ir.FunctionType(ret, params), name)


def _vload(builder, ptr, idx, vt):
    """16 lanes of vt at ptr[idx] (unaligned)."""
    p = builder.gep(ptr, [idx], inbounds=True)
    return builder.load(builder.bitcast(p, vt.as_pointer()), align=4)


def _vstore(builder, v, ptr, idx):
    p = builder.gep(ptr, [idx], inbounds=True)
    builder.store(v, builder.bitcast(p, v.type.as_pointer()), align=4)


def _splat(builder, s):
    i32, v16i, _ = _v16(builder)
    u = builder.insert_element(ir.Constant(v16i, None), s, ir.Constant(i32, 0))
    return builder.shuffle_vector(u, u, ir.Constant(v16i, [0] * 16))


def _fetch_branch(builder, xok, span, tag):
    """The fetch's three paths: blocks (rows2, rows3, gather, end), the branch to them
    emitted (a window of 2 rows when the columns fit (xok) and the rows span at most 1,
    of 3 rows when at most 2, else gathered)."""
    i32 = ir.IntType(32)
    fn = builder.function
    b2, bchk, b3, bg, bend = (fn.append_basic_block(f"{tag}_{n}") for n in
                              ("rows2", "chk3", "rows3", "gather", "end"))
    builder.cbranch(builder.and_(xok, builder.icmp_signed("<=", span, ir.Constant(i32, 1))),
                    b2, bchk)
    builder.position_at_end(bchk)
    builder.cbranch(builder.and_(xok, builder.icmp_signed("<=", span, ir.Constant(i32, 2))),
                    b3, bg)
    return b2, b3, bg, bend


def _fetch_merge(builder, taps, blocks, bend):
    """At bend, the taps of the three paths' blocks (rows2, rows3, gather; taps[blk]:
    [[v16f per tap] per plane]) joined, and the path taken (2, 3 or 0)."""
    i32, _, v16f = _v16(builder)
    builder.position_at_end(bend)
    first = taps[blocks[0]]
    merged = []
    for p in range(len(first)):
        row = []
        for k in range(len(first[p])):
            phi = builder.phi(v16f)
            for blk in blocks:
                phi.add_incoming(taps[blk][p][k], blk)
            row.append(phi)
        merged.append(row)
    path = builder.phi(i32)
    for blk, n in zip(blocks, (2, 3, 0)):
        path.add_incoming(ir.Constant(i32, n), blk)
    return merged, path


def _fetch16(builder, base, plane_offs, w, h, xa, xb, ya, yb, ntaps=4):
    """_fetch16_512 with AVX-512, else _fetch16_avx2 (the same values, the same paths)."""
    f = _fetch16_512 if HAVE_AVX512 else _fetch16_avx2
    return f(builder, base, plane_offs, w, h, xa, xb, ya, yb, ntaps)


def _fetch16_avx2(builder, base, plane_offs, w, h, xa, xb, ya, yb, ntaps=4):
    """_fetch16_512 with AVX2: each half of 8 lanes reads its own window of 16 columns
    (cx_k .. cx_k + 15: two 8-float loads per source row; one permute of each (vpermps)
    and a select per tap and row), the rows as there (2 or 3 from the 16 lanes' least);
    a block where either half's taps spread past 16 columns, or the rows past 3, is
    gathered (two 8-lane vgatherdps per tap). Same arguments and results."""
    i32, v16i, v16f = _v16(builder)
    v8i, v8f = ir.VectorType(i32, 8), ir.VectorType(ir.FloatType(), 8)
    c32 = lambda v: ir.Constant(i32, v)  # noqa: E731
    smin = _fn(builder, "llvm.vector.reduce.smin.v16i32", i32, [v16i])
    smax = _fn(builder, "llvm.vector.reduce.smax.v16i32", i32, [v16i])
    smin8 = _fn(builder, "llvm.vector.reduce.smin.v8i32", i32, [v8i])
    smax8 = _fn(builder, "llvm.vector.reduce.smax.v8i32", i32, [v8i])
    perm = _fn(builder, "llvm.x86.avx2.permps", v8f, [v8f, v8i])
    gat = _fn(builder, "llvm.x86.avx2.gather.d.ps.256", v8f,
              [v8f, ir.IntType(8).as_pointer(), v8i, v8f, ir.IntType(8)])

    def half(v, k):
        return builder.shuffle_vector(v, v, ir.Constant(v8i, list(range(8 * k, 8 * k + 8))))

    def join(a, b):
        return builder.shuffle_vector(a, b, ir.Constant(v16i, list(range(16))))

    def splat8(x):
        u = builder.insert_element(ir.Constant(v8i, None), x, c32(0))
        return builder.shuffle_vector(u, u, ir.Constant(v8i, [0] * 8))

    xah, xbh, yah, ybh = ([half(v, k) for k in (0, 1)] for v in (xa, xb, ya, yb))
    ymin = builder.call(smin, [ya])
    span = builder.sub(builder.call(smax, [yb]), ymin)
    # each half's window: columns cx_k .. cx_k + 15 (inside the row: w >= 16)
    wm16 = builder.sub(w, c32(16))
    cxs, xok = [], builder.icmp_signed(">=", w, c32(16))
    for k in (0, 1):
        xmin = builder.call(smin8, [xah[k]])
        cx = builder.select(builder.icmp_signed("<", xmin, wm16), xmin, wm16)
        cxs.append(cx)
        xok = builder.and_(xok, builder.icmp_signed(
            "<=", builder.sub(builder.call(smax8, [xbh[k]]), cx), c32(15)))
    b2, b3, bg, bend = _fetch_branch(builder, xok, span, "w8")
    taps = {}
    zero, one, seven = (ir.Constant(v8i, [v] * 8) for v in (0, 1, 7))

    def window(nrows, blk):
        builder.position_at_end(blk)
        vym = splat8(ymin)
        hm1 = builder.sub(h, c32(1))
        rowy = []
        for r in range(nrows):  # (a row past the last is never picked: read the last)
            y = builder.add(ymin, c32(r))
            rowy.append(builder.mul(builder.select(builder.icmp_signed("<", y, hm1), y, hm1), w))
        lanes = []  # per half: (index, upper-register flag) of xa and xb, the row flags
        for k in (0, 1):
            vcx = splat8(cxs[k])
            ix = []
            for xv in (xah[k], xbh[k]):
                i = builder.sub(xv, vcx)
                ix.append((builder.and_(i, seven), builder.icmp_signed(">", i, seven)))
            rows_of = []
            for yv in (yah[k], ybh[k]):
                dy = builder.sub(yv, vym)
                rows_of.append((builder.icmp_signed("==", dy, zero),
                                builder.icmp_signed("==", dy, one)))
            lanes.append((ix, rows_of))
        out = []
        for po in plane_offs:
            res = [[None, None] for _ in range(4)]
            for k in (0, 1):
                ix, rows_of = lanes[k]
                rows = []
                for ry in rowy:
                    q = builder.add(po, builder.add(ry, cxs[k]))
                    rows.append((_vload(builder, base, q, v8f),
                                 _vload(builder, base, builder.add(q, c32(8)), v8f)))

                def pick(sel, t):
                    i, up = t
                    v = [builder.select(up, builder.call(perm, [hi, i]),
                                        builder.call(perm, [lo, i])) for lo, hi in rows]
                    r = v[1] if nrows == 2 else builder.select(sel[1], v[1], v[2])
                    return builder.select(sel[0], v[0], r)

                for n, (sel, t) in enumerate(((rows_of[0], ix[0]), (rows_of[0], ix[1]),
                                              (rows_of[1], ix[0]), (rows_of[1], ix[1]))[:ntaps]):
                    res[n][k] = pick(sel, t)
            out.append([join(*res[n]) for n in range(ntaps)])
        taps[blk] = out
        builder.branch(bend)

    window(2, b2)
    window(3, b3)
    builder.position_at_end(bg)
    b8 = builder.bitcast(base, ir.IntType(8).as_pointer())
    vw = splat8(w)
    every = builder.bitcast(ir.Constant(v8i, [-1] * 8), v8f)
    out = []
    for po in plane_offs:
        vo = splat8(po)
        row = []
        for yv, xv in ((yah, xah), (yah, xbh), (ybh, xah), (ybh, xbh))[:ntaps]:
            g = [builder.call(gat, [ir.Constant(v8f, None), b8, builder.add(
                vo, builder.add(builder.mul(yv[k], vw), xv[k])), every,
                ir.Constant(ir.IntType(8), 4)]) for k in (0, 1)]
            row.append(join(*g))
        out.append(row)
    taps[bg] = out
    builder.branch(bend)
    return _fetch_merge(builder, taps, (b2, b3, bg), bend)


def _fetch16_512(builder, base, plane_offs, w, h, xa, xb, ya, yb, ntaps=4):
    """Emit the fetch of 16 lanes' taps (xa, ya), (xb, ya), (xa, yb), (xb, yb) (int32
    vectors: 0 <= xa <= xb < w, 0 <= ya <= yb < h) from each plane (flat float32 ``base``
    at the int32 offsets ``plane_offs``, rows of w). Returns ([[nw, ne, sw, se] per
    plane], path): path 2 or 3 = the window of that many rows, 0 = gathered.
    ntaps=1: the first tap only (a nearest fetch; xb, yb are xa, ya)."""
    i32, v16i, v16f = _v16(builder)
    c32 = lambda v: ir.Constant(i32, v)  # noqa: E731
    smin = _fn(builder, "llvm.vector.reduce.smin.v16i32", i32, [v16i])
    smax = _fn(builder, "llvm.vector.reduce.smax.v16i32", i32, [v16i])
    perm = _fn(builder, "llvm.x86.avx512.vpermi2var.ps.512", v16f, [v16f, v16i, v16f])
    gat = _fn(builder, "llvm.x86.avx512.mask.gather.dps.512", v16f,
              [v16f, ir.IntType(8).as_pointer(), v16i, ir.VectorType(ir.IntType(1), 16), i32])
    ymin = builder.call(smin, [ya])
    span = builder.sub(builder.call(smax, [yb]), ymin)
    # window columns cx .. cx + 31 (inside the row: w >= 32)
    wm32 = builder.sub(w, c32(32))
    xmin = builder.call(smin, [xa])
    cx = builder.select(builder.icmp_signed("<", xmin, wm32), xmin, wm32)
    xok = builder.and_(builder.icmp_signed("<=", builder.sub(builder.call(smax, [xb]), cx),
                                           c32(31)),
                       builder.icmp_signed(">=", w, c32(32)))
    b2, b3, bg, bend = _fetch_branch(builder, xok, span, "w16")
    taps = {}

    def window(nrows, blk):
        builder.position_at_end(blk)
        vcx, vym = _splat(builder, cx), _splat(builder, ymin)
        ia, ib = builder.sub(xa, vcx), builder.sub(xb, vcx)
        zero, one = ir.Constant(v16i, [0] * 16), ir.Constant(v16i, [1] * 16)
        rows_of = []
        for yv in (ya, yb):
            dy = builder.sub(yv, vym)
            rows_of.append((builder.icmp_signed("==", dy, zero),
                            builder.icmp_signed("==", dy, one)))
        hm1 = builder.sub(h, c32(1))
        roff = []
        for r in range(nrows):  # (a row past the last is never picked: read the last)
            y = builder.add(ymin, c32(r))
            roff.append(builder.add(builder.mul(builder.select(
                builder.icmp_signed("<", y, hm1), y, hm1), w), cx))
        out = []
        for po in plane_offs:
            rows = []
            for ro in roff:
                q = builder.add(po, ro)
                rows.append((_vload(builder, base, q, v16f),
                             _vload(builder, base, builder.add(q, c32(16)), v16f)))

            def pick(sel, ix):
                v = [builder.call(perm, [lo, ix, hi]) for lo, hi in rows]
                r = v[1] if nrows == 2 else builder.select(sel[1], v[1], v[2])
                return builder.select(sel[0], v[0], r)

            out.append([pick(rows_of[0], ia), pick(rows_of[0], ib),
                        pick(rows_of[1], ia), pick(rows_of[1], ib)][:ntaps])
        taps[blk] = out
        builder.branch(bend)

    window(2, b2)
    window(3, b3)
    builder.position_at_end(bg)
    b8 = builder.bitcast(base, ir.IntType(8).as_pointer())
    vw = _splat(builder, w)
    ra, rb = builder.mul(ya, vw), builder.mul(yb, vw)
    every = ir.Constant(ir.VectorType(ir.IntType(1), 16), [1] * 16)
    out = []
    for po in plane_offs:
        vo = _splat(builder, po)
        out.append([builder.call(gat, [ir.Constant(v16f, None), b8,
                                       builder.add(vo, builder.add(r, x)), every, c32(4)])
                    for r, x in ((ra, xa), (ra, xb), (rb, xa), (rb, xb))[:ntaps]])
    taps[bg] = out
    builder.branch(bend)
    return _fetch_merge(builder, taps, (b2, b3, bg), bend)


def _sval16(builder, v):
    """sanitize_values on 16 lanes, as _common.sval_b: +-inf -> +-1e30, NaN -> 0."""
    _, _, v16f = _v16(builder)
    k = lambda x: ir.Constant(v16f, [float(x)] * 16)  # noqa: E731
    r = builder.select(builder.fcmp_ordered("==", v, k("inf")), k(np.float32(1e30)), v)
    r = builder.select(builder.fcmp_ordered("==", v, k("-inf")), k(-np.float32(1e30)), r)
    return builder.select(builder.fcmp_unordered("!=", v, v), k(0.0), r)


def _i32_arrays(*arrs):
    return all(isinstance(a, types.Array) and a.layout == "C" and a.dtype == types.int32
               for a in arrs)


def _f32_arrays(*arrs):
    return all(isinstance(a, types.Array) and a.layout == "C" and a.dtype == types.float32
               for a in arrs)


def _bilinear16(nplanes, img, pst, w, h, XA, XB, YA, YB, WT, Z, j, coff, out, opst,
                ooff):
    """bilinear16x3 / bilinear16x1's typing and code, for nplanes planes."""
    if not (_f32_arrays(img, WT, out) and _i32_arrays(XA, XB, YA, YB, Z)
            and WT.ndim == 2):
        return None
    sig = types.int32(img, pst, w, h, XA, XB, YA, YB, WT, Z, j, coff, out, opst, ooff)

    def codegen(context, builder, sig, args):
        i32, v16i, v16f = _v16(builder)
        tys = sig.args
        arr = lambda k: context.make_array(tys[k])(context, builder, args[k])  # noqa: E731
        sc = lambda k: context.cast(builder, args[k], tys[k], types.int32)  # noqa: E731
        fma = _fn(builder, "llvm.fma.v16f32", v16f, [v16f, v16f, v16f])
        any_ = _fn(builder, "llvm.vector.reduce.or.v16i1", ir.IntType(1),
                   [ir.VectorType(ir.IntType(1), 16)])
        base, optr = arr(0).data, arr(12).data
        pst, w, h, jj = sc(1), sc(2), sc(3), sc(10)
        xa, xb, ya, yb, z = (_vload(builder, arr(k).data, jj, v16i) for k in (4, 5, 6, 7, 9))
        wt = arr(8)
        tw = builder.lshr(builder.trunc(cgutils.unpack_tuple(builder, wt.strides, 2)[0], i32),
                          ir.Constant(i32, 2))  # row stride, elements
        wts = [_vload(builder, wt.data, builder.add(jj, builder.mul(tw, ir.Constant(i32, k))),
                      v16f) for k in range(4)]
        zm = builder.icmp_signed("!=", z, ir.Constant(v16i, [0] * 16))
        offs = [builder.mul(pst, ir.Constant(i32, p)) for p in range(nplanes)]
        cj, oj, opst = builder.add(sc(11), jj), builder.add(sc(14), jj), sc(13)
        # every lane's flow zero: the sanitised pixels themselves, nothing fetched (path 1)
        all_ = _fn(builder, "llvm.vector.reduce.and.v16i1", ir.IntType(1),
                   [ir.VectorType(ir.IntType(1), 16)])
        fn = builder.function
        bz, bf, bdone = (fn.append_basic_block(n) for n in ("b16_zero", "b16_fetch",
                                                            "b16_done"))
        builder.cbranch(builder.call(all_, [zm]), bz, bf)
        builder.position_at_end(bz)
        for p in range(nplanes):
            e = _vload(builder, base, builder.add(offs[p], cj), v16f)
            _vstore(builder, _sval16(builder, e), optr,
                    builder.add(builder.mul(opst, ir.Constant(i32, p)), oj))
        builder.branch(bdone)
        builder.position_at_end(bf)
        taps, path = _fetch16(builder, base, offs, w, h, xa, xb, ya, yb)
        for p in range(nplanes):
            po = builder.add(offs[p], cj)
            vals = taps[p] + [_vload(builder, base, po, v16f)]
            t = None
            for v in vals:
                d = builder.fsub(v, v)  # 0, or NaN for NaN and +-inf
                t = d if t is None else builder.fadd(t, d)
            bad = builder.call(any_, [builder.fcmp_unordered("uno", t, t)])
            fn = builder.function
            bfast, bslow, bjoin = (fn.append_basic_block(n) for n in
                                   ("b16_finite", "b16_sanitise", "b16_store"))
            builder.cbranch(bad, bslow, bfast)
            res = {}
            for blk, san in ((bfast, False), (bslow, True)):
                builder.position_at_end(blk)
                a, b, c, d, e = (_sval16(builder, v) for v in vals) if san else vals
                r = builder.fmul(a, wts[0])
                r = builder.call(fma, [b, wts[1], r])
                r = builder.call(fma, [c, wts[2], r])
                r = builder.call(fma, [d, wts[3], r])
                res[blk] = builder.select(zm, e, r)
                builder.branch(bjoin)
            builder.position_at_end(bjoin)
            r = builder.phi(v16f)
            for blk in (bfast, bslow):
                r.add_incoming(res[blk], blk)
            _vstore(builder, r, optr, builder.add(builder.mul(opst, ir.Constant(i32, p)), oj))
        bend = builder.block
        builder.branch(bdone)
        builder.position_at_end(bdone)
        res = builder.phi(i32)
        res.add_incoming(ir.Constant(i32, 1), bz)
        res.add_incoming(path, bend)
        return res

    return sig, codegen


@intrinsic
def bilinear16x3(typingctx, img, pst, w, h, XA, XB, YA, YB, WT, Z, j, coff, out, opst,
                 ooff):
    """Pixels j .. j + 15 of a row of grid_sample(bilinear) of a 3-plane image, as the
    warp kernels compute them (fgcli.kernels.warp._bil_pair): taps (XA, YA), (XB, YA),
    (XA, YB), (XB, YB) (1-D int32 row buffers, lanes j..j+15), each sanitised (sval_b),
    weighted by WT (C-contiguous float32 (4, n): nw, ne, sw, se) in the reference's FMA
    chain fma(se, ., fma(sw, ., fma(ne, ., nw * .))); where Z (int32 row buffer) is
    non-zero, the sanitised pixel itself (img at p * pst + coff + j + lane): the zero-flow
    case. Plane p = 0, 1, 2 of img starts at p * pst, rows of w (C-contiguous float32, flat
    int32 offsets); its results go to out at p * opst + ooff + j (a frame's row, or a row
    buffer). Returns the fetch path (2, 3: window rows; 0: gathered; 1: every lane's Z set,
    so the centres only, no tap fetched: the static parts of a frame).

    When no tap or centre of a plane is NaN or infinite (checked on the 16 lanes: the sum
    of every v - v is not NaN), the sanitising selects are skipped (they would change
    nothing). AVX-512 only (HAVE_AVX512); every lane is written."""
    return _bilinear16(3, img, pst, w, h, XA, XB, YA, YB, WT, Z, j, coff, out, opst,
                       ooff)


@intrinsic
def bilinear16x1(typingctx, img, pst, w, h, XA, XB, YA, YB, WT, Z, j, coff, out, opst,
                 ooff):
    """bilinear16x3 of a one-plane image (pst and opst: unused, any int)."""
    return _bilinear16(1, img, pst, w, h, XA, XB, YA, YB, WT, Z, j, coff, out, opst,
                       ooff)


@intrinsic
def nearest16(typingctx, img, w, h, JX, JY, j, out, ooff):
    """out[ooff + j + lane] = img.flat[JY * w + JX] for lanes j .. j + 15 (1-D int32 row
    buffers JX, JY: 0 <= JX < w, 0 <= JY < h; C-contiguous float32 img (one plane of rows
    of w) and out, int32 offsets), NaN read as +inf (sample_nearest of a depth). Returns
    the fetch path as bilinear16x3. AVX-512 only (HAVE_AVX512)."""
    if not (_f32_arrays(img, out) and _i32_arrays(JX, JY)):
        return None
    sig = types.int32(img, w, h, JX, JY, j, out, ooff)

    def codegen(context, builder, sig, args):
        i32, v16i, v16f = _v16(builder)
        tys = sig.args
        arr = lambda k: context.make_array(tys[k])(context, builder, args[k])  # noqa: E731
        sc = lambda k: context.cast(builder, args[k], tys[k], types.int32)  # noqa: E731
        w, h, jj = sc(1), sc(2), sc(5)
        jx, jy = (_vload(builder, arr(k).data, jj, v16i) for k in (3, 4))
        taps, path = _fetch16(builder, arr(0).data, [ir.Constant(i32, 0)], w, h, jx, jx, jy, jy,
                              ntaps=1)
        t = taps[0][0]
        inf = ir.Constant(v16f, [float("inf")] * 16)
        _vstore(builder, builder.select(builder.fcmp_unordered("!=", t, t), inf, t),
                arr(6).data, builder.add(sc(7), jj))
        return path

    return sig, codegen


@intrinsic
def taps16(typingctx, img, w, h, XA, XB, YA, YB, j, T):
    """T[:, j + lane] = the four taps img.flat[YA * w + XA], [YA * w + XB], [YB * w + XA],
    [YB * w + XB] of lanes j .. j + 15, values as they are (1-D int32 row buffers:
    0 <= XA <= XB < w, 0 <= YA <= YB < h; C-contiguous float32 img, one plane of rows of
    w; C-contiguous float32 T (4, n)). Returns the fetch path as bilinear16x3. AVX-512 only
    (HAVE_AVX512)."""
    if not (_f32_arrays(img, T) and _i32_arrays(XA, XB, YA, YB) and T.ndim == 2):
        return None
    sig = types.int32(img, w, h, XA, XB, YA, YB, j, T)

    def codegen(context, builder, sig, args):
        i32, v16i, v16f = _v16(builder)
        tys = sig.args
        arr = lambda k: context.make_array(tys[k])(context, builder, args[k])  # noqa: E731
        sc = lambda k: context.cast(builder, args[k], tys[k], types.int32)  # noqa: E731
        w, h, jj = sc(1), sc(2), sc(7)
        xa, xb, ya, yb = (_vload(builder, arr(k).data, jj, v16i) for k in (3, 4, 5, 6))
        taps, path = _fetch16(builder, arr(0).data, [ir.Constant(i32, 0)], w, h, xa, xb, ya,
                              yb)
        t = arr(8)
        tw = builder.lshr(builder.trunc(cgutils.unpack_tuple(builder, t.strides, 2)[0], i32),
                          ir.Constant(i32, 2))
        for k in range(4):
            _vstore(builder, taps[0][k], t.data,
                    builder.add(jj, builder.mul(tw, ir.Constant(i32, k))))
        return path

    return sig, codegen


@intrinsic
def fetch16x2(typingctx, img, pst, w, h, JX, JY, j, T, toff, tst):
    """T[p * tst + toff + j + lane] = img.flat[p * pst + JY * w + JX] for planes p = 0, 1 and
    lanes j .. j + 15 (1-D int32 row buffers JX, JY: 0 <= JX < w, 0 <= JY < h;
    C-contiguous float32 img and T, int32 offsets and strides): two planes' nearest reads
    (a vector field at data-dependent pixels), values as they are. Returns the fetch path
    as bilinear16x3. AVX-512 only (HAVE_AVX512)."""
    if not (_f32_arrays(img, T) and _i32_arrays(JX, JY)):
        return None
    sig = types.int32(img, pst, w, h, JX, JY, j, T, toff, tst)

    def codegen(context, builder, sig, args):
        i32, v16i, v16f = _v16(builder)
        tys = sig.args
        arr = lambda k: context.make_array(tys[k])(context, builder, args[k])  # noqa: E731
        sc = lambda k: context.cast(builder, args[k], tys[k], types.int32)  # noqa: E731
        pst, w, h, jj, toff, tst = sc(1), sc(2), sc(3), sc(6), sc(8), sc(9)
        jx, jy = (_vload(builder, arr(k).data, jj, v16i) for k in (4, 5))
        taps, path = _fetch16(builder, arr(0).data, [ir.Constant(i32, 0), pst], w, h, jx, jx,
                              jy, jy, ntaps=1)
        o = builder.add(toff, jj)
        for p in range(2):
            _vstore(builder, taps[p][0], arr(7).data, builder.add(o, builder.mul(
                tst, ir.Constant(i32, p))))
        return path

    return sig, codegen


@intrinsic
def lut16(typingctx, tab, I, j, out):
    """out[j + lane] = tab[I[j + lane]] for lanes j .. j + 15 (1-D C-contiguous int32
    arrays, 0 <= I < tab.size, int32 j): a table lookup as two 8-lane AVX2 gathers
    (vpgatherdd). AVX2 only (HAVE_AVX2).

    Why: LLVM's cost model for this machine (Zen 3: no fast gathers) vectorises a loop of
    table reads with each lane's index moved to a scalar register and loaded alone
    (vpextrd / vpinsrd, ~14 cycles a pixel); the step tables' lookups (luma8, the depth
    priority) through this: luma8_u8_plane_kernel 1.6x faster on Zen 3."""
    if not (_i32_arrays(tab, I, out) and all(a.ndim == 1 for a in (tab, I, out))
            and isinstance(j, types.Integer)):
        return None
    sig = types.void(tab, I, j, out)

    def codegen(context, builder, sig, args):
        i32, v16i, _ = _v16(builder)
        v8i = ir.VectorType(i32, 8)
        tys = sig.args
        arr = lambda k: context.make_array(tys[k])(context, builder, args[k])  # noqa: E731
        jj = context.cast(builder, args[2], tys[2], types.int32)
        idx = _vload(builder, arr(1).data, jj, v16i)
        gat = _fn(builder, "llvm.x86.avx2.gather.d.d.256", v8i,
                  [v8i, ir.IntType(8).as_pointer(), v8i, v8i, ir.IntType(8)])
        b8 = builder.bitcast(arr(0).data, ir.IntType(8).as_pointer())
        every = ir.Constant(v8i, [-1] * 8)
        g = [builder.call(gat, [ir.Constant(v8i, None), b8, builder.shuffle_vector(
            idx, idx, ir.Constant(v8i, list(range(8 * k, 8 * k + 8)))), every,
            ir.Constant(ir.IntType(8), 4)]) for k in (0, 1)]
        _vstore(builder, builder.shuffle_vector(g[0], g[1], ir.Constant(v16i, list(range(16)))),
                arr(3).data, jj)
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def half_bits_f16c(typingctx, v):
    """The IEEE binary16 bits of float32 v, rounded to nearest even, as an int32 in
    0 .. 65535: LLVM's fptrunc to half, one vcvtps2ph per 8 lanes where the CPU has F16C
    (HAVE_F16C; without it LLVM would call a runtime function numba does not link).
    torch's ``.to(torch.float16)`` for every float32 (inf beyond +-65504, NaN as NaN)."""
    if v != types.float32:
        return None

    def codegen(context, builder, sig, args):
        h = builder.fptrunc(args[0], ir.HalfType())
        return builder.zext(builder.bitcast(h, ir.IntType(16)), ir.IntType(32))

    return types.int32(types.float32), codegen
