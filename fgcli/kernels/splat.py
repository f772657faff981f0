"""Nearest-depth dilation and the depth-aware forward splat (fgcli.ops.splat), as numba
kernels: one pass for the dilation, two for the splat (scatter with an atomic int64 min of
``depth bits << 32 | source index``, then resolve), no frame-sized temporaries beyond the
key buffer. Bit-identical to the torch reference (same float32 operations, FMA where torch
uses FMA)."""
from __future__ import annotations


import numpy as np
from numba import njit, prange

from fgcli.kernels._common import F32, I64_MAX, INF, INLINE, KERNEL, bits, clampf, sdepth, smv
from fgcli.kernels._intrin import atomic_min_i64, fma


@njit(**KERNEL)
def dilate_kernel(depth, mv, r, dout, mvout):
    """depth (H, W), mv (2, H, W) -> dout (H, W), mvout (2, H, W)."""
    h, w = depth.shape
    for py in prange(h):
        y = np.int64(py)  # prange indices are unsigned: keep index arithmetic signed
        for x in range(w):
            dc = sdepth(depth[y, x])
            best = dc
            by, bx = y, x
            found = False  # a strictly nearer pixel than the centre
            for yy in range(max(0, y - r), min(h, y + r + 1)):
                for xx in range(max(0, x - r), min(w, x + r + 1)):
                    d = sdepth(depth[yy, xx])
                    # lexicographic (depth, flat index) minimum: the first strictly nearer
                    # in row-major order; the centre keeps ties
                    if d < best:
                        best = d
                        by, bx = yy, xx
                        found = True
            if not found:
                by, bx = y, x
            dout[y, x] = best
            mvout[0, y, x] = smv(mv[0, by, bx])
            mvout[1, y, x] = smv(mv[1, by, bx])


@njit(**INLINE)
def _disp(x, y, h, w, depth1, mv1, mv0, depth0, ca, cb, quad, use_d0, tol):
    """Displacement p_t - p1 of source pixel (x, y) and its sanitised vector a."""
    ax = smv(mv1[0, y, x])
    ay = smv(mv1[1, y, x])
    if quad:
        fx = F32(x)
        fy = F32(y)
        # inside_mask(a) and nearest_index(a)
        use = (ax >= F32(-0.5) - fx) and (ax < F32(w - 0.5) - fx) and \
              (ay >= F32(-0.5) - fy) and (ay < F32(h - 0.5) - fy)
        ix = int(clampf(np.floor(ax + (fx + F32(0.5))), F32(0.0), F32(w - 1)))
        iy = int(clampf(np.floor(ay + (fy + F32(0.5))), F32(0.0), F32(h - 1)))
        bx = smv(mv0[0, iy, ix])
        by = smv(mv0[1, iy, ix])
        if use_d0:
            d0s = sdepth(depth0[iy, ix])
            d1s = sdepth(depth1[y, x])
            same = d0s == d1s or abs(d0s - d1s) <= min(d0s, d1s) * tol
            use = use and same
        if not use:
            bx = ax
            by = ay
        return fma(ax, ca, bx * cb), fma(ay, ca, by * cb), ax, ay
    return ax * ca, ay * ca, ax, ay


@njit(**KERNEL)
def splat_kernel(depth1, mv1, mv0, depth0, ca, cb, quad, use_d0, tol, buf,
                 to1, to0, dout, valid, source):
    """Scatter (atomic min of packed keys into buf, (H+2)*(W+2) with an off-screen ring),
    then resolve every target pixel."""
    h, w = depth1.shape
    w2 = w + 2
    nb = buf.shape[0]
    for i in prange(nb):
        buf[i] = I64_MAX
    for py in prange(h):
        y = np.int64(py)  # prange indices are unsigned: keep index arithmetic signed
        for x in range(w):
            dx, dy, _, _ = _disp(x, y, h, w, depth1, mv1, mv0, depth0, ca, cb, quad, use_d0, tol)
            qx = clampf(np.floor(dx + (F32(x) + F32(0.5))), F32(-1.0), F32(w)) + F32(1.0)
            qy = clampf(np.floor(dy + (F32(y) + F32(0.5))), F32(-1.0), F32(h)) + F32(1.0)
            q = int(qy) * w2 + int(qx)
            key = (np.int64(bits(sdepth(depth1[y, x]))) << 32) | np.int64(y * w + x)
            atomic_min_i64(buf, q, key)
    for py in prange(h):
        y = np.int64(py)  # prange indices are unsigned: keep index arithmetic signed
        for x in range(w):
            k = buf[(y + 1) * w2 + x + 1]
            if k == I64_MAX:
                source[y, x] = -1
                valid[y, x] = False
                dout[y, x] = INF
                to1[0, y, x] = F32(0.0)
                to1[1, y, x] = F32(0.0)
                to0[0, y, x] = F32(0.0)
                to0[1, y, x] = F32(0.0)
            else:
                s = np.int32(k & 0xFFFFFFFF)
                sy = s // w
                sx = s - sy * w
                dx, dy, ax, ay = _disp(sx, sy, h, w, depth1, mv1, mv0, depth0, ca, cb, quad,
                                       use_d0, tol)
                source[y, x] = s
                valid[y, x] = True
                dout[y, x] = sdepth(depth1[sy, sx])
                to1[0, y, x] = -dx
                to1[1, y, x] = -dy
                to0[0, y, x] = ax - dx
                to0[1, y, x] = ay - dy
