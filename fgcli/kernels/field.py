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
from numba import njit

from fgcli.kernels._common import F32, INLINE, clamp_b

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
def field_scatter_kernel(pos, kx, ky, dist, d, h, w, thr, steps, buf, sec):
    """vector_field's scatter. pos (2, N) float32 footprint positions; kx, ky (N,) int64
    primary entries; dist (N,) float32 secondary walk lengths; d (2, N) float32 unit
    steps; steps: secondary steps (0: none); buf, sec (2, (h+2)*(w+2)) int64 zeroed ->
    buf = max(primary, secondary) entries (the caller crops the ring)."""
    n = pos.shape[1]
    w2 = w + 2
    for i in range(n):
        xa, xb, ya, yb, t00, t10, t01, t11 = _taps(pos[0, i], pos[1, i], h, w, thr)
        a = kx[i]
        b = ky[i]
        for q, t in ((ya * w2 + xa, t00), (ya * w2 + xb, t10), (yb * w2 + xa, t01),
                     (yb * w2 + xb, t11)):
            if t:
                if a > buf[0, q]:
                    buf[0, q] = a
                if b > buf[1, q]:
                    buf[1, q] = b
    if steps < 1:
        return
    # secondary entries walk back from the footprint, counting primary texels hit
    for i in range(n):
        di = dist[i]
        if not di >= F32(1.0):
            continue
        a = kx[i] - _PRIMARY
        b = ky[i] - _PRIMARY
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
            if buf[0, q] >= _PRIMARY:
                hits += 1
            if hits > 3:
                continue
            if a > sec[0, q]:
                sec[0, q] = a
            if b > sec[1, q]:
                sec[1, q] = b
    for c in range(2):
        for q in range(buf.shape[1]):
            if sec[c, q] > buf[c, q]:
                buf[c, q] = sec[c, q]


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
