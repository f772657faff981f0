"""Mob-FGSR gap fill (splat-crack refinement, 'nearest' candidate) and the extrapolation
hole rule (fgcli.ops.fill) as one-pass numba kernels reading only pre-fill values, like
the reference. Bit-identical to the torch reference."""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from fgcli.kernels._common import F32, INF, INLINE, KERNEL, clampf, sdepth, smv

# 3x3 neighbours, row-major, centre excluded (fgcli.ops.fill._NEIGH)
NDY = np.array([-1, -1, -1, 0, 0, 1, 1, 1], dtype=np.int64)
NDX = np.array([-1, 0, 1, -1, 1, -1, 0, 1], dtype=np.int64)


@njit(**INLINE)
def _d(depth, valid, y, x):
    """Gap-fill depth: sanitised, +inf at holes."""
    if not valid[y, x]:
        return INF
    return sdepth(depth[y, x])


@njit(**KERNEL)
def gap_fill_kernel(to1, to0, depth, valid, source, f1, fb, fbd, has_fb, has_fbd, c1, c0,
                    o_to1, o_to0, o_depth, o_valid, o_source, o_filled, o_holes):
    """to1/to0 (2, H, W), depth (H, W), valid (H, W) bool, source (H, W) int32; f1 = the
    float32 factor (1 - threshold); fb (2, H, W) / fbd (H, W) fallback fields (used when
    has_fb / has_fbd); c1, c0 the fallback coefficients. Writes the o_* arrays."""
    h, w = depth.shape
    for py in prange(h):
        y = np.int64(py)  # prange indices are unsigned: keep index arithmetic signed
        cand = np.zeros(8, dtype=np.bool_)
        dn = np.empty(8, dtype=np.float32)
        for x in range(w):
            dc = _d(depth, valid, y, x)
            hc = not valid[y, x]
            limit = dc * f1
            # 3x3 minimum (out-of-image ignored) below the margin, or a hole: suspicious
            susp = hc
            if not susp:
                m = dc
                for yy in range(max(0, y - 1), min(h, y + 2)):
                    for xx in range(max(0, x - 1), min(w, x + 2)):
                        v = _d(depth, valid, yy, xx)
                        if v < m:
                            m = v
                susp = m < limit
            sy, sx = y, x
            fill = False
            if susp:
                for k in range(8):
                    ny = y + NDY[k]
                    nx = x + NDX[k]
                    if 0 <= ny < h and 0 <= nx < w:
                        dn[k] = _d(depth, valid, ny, nx)
                        cand[k] = valid[ny, nx] and (dn[k] < limit or hc)
                    else:
                        dn[k] = INF
                        cand[k] = False
                keep = ((not cand[0]) and (not cand[1]) and (not cand[3])) or \
                       ((not cand[1]) and (not cand[2]) and (not cand[4])) or \
                       ((not cand[3]) and (not cand[5]) and (not cand[6])) or \
                       ((not cand[4]) and (not cand[6]) and (not cand[7]))
                if not keep:
                    best = -1
                    for k in range(8):
                        if cand[k] and (best < 0 or dn[k] < dn[best]):
                            best = k
                    sy = y + NDY[best]
                    sx = x + NDX[best]
                    fill = True
            o_to1[0, y, x] = to1[0, sy, sx]
            o_to1[1, y, x] = to1[1, sy, sx]
            o_to0[0, y, x] = to0[0, sy, sx]
            o_to0[1, y, x] = to0[1, sy, sx]
            o_depth[y, x] = _d(depth, valid, sy, sx)
            o_source[y, x] = source[sy, sx]
            o_filled[y, x] = fill
            v = valid[y, x] or fill
            o_valid[y, x] = v
            o_holes[y, x] = not v
            if not v and has_fb:
                mx = smv(fb[0, y, x])
                my = smv(fb[1, y, x])
                o_to1[0, y, x] = mx * c1
                o_to1[1, y, x] = my * c1
                o_to0[0, y, x] = mx * c0
                o_to0[1, y, x] = my * c0
                if has_fbd:
                    o_depth[y, x] = sdepth(fbd[y, x])


@njit(**KERNEL)
def extrap_fill_kernel(mv1, depth1, to1, to0, valid, depth_t, alpha, f1,
                       o_to1, o_to0, o_depth, o_holes):
    """fill_extrap_holes: holes (valid False) take alpha * mv1(q) when frame 1's depth at
    the pixel nearest q + alpha * mv1(q) is background (else zero motion), and
    to0 = to1 + mv1(nearest q + to1)."""
    h, w = depth1.shape
    for py in prange(h):
        y = np.int64(py)  # prange indices are unsigned: keep index arithmetic signed
        for x in range(w):
            if valid[y, x]:
                o_to1[0, y, x] = to1[0, y, x]
                o_to1[1, y, x] = to1[1, y, x]
                o_to0[0, y, x] = to0[0, y, x]
                o_to0[1, y, x] = to0[1, y, x]
                o_depth[y, x] = sdepth(depth_t[y, x])
                o_holes[y, x] = False
                continue
            mx = smv(mv1[0, y, x]) * alpha
            my = smv(mv1[1, y, x]) * alpha
            sx = F32(x) + mx
            sy = F32(y) + my
            inside = (sx >= F32(-0.5)) and (sx < F32(w - 0.5)) and (sy >= F32(-0.5)) and \
                     (sy < F32(h - 0.5))
            ix = int(clampf(np.floor(sx + F32(0.5)), F32(0.0), F32(w - 1)))
            iy = int(clampf(np.floor(sy + F32(0.5)), F32(0.0), F32(h - 1)))
            ds = sdepth(depth1[iy, ix])
            do = sdepth(depth1[y, x])
            bg = inside and not (ds < do * f1)
            if bg:
                vx, vy, dd = mx, my, ds
            else:
                vx, vy, dd = F32(0.0), F32(0.0), do
            o_to1[0, y, x] = vx
            o_to1[1, y, x] = vy
            o_depth[y, x] = dd
            o_holes[y, x] = True
            jx = int(clampf(np.floor((F32(x) + vx) + F32(0.5)), F32(0.0), F32(w - 1)))
            jy = int(clampf(np.floor((F32(y) + vy) + F32(0.5)), F32(0.0), F32(h - 1)))
            o_to0[0, y, x] = vx + smv(mv1[0, jy, jx])
            o_to0[1, y, x] = vy + smv(mv1[1, jy, jx])
