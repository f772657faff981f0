"""Mob-FGSR Eq. 1 blend (colour and depth in one pass) and the cross-fade baseline
(fgcli.ops.blend) as numba kernels.

Exactness: every choice and the lerp are the reference's float32 operations (lerp with
torch's FMA formula), so colour and depth are bit-identical except where the brightness
difference B lands within ~1e-6 of t_b: torch computes the sRGB power x^(1/2.4) with
Sleef's vectorised exp/log (<= 1 ulp), the kernel with a 9k-entry table over the float32
exponent/mantissa, linearly interpolated (relative error < 1e-7; libm's scalar
exp/log would cost ~50 ms per 1080p frame). A pixel whose B differs from t_b by more than
a few float32 ulps makes the same choice."""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from fgcli.kernels._common import F32, INLINE, KERNEL, ROWS, bits, sdepth_b, smv_b, sval, sval_b
from fgcli.kernels._intrin import bilinear16x3, fma, nearest16
from fgcli.kernels.warp import I32, _taps_px, _warp_px

_LO = np.float32(0.0031308)  # the clamp of fgcli.ops.blend._encode_fast
_SHIFT = 13  # table step: 2**-10 of an octave


def encode_table():
    """(table float32, base index): x^(1/2.4) at the float32 values whose low 13 mantissa
    bits are 0, from the octave of 0.0031308 to 1.0 (+1 entry)."""
    p = float(np.float32(1.0 / 2.4))
    lo = int(np.array(_LO).view(np.int32)) >> _SHIFT
    hi = int(np.array(np.float32(1.0)).view(np.int32)) >> _SHIFT
    idx = np.arange(lo, hi + 2, dtype=np.int64)
    xs = (idx << _SHIFT).astype(np.int32).view(np.float32).astype(np.float64)
    return (xs ** p).astype(np.float32), lo


@njit(**INLINE)
def _enc(v, table, base):
    if v < _LO:
        v = _LO
    if v > F32(1.0):
        v = F32(1.0)
    b = bits(v)
    i = (b >> _SHIFT) - base
    t = F32(b & ((1 << _SHIFT) - 1)) * F32(1.0 / (1 << _SHIFT))
    t0 = table[i]
    return t0 + t * (table[i + 1] - t0)


@njit(**INLINE)
def _agree_b(x, y, t):
    """fgcli.ops.blend._agree (x == y or |x - y| <= min(x, y) t) as a bool."""
    return (x == y) | (abs(x - y) <= min(x, y) * t)


@njit(**INLINE)
def _lerp_b(a, b, w):
    """torch.lerp's float32 formula (vectorised CPU kernel: one FMA), as a select."""
    return fma(w, b - a, a) if abs(w) < F32(0.5) else fma(w - F32(1.0), b - a, b)


# The Eq. 1 helpers run only inside ROWS functions (_blend_rows, _warp_blend_rows), which
# numba compiles with noalias arrays and no parfor alias analysis, so their flags are
# bools: LLVM keeps them as i1 lanes. As int32 flags they ran on 64-bit lanes (numba
# computes int32 & int32 and int32 - int32 in int64, and the selects and compares of the
# widened values stayed so: the first pass's vector loop worked on 38 <8 x i64> values).
# In a parallel loop's body the parfor analysis would count a copied bool as a possible
# array alias and drop noalias from every array (a warp + blend kernel tried so ran 1.5x
# slower): there flags stay int32. blend_kernel lists the few pixels its table test needs
# first (a scalar compaction): a loop over the row that tests each pixel was vectorised
# too (masked table gathers at every pixel), 2x slower.
@njit(**INLINE)
def _eq1_px(c0, c1, d0, d1, v0, v1, ys, x, y, dt, has_dt, mvalid, to1, to0, has_static,
            a, near_w, td, endpoint, out_d):
    """Eq. 1 at pixel x of sample row ``ys`` (c0, c1 (3, ., W), d0, d1, v0, v1 (., W): the
    warped samples, v0 / v1 uint8) and frame row ``y`` (dt, mvalid (uint8), to1, to0: full
    frames), except the brightness test: writes the depth, returns (weight, needs the
    brightness test)."""
    u0 = np.uint8(0)
    thr_static = F32(1e-3)
    e0 = sdepth_b(d0[ys, x])
    e1 = sdepth_b(d1[ys, x])
    p0 = v0[ys, x] != u0
    p1 = v1[ys, x] != u0
    agree = _agree_b(e0, e1, td)
    take0 = e0 > e1
    if has_dt:
        t = sdepth_b(dt[y, x])
        m0 = _agree_b(e0, t, td)
        m1 = _agree_b(e1, t, td)
        take0 = m0 if m0 != m1 else take0
    dis = p0 & p1 & (not agree)
    pick0 = (dis & take0) | (p0 & (not p1))
    pick1 = (dis & (not take0)) | (p1 & (not p0))
    none = not (p0 | p1)
    static = False
    if has_static:
        static = ((mvalid[y, x] != u0) &
                  (max(abs(to1[0, y, x]), abs(to1[1, y, x])) < thr_static) &
                  (max(abs(to0[0, y, x]), abs(to0[1, y, x])) < thr_static))
    mid = (not (pick0 | pick1 | none)) & agree & (endpoint == 0) & (not static)
    eqc = ((sval_b(c0[0, ys, x]) == sval_b(c1[0, ys, x])) &
           (sval_b(c0[1, ys, x]) == sval_b(c1[1, ys, x])) &
           (sval_b(c0[2, ys, x]) == sval_b(c1[2, ys, x])))
    wt = a
    wt = near_w if ((mid & eqc) | none) else wt
    wt = F32(0.0) if pick0 else wt
    wt = F32(1.0) if pick1 else wt
    take_d0 = pick0 | ((agree | none) & (not pick1) & (near_w == F32(0.0)))
    out_d[y, x] = e0 if take_d0 else e1
    return wt, mid & (not eqc)


@njit(**INLINE)
def _similar(c0, c1, ys, x, tb, table, base):
    """Eq. 1's brightness test on the sRGB-encoded samples (scalar: six table lookups)."""
    q0 = abs(_enc(sval(c0[0, ys, x]), table, base) - _enc(sval(c1[0, ys, x]), table, base))
    q1 = abs(_enc(sval(c0[1, ys, x]), table, base) - _enc(sval(c1[1, ys, x]), table, base))
    q2 = abs(_enc(sval(c0[2, ys, x]), table, base) - _enc(sval(c1[2, ys, x]), table, base))
    bd = fma(q1, F32(1.055), (q0 + q2) * F32(0.5 * 1.055))
    return np.int32(bd <= tb)


# Bounds of the brightness difference that decide most pixels without the table (exact:
# they decide only where the table's own result is certain to agree). On [_LO, 1],
# x^(5/12) has slope p x^(p - 1) (p = 5/12): at most p 2^ceil(-e 7/12) above 2^e, at least
# p (at 1); so |a^p - b^p| lies between those slopes times |a - b| (mean value theorem).
# B is accepted when its upper bound is below t_b, and rejected when its lower bound is
# above, each with a margin (relative 1e-5 and absolute 4e-6) far above the table's error
# (< 1e-6 on B) and the bounds' float32 rounding (< 1e-6 relative). Camera motion: ~94 % of
# the pixels that need the test are decided so (blade / orbit at 1080p), the rest by the
# table, one by one.
_P_LO = np.float32(0.4166)  # below 5/12: a lower bound of the slope


@njit(**INLINE)
def _slope_hi(m):
    """An upper bound of p x^(p-1) for x >= m (m in [_LO, 1]): p 2^ceil(-e 7/12), e the
    binary exponent of m."""
    e = np.int32(127) - ((bits(m) >> 23) & np.int32(255))  # -e, 0..9 here
    # ceil(7 e / 12) = (7 e + 11) // 12, as a multiply and shift: exact for 7 e + 11 < 128
    # (e <= 9 gives at most 74); numba's // on ints keeps Python's floor semantics and
    # zero check, which cost ~1 ms per 1080p frame in the blend
    n = ((np.int32(7) * e + np.int32(11)) * np.int32(43)) >> np.int32(9)
    return F32(5.0 / 12.0 * 1.0000002) * (np.int32((np.int32(127) + n) << 23)).view(np.float32)


@njit(**INLINE)
def _bright_bounds(c0, c1, ys, x, tb_acc, tb_rej):
    """(surely similar, surely not) by the slope bounds, without the table (bools)."""
    a0 = min(max(sval_b(c0[0, ys, x]), _LO), F32(1.0))
    a1 = min(max(sval_b(c0[1, ys, x]), _LO), F32(1.0))
    a2 = min(max(sval_b(c0[2, ys, x]), _LO), F32(1.0))
    b0 = min(max(sval_b(c1[0, ys, x]), _LO), F32(1.0))
    b1 = min(max(sval_b(c1[1, ys, x]), _LO), F32(1.0))
    b2 = min(max(sval_b(c1[2, ys, x]), _LO), F32(1.0))
    d0 = abs(a0 - b0)
    d1 = abs(a1 - b1)
    d2 = abs(a2 - b2)
    hi = F32(1.055) * (_slope_hi(min(a1, b1)) * d1 +
                       F32(0.5) * (_slope_hi(min(a0, b0)) * d0 + _slope_hi(min(a2, b2)) * d2))
    lo = F32(1.055) * _P_LO * (d1 + F32(0.5) * (d0 + d2))
    return hi <= tb_acc, lo >= tb_rej


@njit(**INLINE)
def _out_px(c0, c1, k, ys, x, y, wt, endpoint, out_c):
    """The lerp (or the endpoint frame) into out_c[k, y, x]."""
    u = sval_b(c0[k, ys, x])
    v = sval_b(c1[k, ys, x])
    r = _lerp_b(u, v, wt)
    r = u if endpoint == 1 else r
    out_c[k, y, x] = v if endpoint == 2 else r


@njit(**INLINE)
def _eq1_row(c0, c1, d0, d1, v0, v1, ys, y, dt, has_dt, mvalid, to1, to0, has_static, a,
             near_w, td, tb_acc, tb_rej, endpoint, out_d, wts, need):
    """The blend's first pass over a row (every case of Eq. 1 but the undecided brightness
    tests): wts, need (uint8) and the depths of row y; returns 1 when a pixel needs the
    table, else 0. The kernels call it once with has_static a literal True and once with
    False, in the two arms of a branch: the static test's uint8 read under a runtime flag
    has no AVX2 masked load (AVX-512 has one), and LLVM kept the whole loop scalar for it
    (on Zen 3 this pass ran 3.4x slower, blend_kernel 2.2x)."""
    w = d0.shape[1]
    for x in range(w):
        wt, nd = _eq1_px(c0, c1, d0, d1, v0, v1, ys, x, y, dt, has_dt, mvalid, to1, to0,
                         has_static, a, near_w, td, endpoint, out_d)
        sure, sure_not = _bright_bounds(c0, c1, ys, x, tb_acc, tb_rej)
        wts[x] = near_w if (nd & sure) else wt
        need[x] = np.uint8(nd & (not (sure | sure_not)))
    # (whether any pixel needs the table, in a loop of its own: a count in the loop above
    # was an int64 reduction, which halved its vector width)
    m = np.uint8(0)
    for x in range(w):
        m = max(m, need[x])
    return m


@njit(**ROWS)
def _blend_rows(ya, yb, c0, c1, d0, d1, v0, v1, dt, has_dt, mvalid, to1, to0, has_static, a,
                near_w, td, tb, tb_acc, tb_rej, endpoint, table, base, out_c, out_d, wts, need,
                idx):
    """blend_kernel's rows ya..yb (one chunk of its parallel loop)."""
    h, w = d0.shape
    for y in range(ya, yb):
        if has_static:  # (versioned: _eq1_row)
            nn = _eq1_row(c0, c1, d0, d1, v0, v1, y, y, dt, has_dt, mvalid, to1, to0,
                          True, a, near_w, td, tb_acc, tb_rej, endpoint, out_d, wts, need)
        else:
            nn = _eq1_row(c0, c1, d0, d1, v0, v1, y, y, dt, has_dt, mvalid, to1, to0,
                          False, a, near_w, td, tb_acc, tb_rej, endpoint, out_d, wts, need)
        if nn > 0:  # the undecided few: the table, pixel by pixel
            n = 0
            for x in range(w):
                idx[n] = np.int32(x)
                n += np.int32(need[x])
            for i in range(n):
                x = np.int64(idx[i])
                if _similar(c0, c1, y, x, tb, table, base) != 0:
                    wts[x] = near_w
        # one plane at a time: a pixel loop writing all three planes ran 3-6x slower
        for k in range(3):
            for x in range(w):
                _out_px(c0, c1, k, y, x, y, wts[x], endpoint, out_c)


@njit(**KERNEL)
def blend_kernel(c0, c1, d0, d1, v0, v1, dt, has_dt, mvalid, to1, to0, has_static,
                 a, near_w, td, tb, tb_acc, tb_rej, endpoint, table, base, out_c, out_d):
    """Eq. 1 per pixel (see fgcli.ops.blend.blend_interp): colour (3, H, W) and depth.
    a: float32 alpha; near_w 0 or 1; endpoint 0 (none), 1 (alpha 0: c0), 2 (alpha 1: c1).

    Per row, three passes over x: every case but the brightness test (vectorised), the
    brightness test for the pixels that need it (scalar: six table lookups each), the
    lerp and the outputs (vectorised, one colour plane after the other)."""
    h, w = d0.shape
    nch = min(h, 64)
    for ch in prange(nch):
        ya = np.int64(ch) * h // nch
        yb = (np.int64(ch) + 1) * h // nch
        wts = np.empty(w, dtype=np.float32)
        need = np.empty(w, dtype=np.uint8)
        idx = np.empty(w, dtype=np.int32)
        _blend_rows(ya, yb, c0, c1, d0, d1, v0, v1, dt, has_dt, mvalid, to1, to0, has_static, a,
                    near_w, td, tb, tb_acc, tb_rej, endpoint, table, base, out_c, out_d, wts, need,
                    idx)


@njit(**ROWS)
def _warp_blend_rows(ya, yb, c1, d1, to1, c0, d0, to0, gxn, gyn, kx, ky, dt, has_dt,
                     mvalid, sto1, sto0, has_static, a, near_w, td, tb, tb_acc, tb_rej,
                     endpoint, table, base, out_c, out_d, XA, XB, YA, YB, JX, JY, Z, WT,
                     s1, s0, sd1, sd0, v1, v0, wts, need, idx):
    """warp_blend_kernel's rows ya..yb (one chunk of its parallel loop), with the chunk's row
    buffers."""
    h, w = d1.shape
    hw = F32(w * 0.5)
    hh = F32(h * 0.5)
    wm1 = F32(w - 1)
    hm1 = F32(h - 1)
    w32 = I32(w)
    h32 = I32(h)
    hw32 = I32(h * w)
    nb = w // 16
    for y in range(ya, yb):
        yf = F32(y)
        gyy = gyn[y]
        lo_y = F32(-0.5) - yf
        hi_y = F32(h - 0.5) - yf
        for x in range(w):
            _taps_px(to1, v1, 0, x, y, F32(I32(x)), lo_y, hi_y, gxn[x], gyy, kx, ky, hw, hh, wm1,
                     hm1, w32, h32, XA, XB, YA, YB, WT, Z, JX, JY)
        for blk in range(nb):
            bilinear16x3(c1, hw32, w32, h32, XA, XB, YA, YB, WT, Z, I32(16 * blk),
                         I32(y * w), s1, w32, I32(0))
            nearest16(d1, w32, h32, JX, JY, I32(16 * blk), sd1, I32(0))
        for x in range(16 * nb, w):
            _warp_px(c1, d1, to1, s1, sd1, v1, x, y, 0, F32(I32(x)), yf, lo_y, hi_y, gxn[x], gyy,
                     kx, ky, hw, hh, wm1, hm1, w32, h32, hw32)
        for x in range(w):
            _taps_px(to0, v0, 0, x, y, F32(I32(x)), lo_y, hi_y, gxn[x], gyy, kx, ky, hw, hh, wm1,
                     hm1, w32, h32, XA, XB, YA, YB, WT, Z, JX, JY)
        for blk in range(nb):
            bilinear16x3(c0, hw32, w32, h32, XA, XB, YA, YB, WT, Z, I32(16 * blk),
                         I32(y * w), s0, w32, I32(0))
            nearest16(d0, w32, h32, JX, JY, I32(16 * blk), sd0, I32(0))
        for x in range(16 * nb, w):
            _warp_px(c0, d0, to0, s0, sd0, v0, x, y, 0, F32(I32(x)), yf, lo_y, hi_y, gxn[x], gyy,
                     kx, ky, hw, hh, wm1, hm1, w32, h32, hw32)
        # blend_kernel's three passes on the sample row 0
        if has_static:  # (versioned: _eq1_row)
            nn = _eq1_row(s0, s1, sd0, sd1, v0, v1, 0, y, dt, has_dt, mvalid, sto1, sto0,
                          True, a, near_w, td, tb_acc, tb_rej, endpoint, out_d, wts, need)
        else:
            nn = _eq1_row(s0, s1, sd0, sd1, v0, v1, 0, y, dt, has_dt, mvalid, sto1, sto0,
                          False, a, near_w, td, tb_acc, tb_rej, endpoint, out_d, wts, need)
        if nn > 0:
            n = 0
            for x in range(w):
                idx[n] = np.int32(x)
                n += np.int32(need[x])
            for i in range(n):
                x = np.int64(idx[i])
                if _similar(s0, s1, 0, x, tb, table, base) != 0:
                    wts[x] = near_w
        for k in range(3):
            for x in range(w):
                _out_px(s0, s1, k, 0, x, y, wts[x], endpoint, out_c)


@njit(**KERNEL)
def warp_blend_kernel(c1, d1, to1, c0, d0, to0, gxn, gyn, kx, ky, dt, has_dt, mvalid, sto1,
                      sto0, has_static, a, near_w, td, tb, tb_acc, tb_rej, endpoint, table,
                      base, out_c, out_d):
    """mob-fgsr's warp of both frames (fgcli.kernels.warp.warp_window_kernel) and its Eq. 1
    blend (blend_kernel) in one pass, row by row: the warped samples, their depths and
    valid flags go to row buffers that stay in cache instead of eight frame-sized planes
    written and read back (~140 MB per 1080p frame). Arguments: warp_window_kernel's
    inputs, then blend_kernel's (sto1, sto0: its to1, to0 of the static test); the same
    values, bit for bit. AVX-512 or AVX2 (the window fetches: fgcli.kernels._intrin)."""
    h, w = d1.shape
    nch = min(h, 64)
    for ch in prange(nch):
        ya = np.int64(ch) * h // nch
        yb = (np.int64(ch) + 1) * h // nch
        # (row buffers, allocated here one by one: arrays unpacked from a helper's tuple, or
        # reshaped views, would count as aliases and no loop would be vectorised)
        XA = np.empty(w, dtype=np.int32)
        XB = np.empty(w, dtype=np.int32)
        YA = np.empty(w, dtype=np.int32)
        YB = np.empty(w, dtype=np.int32)
        JX = np.empty(w, dtype=np.int32)
        JY = np.empty(w, dtype=np.int32)
        Z = np.empty(w, dtype=np.int32)
        WT = np.empty((4, w), dtype=np.float32)
        s1 = np.empty((3, 1, w), dtype=np.float32)  # the samples: row 0 of (3, 1, w)
        s0 = np.empty((3, 1, w), dtype=np.float32)
        sd1 = np.empty((1, w), dtype=np.float32)
        sd0 = np.empty((1, w), dtype=np.float32)
        v1 = np.empty((1, w), dtype=np.uint8)
        v0 = np.empty((1, w), dtype=np.uint8)
        wts = np.empty(w, dtype=np.float32)
        need = np.empty(w, dtype=np.uint8)
        idx = np.empty(w, dtype=np.int32)
        _warp_blend_rows(ya, yb, c1, d1, to1, c0, d0, to0, gxn, gyn, kx, ky, dt, has_dt,
                         mvalid, sto1, sto0, has_static, a, near_w, td, tb, tb_acc, tb_rej,
                         endpoint, table, base, out_c, out_d, XA, XB, YA, YB, JX, JY, Z, WT,
                         s1, s0, sd1, sd0, v1, v0, wts, need, idx)


@njit(**KERNEL)
def crossfade_kernel(c0, c1, d0, d1, mv1, a, ms, out_c, out_d, out_mv):
    """blend baseline: lerp(c0, c1, a), min depth, mv = sanitize_mv(mv1) * ms. Channel
    loop outside the row loop (a runtime count inside it keeps the row loop scalar)."""
    ch, h, w = c0.shape
    for py in prange(h):
        y = np.int64(py)  # prange indices are unsigned: keep index arithmetic signed
        for k in range(ch):
            for x in range(w):
                out_c[k, y, x] = _lerp_b(sval_b(c0[k, y, x]), sval_b(c1[k, y, x]), a)
        for x in range(w):
            out_d[y, x] = min(sdepth_b(d0[y, x]), sdepth_b(d1[y, x]))
            out_mv[0, y, x] = smv_b(mv1[0, y, x]) * ms
            out_mv[1, y, x] = smv_b(mv1[1, y, x]) * ms


@njit(cache=True, nogil=True)
def any_nonzero_kernel(a):
    """True when any element of the flat float32 array is non-zero or NaN (early exit:
    a moving frame answers after its first moving pixel)."""
    for i in range(a.shape[0]):
        if a[i] != F32(0.0):  # NaN != 0 is True
            return True
    return False

