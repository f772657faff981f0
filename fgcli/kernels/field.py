"""FSR 3's footprint scatters (fgcli.ops.fsr3.vector_field and reconstruct_depths) as numba
kernels: the source positions and packed entries come from the reference's own torch code;
the kernels do what torch does with four scatter_reduce calls per channel and the
secondary walk (a few dozen full passes): one pass over the sources, each writing its
bilinear footprint (and its secondary entries) with a plain maximum or minimum. Every
float operation is the reference's (clamp, floor, the tap weights, the walk's positions),
and a maximum or minimum does not depend on the order of writes, so the result is
identical to the reference."""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from fgcli.kernels._common import F32, INLINE, KERNEL, clamp_b, smv_b, sval_b
from fgcli.kernels._intrin import fma
from fgcli.kernels.warp import _coords

_PRIMARY = np.int64(1) << np.int64(31)


@njit(**INLINE)
def _taps(px, py, h, w, thr):
    """The reference's _footprint for one position: base column/row in the (h+2) x (w+2)
    buffer and the four taps' write flags (weight > thr), order (0,0), (1,0), (0,1), (1,1)."""
    x = clamp_b(px, F32(-2.0), F32(w + 1.0))
    y = clamp_b(py, F32(-2.0), F32(h + 1.0))
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = x - x0
    fy = y - y0
    ex = F32(1.0) - fx
    ey = F32(1.0) - fy
    xa = np.int64(clamp_b(x0, F32(-1.0), F32(w))) + 1
    xb = np.int64(clamp_b(x0 + F32(1.0), F32(-1.0), F32(w))) + 1
    ya = np.int64(clamp_b(y0, F32(-1.0), F32(h))) + 1
    yb = np.int64(clamp_b(y0 + F32(1.0), F32(-1.0), F32(h))) + 1
    return xa, xb, ya, yb, ex * ey > thr, fx * ey > thr, ex * fy > thr, fx * fy > thr


@njit(cache=True, nogil=True)
def field_scatter_kernel(pos, key, dist, d, h, w, thr, steps, buf, sec):
    """vector_field's scatter, one component. pos (2, N) float32 footprint positions; key
    (N,) int64 primary entries of the component; dist (N,) float32 secondary walk lengths;
    d (2, N) float32 unit steps; steps: secondary steps (0: none); buf, sec ((h+2)*(w+2),)
    int64 zeroed -> buf = max(primary, secondary) entries (the caller crops the ring).

    The two components are independent (each source writes both at the same taps with the
    same priority bits, so a texel's primary flag is the same in both: the secondary walk
    of either counts the same hits), so the caller runs them on two threads."""
    n = pos.shape[1]
    w2 = w + 2
    for i in range(n):
        xa, xb, ya, yb, t00, t10, t01, t11 = _taps(pos[0, i], pos[1, i], h, w, thr)
        a = key[i]
        for q, t in ((ya * w2 + xa, t00), (ya * w2 + xb, t10), (yb * w2 + xa, t01),
                     (yb * w2 + xb, t11)):
            if t and a > buf[q]:
                buf[q] = a
    if steps < 1:
        return
    # secondary entries walk back from the footprint, counting primary texels hit
    for i in range(n):
        di = dist[i]
        if not di >= F32(1.0):
            continue
        a = key[i] - _PRIMARY
        hits = 0
        for k in range(1, steps + 1):
            if not (di >= F32(k)) or hits > 3:
                break
            kf = F32(k)
            qx = pos[0, i] - d[0, i] * kf
            qy = pos[1, i] - d[1, i] * kf
            xi = np.int64(clamp_b(np.floor(qx), F32(-1.0), F32(w))) + 1
            yi = np.int64(clamp_b(np.floor(qy), F32(-1.0), F32(h))) + 1
            if xi < 1 or xi > w or yi < 1 or yi > h:
                continue
            q = yi * w2 + xi
            if buf[q] >= _PRIMARY:
                hits += 1
            if hits > 3:
                continue
            if a > sec[q]:
                sec[q] = a
    for q in range(buf.shape[0]):
        if sec[q] > buf[q]:
            buf[q] = sec[q]


@njit(cache=True, nogil=True)
def depth_scatter_kernel(pos, depth, h, w, thr, buf):
    """reconstruct_depths' scatter for one target time: pos (2, N) float32, depth (N,)
    float32 sanitised -> buf ((h+2)*(w+2),) float32 (+inf initialised) holds the minimum
    depth written into each texel's footprint taps."""
    n = pos.shape[1]
    w2 = w + 2
    for i in range(n):
        xa, xb, ya, yb, t00, t10, t01, t11 = _taps(pos[0, i], pos[1, i], h, w, thr)
        z = depth[i]
        for q, t in ((ya * w2 + xa, t00), (ya * w2 + xb, t10), (yb * w2 + xa, t01),
                     (yb * w2 + xb, t11)):
            if t and z < buf[q]:
                buf[q] = z


# ----------------------------------------------------------------------------- entries

_LR, _LG, _LB = F32(0.2126), F32(0.7152), F32(0.0722)  # fgcli.ops.color.REC709_LUMA


@njit(**INLINE)
def half_bits(v):
    """IEEE binary16 bits (round to nearest even) of a finite float32 within +-65504, as
    torch's ``.to(torch.float16).view(torch.int16) & 0xFFFF`` (checked against torch for
    every such float32). numba has no float16 type."""
    x = np.int64(np.float32(v).view(np.int32)) & np.int64(0xFFFFFFFF)
    sign = (x >> 16) & 0x8000
    a = x & 0x7FFFFFFF
    # a subnormal half (|v| < 2**-14) is the integer multiple of 2**-24, rounded to even
    sub = np.int64(np.rint(abs(v) * F32(16777216.0)))
    nrm = (a + 0xFFF + ((a >> 13) & 1) - 0x38000000) >> 13
    return sign | (sub if a < 0x38800000 else nrm)


@njit(**INLINE)
def _lum(c, y, x):
    """luminance(sanitize_values(c)) at one pixel."""
    return (sval_b(c[0, y, x]) * _LR + sval_b(c[1, y, x]) * _LG) + sval_b(c[2, y, x]) * _LB


@njit(**INLINE)
def _pack(prio, comp):
    """pack_entries for one component: prio << 16 | half bits of the clamped component."""
    c = clamp_b(comp, F32(-65504.0), F32(65504.0))
    return (prio << 16) | half_bits(c)


@njit(**KERNEL)
def entries_kernel(c0, c1, vec, hi, a1, gxn, gyn, kx, ky, pos, keys):
    """fgcli.ops.fsr3.field_entries per pixel: frame 0's luminance read bilinearly at
    p + v (grid_sample's arithmetic, on-screen test), its 5-bit agreement with frame 1's
    luminance at p, the packed primary entries of both components (keys (2, H, W) int64)
    and the footprint positions p + (1 - alpha) v (pos (2, H, W); a1 = 1 - alpha)."""
    h, w = hi.shape
    hw = F32(w * 0.5)
    hh = F32(h * 0.5)
    wm1 = F32(w - 1)
    hm1 = F32(h - 1)
    for py in prange(h):
        y = np.int64(py)
        yf = F32(y)
        gyy = gyn[y]
        lo_y = F32(-0.5) - yf
        hi_y = F32(h - 0.5) - yf
        s0 = np.empty(w, dtype=np.float32)
        ins = np.empty(w, dtype=np.float32)
        for x in range(w):
            vx = smv_b(vec[0, y, x])
            vy = smv_b(vec[1, y, x])
            xf = F32(x)
            ins[x] = F32((vx >= F32(-0.5) - xf) & (vx < F32(w - 0.5) - xf) & (vy >= lo_y)
                         & (vy < hi_y))
            zero = (vx == F32(0.0)) & (vy == F32(0.0))
            y0, x0, y1, x1, nw, ne, sw, se = _coords(vx, vy, gxn[x], gyy, kx, ky, hw, hh, wm1,
                                                     hm1, w, h)
            r = fma(sval_b(_lum(c0, y1, x1)), se,
                    fma(sval_b(_lum(c0, y1, x0)), sw,
                        fma(sval_b(_lum(c0, y0, x1)), ne, sval_b(_lum(c0, y0, x0)) * nw)))
            s0[x] = sval_b(_lum(c0, y, x)) if zero else r
        for x in range(w):
            vx = smv_b(vec[0, y, x])
            vy = smv_b(vec[1, y, x])
            a = s0[x]
            b = _lum(c1, y, x)
            a = (F32(0.0) if a < F32(0.0) else a) + F32(0.001)
            b = (F32(0.0) if b < F32(0.0) else b) + F32(0.001)
            r = (a if a < b else b) / (b if a < b else a)
            r = F32(1.0) if r != r else r
            lo = np.int64(clamp_b(np.rint(r * F32(31.0)), F32(0.0), F32(31.0)))
            lo = lo if ins[x] != F32(0.0) else np.int64(0)
            hv = hi[y, x]
            hv = 0 if hv < 0 else (1023 if hv > 1023 else hv)
            prio = (hv << 5) | lo | 32768
            keys[0, y, x] = _pack(prio, vx)
            keys[1, y, x] = _pack(prio, vy)
            pos[0, y, x] = F32(x) + vx * a1
            pos[1, y, x] = yf + vy * a1


@njit(**INLINE)
def half_value(b):
    """The float32 value of binary16 bits b (0..0xFFFF), then NaN -> 0 and +-inf ->
    +-65504 (unpack_vector_field's nan_to_num); exact, as torch's conversion."""
    sign = (b >> 15) & 1
    e = (b >> 10) & 0x1F
    m = b & 0x3FF
    sub = F32(m) * F32(5.960464477539063e-08)  # m * 2**-24, exact
    nrm = np.int32(((e + 112) << 23) | (m << 13)).view(np.float32)
    v = sub if e == 0 else nrm
    v = F32(65504.0) if e == 31 else v
    v = -v if sign == 1 else v
    return F32(0.0) if (e == 31) & (m != 0) else v


@njit(**KERNEL)
def unpack_kernel(field, vec, prio, valid):
    """fgcli.ops.fsr3.unpack_vector_field: field (2, H, W) int64 -> vec (2, H, W) float32
    (times valid, as the reference's product: -0.0 for a negative unwritten component),
    prio (H, W) int64 (16 bits of the y entry), valid (H, W) bool."""
    h, w = prio.shape
    for py in prange(h):
        y = np.int64(py)
        for x in range(w):
            p = (field[1, y, x] >> 16) & 0xFFFF
            ok = p > 0
            prio[y, x] = p
            valid[y, x] = ok
            m = F32(ok)
            vec[0, y, x] = half_value(field[0, y, x] & 0xFFFF) * m
            vec[1, y, x] = half_value(field[1, y, x] & 0xFFFF) * m
