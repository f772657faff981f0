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

from fgcli.kernels._common import F32, INLINE, KERNEL, bits, sdepth, sval
from fgcli.kernels._intrin import fma

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
def _agree(x, y, t):
    return x == y or abs(x - y) <= min(x, y) * t


@njit(**INLINE)
def lerp(a, b, w):
    """torch.lerp's float32 formula (vectorised CPU kernel: one FMA)."""
    if abs(w) < F32(0.5):
        return fma(w, b - a, a)
    return fma(w - F32(1.0), b - a, b)


@njit(**KERNEL)
def blend_kernel(c0, c1, d0, d1, v0, v1, dt, has_dt, mvalid, to1, to0, has_static,
                 a, near_w, td, tb, endpoint, table, base, out_c, out_d):
    """Eq. 1 per pixel (see fgcli.ops.blend.blend_interp): colour (3, H, W) and depth.
    a: float32 alpha; near_w 0 or 1; endpoint 0 (none), 1 (alpha 0: c0), 2 (alpha 1: c1)."""
    h, w = d0.shape
    thr_static = F32(1e-3)
    for py in prange(h):
        y = np.int64(py)  # prange indices are unsigned: keep index arithmetic signed
        for x in range(w):
            a0 = sval(c0[0, y, x])
            a1 = sval(c0[1, y, x])
            a2 = sval(c0[2, y, x])
            b0 = sval(c1[0, y, x])
            b1 = sval(c1[1, y, x])
            b2 = sval(c1[2, y, x])
            e0 = sdepth(d0[y, x])
            e1 = sdepth(d1[y, x])
            p0 = v0[y, x]
            p1 = v1[y, x]
            agree = _agree(e0, e1, td)
            take0 = e0 > e1
            if has_dt:
                t = sdepth(dt[y, x])
                m0 = _agree(e0, t, td)
                m1 = _agree(e1, t, td)
                if m0 != m1:
                    take0 = m0
            both = p0 and p1
            dis = both and not agree
            pick0 = (dis and take0) or (p0 and not p1)
            pick1 = (dis and not take0) or (p1 and not p0)
            none = not (p0 or p1)
            if pick1:
                wt = F32(1.0)
            elif pick0:
                wt = F32(0.0)
            elif none:
                wt = near_w
            else:
                wt = a
                if agree and endpoint == 0:
                    static = False
                    if has_static and mvalid[y, x]:
                        static = max(abs(to1[0, y, x]), abs(to1[1, y, x])) < thr_static and \
                            max(abs(to0[0, y, x]), abs(to0[1, y, x])) < thr_static
                    if not static:
                        if a0 == b0 and a1 == b1 and a2 == b2:
                            similar = True
                        else:
                            q0 = abs(_enc(a0, table, base) - _enc(b0, table, base))
                            q1 = abs(_enc(a1, table, base) - _enc(b1, table, base))
                            q2 = abs(_enc(a2, table, base) - _enc(b2, table, base))
                            bd = fma(q1, F32(1.055), (q0 + q2) * F32(0.5 * 1.055))
                            similar = bd <= tb
                        if similar:
                            wt = near_w
            if endpoint == 1:
                out_c[0, y, x] = a0
                out_c[1, y, x] = a1
                out_c[2, y, x] = a2
            elif endpoint == 2:
                out_c[0, y, x] = b0
                out_c[1, y, x] = b1
                out_c[2, y, x] = b2
            else:
                out_c[0, y, x] = lerp(a0, b0, wt)
                out_c[1, y, x] = lerp(a1, b1, wt)
                out_c[2, y, x] = lerp(a2, b2, wt)
            take_d0 = pick0 or ((agree or none) and not pick1 and near_w == F32(0.0))
            out_d[y, x] = e0 if take_d0 else e1


@njit(**KERNEL)
def crossfade_kernel(c0, c1, d0, d1, mv1, a, ms, out_c, out_d, out_mv):
    """blend baseline: lerp(c0, c1, a), min depth, mv = sanitize_mv(mv1) * ms."""
    ch, h, w = c0.shape
    for py in prange(h):
        y = np.int64(py)  # prange indices are unsigned: keep index arithmetic signed
        for x in range(w):
            for k in range(ch):
                out_c[k, y, x] = lerp(sval(c0[k, y, x]), sval(c1[k, y, x]), a)
            out_d[y, x] = min(sdepth(d0[y, x]), sdepth(d1[y, x]))
            for k in range(2):
                m = mv1[k, y, x]
                if m != m:
                    m = F32(0.0)
                elif m > F32(1e6):
                    m = F32(1e6)
                elif m < F32(-1e6):
                    m = F32(-1e6)
                out_mv[k, y, x] = m * ms
