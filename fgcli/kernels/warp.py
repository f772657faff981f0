"""Backward warping (fgcli.ops.warp): bilinear colour (torch grid_sample's arithmetic,
align_corners=False, border clamp) and nearest depth fetches, fused per stage: the
mob-fgsr warp of both frames in one pass, the mv-warp baseline in one pass."""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from fgcli.kernels._common import F32, INF, INLINE, KERNEL, clampf, sflow, smv, sval
from fgcli.kernels._intrin import fma


@njit(**INLINE)
def _inside(fx, fy, x, y, h, w):
    """inside_mask on the raw flow (NaN -> False)."""
    return (fx >= F32(-0.5) - F32(x)) and (fx < F32(w - 0.5) - F32(x)) and \
           (fy >= F32(-0.5) - F32(y)) and (fy < F32(h - 0.5) - F32(y))


@njit(**INLINE)
def _bilinear(img, out, x, y, fx, fy, h, w, gxn, gyn, kx, ky):
    """out[:, y, x] = img sampled at (x + fx, y + fy) (fx, fy sanitised flow), as
    F.grid_sample(bilinear, border, align_corners=False) computes it on the normalised
    grid ``gxn + f * 2 / w``; zero flow returns the pixel exactly."""
    c = img.shape[0]
    if fx == F32(0.0) and fy == F32(0.0):
        for k in range(c):
            out[k, y, x] = sval(img[k, y, x])
        return
    gx = fma(fx, kx, gxn[x])
    gy = fma(fy, ky, gyn[y])
    # unnormalise ((g + 1) * size / 2 - 0.5, one FMA as ATen's vectorised kernel is
    # compiled) and clip to the border
    ix = clampf(fma(gx + F32(1.0), F32(w * 0.5), F32(-0.5)), F32(0.0), F32(w - 1))
    iy = clampf(fma(gy + F32(1.0), F32(h * 0.5), F32(-0.5)), F32(0.0), F32(h - 1))
    x0f = np.floor(ix)
    y0f = np.floor(iy)
    tx = ix - x0f
    ty = iy - y0f
    e = F32(1.0) - tx
    s = F32(1.0) - ty
    nw = s * e
    ne = s * tx
    sw = ty * e
    se = ty * tx
    x0 = int(x0f)
    y0 = int(y0f)
    x1ok = x0 + 1 < w
    y1ok = y0 + 1 < h
    for k in range(c):
        vnw = sval(img[k, y0, x0])
        vne = sval(img[k, y0, x0 + 1]) if x1ok else F32(0.0)
        vsw = sval(img[k, y0 + 1, x0]) if y1ok else F32(0.0)
        vse = sval(img[k, y0 + 1, x0 + 1]) if (x1ok and y1ok) else F32(0.0)
        # nw + ne + sw + se, contracted to an FMA chain as in ATen's build
        out[k, y, x] = fma(vse, se, fma(vsw, sw, fma(vne, ne, vnw * nw)))


@njit(**INLINE)
def _nearest_depth(depth, fx, fy, x, y, h, w):
    """sample_nearest of a (H, W) depth at the sanitised flow; NaN -> +inf."""
    ix = int(clampf(np.floor(fx + (F32(x) + F32(0.5))), F32(0.0), F32(w - 1)))
    iy = int(clampf(np.floor(fy + (F32(y) + F32(0.5))), F32(0.0), F32(h - 1)))
    v = depth[iy, ix]
    if v != v:
        return INF
    return v


@njit(**INLINE)
def _warp_pixel(c, d, to, s, sd, v, x, y, h, w, gxn, gyn, kx, ky):
    """One frame at pixel (x, y): colour (bilinear) and depth (nearest) along ``to``, and
    the valid mask on the raw offset."""
    rx = to[0, y, x]
    ry = to[1, y, x]
    v[y, x] = _inside(rx, ry, x, y, h, w)
    fx = sflow(rx)
    fy = sflow(ry)
    _bilinear(c, s, x, y, fx, fy, h, w, gxn, gyn, kx, ky)
    sd[y, x] = _nearest_depth(d, fx, fy, x, y, h, w)


@njit(**KERNEL)
def warp_kernel(c1, d1, to1, c0, d0, to0, two, gxn, gyn, kx, ky, s1, sd1, v1, s0, sd0, v0):
    """Mob-FGSR warp stage: colour (bilinear) and depth (nearest) of frame 1 along to1 and,
    when ``two``, of frame 0 along to0; valid masks on the raw offsets."""
    h, w = d1.shape
    for py in prange(h):
        y = np.int64(py)  # prange indices are unsigned: keep index arithmetic signed
        for x in range(w):
            _warp_pixel(c1, d1, to1, s1, sd1, v1, x, y, h, w, gxn, gyn, kx, ky)
            if two:
                _warp_pixel(c0, d0, to0, s0, sd0, v0, x, y, h, w, gxn, gyn, kx, ky)


@njit(**KERNEL)
def mv_warp_kernel(img, depth, mv, scale, raw_depth_flow, gxn, gyn, kx, ky, out, dout):
    """mv-warp baseline: colour warped by sanitize_mv(mv) * scale (bilinear), depth fetched
    at mv * scale (the raw vectors when raw_depth_flow, as the reference), nearest."""
    h, w = depth.shape
    for py in prange(h):
        y = np.int64(py)  # prange indices are unsigned: keep index arithmetic signed
        for x in range(w):
            mx = mv[0, y, x]
            my = mv[1, y, x]
            fx = sflow(smv(mx) * scale)
            fy = sflow(smv(my) * scale)
            _bilinear(img, out, x, y, fx, fy, h, w, gxn, gyn, kx, ky)
            if raw_depth_flow:
                fx = sflow(mx * scale)
                fy = sflow(my * scale)
            dout[y, x] = _nearest_depth(depth, fx, fy, x, y, h, w)
