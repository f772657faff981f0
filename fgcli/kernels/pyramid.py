"""The mip chain of fgcli.ops.pyramid: one 2x2 box-average level (torch's avg_pool2d with
ceil_mode, whose CPU kernel is not vectorised for this case: 45 ms for a 4-channel 1080p
level against 8 ms here), and pyramid_inpaint's dense part."""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from fgcli.kernels._common import F32, INF, INLINE, KERNEL, sval_b
from fgcli.kernels._intrin import fma
from fgcli.kernels.warp import _grid_coords

U0 = np.uint8(0)
U1 = np.uint8(1)


@njit(**KERNEL)
def pool2_kernel(src, dst):
    """dst = avg_pool2d(src, 2, ceil_mode=True) for (C, H, W) float32: each output the sum
    of the existing children in row-major order, from 0 (as torch's loop), divided by
    their count (so the last row / column of an odd size averages what exists)."""
    c, h, w = src.shape
    h2 = dst.shape[1]
    w2 = dst.shape[2]
    wf = w // 2
    for q in prange(c * h2):
        k = q // h2
        oy = q - k * h2
        y0 = 2 * oy
        if y0 + 1 < h:
            for ox in range(wf):
                s = F32(0.0) + src[k, y0, 2 * ox]
                s += src[k, y0, 2 * ox + 1]
                s += src[k, y0 + 1, 2 * ox]
                s += src[k, y0 + 1, 2 * ox + 1]
                dst[k, oy, ox] = s / F32(4.0)
            if wf < w2:
                s = F32(0.0) + src[k, y0, w - 1]
                s += src[k, y0 + 1, w - 1]
                dst[k, oy, wf] = s / F32(2.0)
        else:
            for ox in range(wf):
                s = F32(0.0) + src[k, y0, 2 * ox]
                s += src[k, y0, 2 * ox + 1]
                dst[k, oy, ox] = s / F32(2.0)
            if wf < w2:
                dst[k, oy, wf] = (F32(0.0) + src[k, y0, w - 1]) / F32(1.0)


@njit(**INLINE)
def _pool_rows(pr, nr, w, lev1, k, q):
    """lev1[k, q, :] = pool2_kernel of the level-0 rows pr[0:nr] (nr = 2, or 1 at an odd
    height's last row): the same sums in the same order."""
    w2 = lev1.shape[2]
    wf = w // 2
    if nr == 2:
        for ox in range(wf):
            s = F32(0.0) + pr[0, 2 * ox]
            s += pr[0, 2 * ox + 1]
            s += pr[1, 2 * ox]
            s += pr[1, 2 * ox + 1]
            lev1[k, q, ox] = s / F32(4.0)
        if wf < w2:
            s = F32(0.0) + pr[0, w - 1]
            s += pr[1, w - 1]
            lev1[k, q, wf] = s / F32(2.0)
    else:
        for ox in range(wf):
            s = F32(0.0) + pr[0, 2 * ox]
            s += pr[0, 2 * ox + 1]
            lev1[k, q, ox] = s / F32(2.0)
        if wf < w2:
            lev1[k, q, wf] = (F32(0.0) + pr[0, w - 1]) / F32(1.0)


@njit(**KERNEL)
def inpaint_prep_kernel(values, weight, unit, holes, given, out, hout, lev1, nh, copy):
    """fgcli.ops.pyramid.pyramid_inpaint's dense part in one pass, level 0 never stored:
    out (C, H, W) = sanitize_values(values); the weight cleaned (NaN, +-inf and negatives
    -> 0); hout (H, W) uint8 = holes (given) or cleaned weight <= 0; lev1 (C + 1, h2, w2)
    = pool2_kernel of level 0 = [v * w, w] with w the cleaned weight, 0 at holes (the
    same sums in the same order); nh (h2,) the holes of each pair of rows. unit: a weight
    of 1 everywhere (weight is then read, not used; given holes make it the reference's
    (~holes).float()). copy False: out is values itself (in place), and only a row with a
    value sanitising changes is written; hout may then be the given holes themselves (it
    is written only where they are not given)."""
    c, h, w = values.shape
    h2 = lev1.shape[1]
    for pq in prange(h2):
        q = np.int64(pq)
        y0 = 2 * q
        nr = 2 if y0 + 1 < h else 1
        wr = np.empty((2, w), dtype=np.float32)  # level 0's weight rows
        pr = np.empty((2, w), dtype=np.float32)  # level 0's product rows, one channel
        n = 0
        for r in range(nr):
            y = y0 + r
            for x in range(w):
                v = F32(1.0) if unit else weight[y, x]
                v = F32(0.0) if (v != v) | (v == INF) | (v < F32(0.0)) else v
                hl = (holes[y, x] != U0) if given else (v <= F32(0.0))
                if copy or not given:
                    hout[y, x] = U1 if hl else U0
                wr[r, x] = F32(0.0) if hl else v
                n += np.int64(hl)
        nh[q] = n
        for k in range(c + 1):
            for r in range(nr):
                y = y0 + r
                if k < c and copy:
                    for x in range(w):
                        sv = sval_b(values[k, y, x])
                        out[k, y, x] = sv
                        pr[r, x] = sv * wr[r, x]
                elif k < c:
                    changed = 0
                    for x in range(w):
                        v = values[k, y, x]
                        sv = sval_b(v)
                        changed += np.int64(sv != v)
                        pr[r, x] = sv * wr[r, x]
                    if changed:
                        for x in range(w):
                            out[k, y, x] = sval_b(values[k, y, x])
                else:
                    for x in range(w):
                        pr[r, x] = wr[r, x]
            _pool_rows(pr, nr, w, lev1, k, q)


@njit(**KERNEL)
def hole_index_kernel(hout, start, idx):
    """The flat indices of the holes (hout (H, W) uint8) in increasing order (torch's
    nonzero): each pair of rows q writes its own from start[q] (the prefix sums of
    inpaint_prep_kernel's counts)."""
    h, w = hout.shape
    for pq in prange(start.shape[0] - 1):
        q = np.int64(pq)
        k = start[q]
        for y in range(2 * q, min(2 * q + 2, h)):
            for x in range(w):
                if hout[y, x] != U0:
                    idx[k] = y * w + x
                    k += 1


@njit(**KERNEL)
def level_sample_kernel(level, s, xs, ys, out):
    """fgcli.ops.pyramid._sample_level: level (C, h, w) read bilinearly (grid_sample,
    border, align_corners=False: fgcli.kernels.warp's arithmetic) at the full-resolution
    pixels (xs, ys) (N,) scaled by s = 2**i, the grid point worked out as the reference's
    float32 ops ((x + 0.5) / s / w * 2 - 1); out (C, N)."""
    c, hl, wl = level.shape
    hw = F32(wl * 0.5)
    hh = F32(hl * 0.5)
    wm1 = F32(wl - 1)
    hm1 = F32(hl - 1)
    fw = F32(wl)
    fh = F32(hl)
    flat = level.reshape((c, hl * wl))
    n = xs.shape[0]
    nch = (n + 4095) // 4096
    for pc in prange(nch):
        j0 = np.int64(pc) * 4096
        m = min(4096, n - j0)
        xr = xs[j0:j0 + m]
        yr = ys[j0:j0 + m]
        i00 = np.empty(m, dtype=np.int64)  # flat taps and weights, then one gather loop
        i01 = np.empty(m, dtype=np.int64)  # per channel (a channel loop of runtime
        i10 = np.empty(m, dtype=np.int64)  # length inside the point loop stays scalar)
        i11 = np.empty(m, dtype=np.int64)
        wnw = np.empty(m, dtype=np.float32)
        wne = np.empty(m, dtype=np.float32)
        wsw = np.empty(m, dtype=np.float32)
        wse = np.empty(m, dtype=np.float32)
        for j in range(m):
            gx = (((xr[j] + F32(0.5)) / s) / fw) * F32(2.0) - F32(1.0)
            gy = (((yr[j] + F32(0.5)) / s) / fh) * F32(2.0) - F32(1.0)
            y0, x0, y1, x1, nw, ne, sw, se = _grid_coords(gx, gy, hw, hh, wm1, hm1, wl, hl)
            i00[j] = y0 * wl + x0
            i01[j] = y0 * wl + x1
            i10[j] = y1 * wl + x0
            i11[j] = y1 * wl + x1
            wnw[j] = nw
            wne[j] = ne
            wsw[j] = sw
            wse[j] = se
        for k in range(c):
            lf = flat[k]
            o = out[k, j0:j0 + m]
            for j in range(m):
                o[j] = fma(sval_b(lf[i11[j]]), wse[j],
                           fma(sval_b(lf[i10[j]]), wsw[j],
                               fma(sval_b(lf[i01[j]]), wne[j], sval_b(lf[i00[j]]) * wnw[j])))
