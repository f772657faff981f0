"""Backward warping (fgcli.ops.warp): bilinear colour (torch grid_sample's arithmetic,
align_corners=False, border clamp) and nearest depth fetches, fused per stage: the
mob-fgsr warp of both frames in one pass, the mv-warp baseline in one pass.

Speed: the per-pixel body is written without branches (every choice a select: the
sanitising rules, the border taps, the zero-flow exact case), so LLVM vectorises the row
loop with AVX2/AVX-512 gathers; a branch in the body (even a never-taken one) halved the
speed at 1080p. With AVX-512 the mob-fgsr warp fetches its taps 16 pixels at a time from
windows of source rows instead (fgcli.kernels._intrin.bilinear16x3; no gathers where the
flow is smooth): per row, one vectorised pass works out the taps and weights into row
buffers, then one intrinsic call per 16 pixels reads, weights and stores them."""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from fgcli.kernels._common import (F32, INF, INLINE, KERNEL, ROWS, clamp_b, sflow_b, smv_b,
                                   sval_b)
from fgcli.kernels._intrin import (HAVE_WINDOW16, bilinear16x3, fma, ld32, ld_pair, mad32,
                                   nearest16)

I32 = np.int32


@njit(**INLINE)
def _unnormalise(gx, gy, hw, hh, wm1, hm1):
    """grid_sample(bilinear, border, align_corners=False)'s source position of the
    normalised grid point (gx, gy): ((g + 1) * size / 2 - 0.5, one FMA as ATen's vectorised
    kernel is compiled, clipped to the border), as (x0f, y0f, tx, ty, 1 - tx, 1 - ty): the
    floors and the fractions."""
    ix = clamp_b(fma(gx + F32(1.0), hw, F32(-0.5)), F32(0.0), wm1)
    iy = clamp_b(fma(gy + F32(1.0), hh, F32(-0.5)), F32(0.0), hm1)
    x0f = np.floor(ix)
    y0f = np.floor(iy)
    tx = ix - x0f
    ty = iy - y0f
    return x0f, y0f, tx, ty, F32(1.0) - tx, F32(1.0) - ty


@njit(**INLINE)
def _grid_coords(gx, gy, hw, hh, wm1, hm1, w, h):
    """Bilinear taps and weights at the normalised grid point (gx, gy): (y0, x0, y1, x1,
    nw, ne, sw, se), int64 indices (pyramid levels of any size)."""
    x0f, y0f, tx, ty, e, s = _unnormalise(gx, gy, hw, hh, wm1, hm1)
    x0 = np.int64(x0f)
    y0 = np.int64(y0f)
    xin = x0 + 1 < w
    yin = y0 + 1 < h
    x1 = x0 + 1 if xin else x0
    y1 = y0 + 1 if yin else y0
    nw = s * e
    ne = s * tx if xin else F32(0.0)
    sw = ty * e if yin else F32(0.0)
    se = ty * tx if (xin & yin) else F32(0.0)
    return y0, x0, y1, x1, nw, ne, sw, se


@njit(**INLINE)
def _flat_coords(fx, fy, gxn_x, gyy, kx, ky, hw, hh, wm1, hm1, w, h):
    """Bilinear taps and weights of grid_sample(bilinear, border, align_corners=False) on
    the normalised grid ``gxn + f * 2 / w``, for the 32-bit pair loads (w, h int32; the
    caller checks 2 <= w and planes * h * w < 2**31): (p, rs, xi, nw, ne, sw, se), where
    the taps (x0, x1) of row y0 are elements p, p + 1 of a plane (p = y0 * w + x0, or one
    left when x0 is the last column: x1 = x0 there and its weight is 0), row y1's are
    p + rs, xi = 1 when x1 = x0 + 1. The same weights as _grid_coords."""
    x0f, y0f, tx, ty, e, s = _unnormalise(fma(fx, kx, gxn_x), fma(fy, ky, gyy), hw, hh, wm1,
                                          hm1)
    x0 = I32(x0f)
    y0 = I32(y0f)
    xin = x0f < wm1  # x0 + 1 < w (as in bil_taps: no 64-bit compares)
    yin = y0f < hm1
    nw = s * e
    ne = s * tx if xin else F32(0.0)
    sw = ty * e if yin else F32(0.0)
    se = ty * tx if (xin & yin) else F32(0.0)
    # (xi is an int: a bool in the returned tuple counts as a possible array alias in
    # numba's parfor analysis, which then drops noalias and the loop is not vectorised)
    return (mad32(y0, w, x0 - (I32(0) if xin else I32(1))), w if yin else I32(0),
            I32(1) if xin else I32(0), nw, ne, sw, se)


@njit(**INLINE)
def _bil_pair(img, p, rs, xi, nw, ne, sw, se):
    """One channel's bilinear sample from two pair loads at flat index p (the channel's
    plane offset included) and p + rs (x1 = x0 at the last column reads x0 twice): the
    sanitised taps' nw + ne + sw + se, contracted to an FMA chain as in ATen's build."""
    a, b = ld_pair(img, p)
    vnw = sval_b(a if xi != 0 else b)
    vne = sval_b(b)
    a, b = ld_pair(img, mad32(rs, I32(1), p))
    vsw = sval_b(a if xi != 0 else b)
    vse = sval_b(b)
    return fma(vse, se, fma(vsw, sw, fma(vne, ne, vnw * nw)))


@njit(**INLINE)
def _nearest_depth32(depth, fx, fy, xf, yf, wm1, hm1, w):
    """sample_nearest of a C-contiguous (H, W) depth at the sanitised flow (32-bit index,
    w int32); NaN -> +inf."""
    jx = clamp_b(np.floor(fx + (xf + F32(0.5))), F32(0.0), wm1)
    jy = clamp_b(np.floor(fy + (yf + F32(0.5))), F32(0.0), hm1)
    v = ld32(depth, mad32(I32(jy), w, I32(jx)))
    return INF if v != v else v


def flat_ok(h: int, w: int, planes: int) -> bool:
    """Whether the pair-load kernels apply: 2 <= w and every flat index fits int32."""
    return w >= 2 and planes * h * w < 2 ** 31


# Loops live in the kernels themselves and have constant trip counts inside the row loop:
# a row loop inside an inlined helper, or a channel loop of runtime length, is not
# vectorised (each measured 2-7x slower at 1080p). Colour is 3 channels here; other
# channel counts run the torch reference (fgcli.kernels.ops).


@njit(**INLINE)
def _warp_px(c, d, to, s, sd, v, x, y, oy, xf, yf, lo_y, hi_y, gxn_x, gyy, kx, ky, hw, hh,
             wm1, hm1, w, h, hw32):
    """One frame at pixel (x, y): colour (bilinear, 3 channels) and depth (nearest) along
    ``to``, written to row ``oy`` of s, sd, v (y itself, or 0 of a row buffer); valid =
    inside_mask on the raw offset (NaN -> False); zero flow returns the sanitised pixel
    exactly. w, h, hw32 (= h * w) int32: the taps are 32-bit pair loads."""
    rx = to[0, y, x]
    ry = to[1, y, x]
    v[oy, x] = (rx >= F32(-0.5) - xf) & (rx < F32(w - 0.5) - xf) & (ry >= lo_y) & (ry < hi_y)
    fx = sflow_b(rx)
    fy = sflow_b(ry)
    zero = (fx == F32(0.0)) & (fy == F32(0.0))
    p, rs, xi, nw, ne, sw, se = _flat_coords(fx, fy, gxn_x, gyy, kx, ky, hw, hh, wm1, hm1,
                                             w, h)
    for k in range(3):
        r = _bil_pair(c, mad32(I32(k), hw32, p), rs, xi, nw, ne, sw, se)
        s[k, oy, x] = sval_b(c[k, y, x]) if zero else r
    sd[oy, x] = _nearest_depth32(d, fx, fy, xf, yf, wm1, hm1, w)


@njit(**KERNEL)
def warp_pixels_kernel(c1, d1, to1, c0, d0, to0, two, gxn, gyn, kx, ky, s1, sd1, v1, s0, sd0,
                       v0):
    """Mob-FGSR warp stage (3-channel colour): colour (bilinear) and depth (nearest) of
    frame 1 along to1 and, when ``two``, of frame 0 along to0, row by row. C-contiguous
    colour and depth, flat_ok(h, w, 3). (warp_kernel: this one, or warp_window_kernel
    where the CPU has AVX-512.)"""
    h, w = d1.shape
    hw = F32(w * 0.5)
    hh = F32(h * 0.5)
    wm1 = F32(w - 1)
    hm1 = F32(h - 1)
    w32 = I32(w)
    h32 = I32(h)
    hw32 = I32(h * w)
    for py in prange(h):
        y = np.int64(py)  # prange indices are unsigned: keep index arithmetic signed
        yf = F32(y)
        gyy = gyn[y]
        lo_y = F32(-0.5) - yf
        hi_y = F32(h - 0.5) - yf
        for x in range(w):
            _warp_px(c1, d1, to1, s1, sd1, v1, x, y, y, F32(I32(x)), yf, lo_y, hi_y, gxn[x], gyy,
                     kx, ky, hw, hh, wm1, hm1, w32, h32, hw32)
        if two:
            for x in range(w):
                _warp_px(c0, d0, to0, s0, sd0, v0, x, y, y, F32(I32(x)), yf, lo_y, hi_y, gxn[x],
                         gyy, kx, ky, hw, hh, wm1, hm1, w32, h32, hw32)


@njit(**INLINE)
def bil_taps(fx, fy, x, gxn_x, gyy, kx, ky, hw, hh, wm1, hm1, w, h, XA, XB, YA, YB, WT, Z):
    """_flat_coords for the 16-lane fetches (fgcli.kernels._intrin.bilinear16x3): the taps
    of pixel x along the sanitised flow (fx, fy) into row buffers: columns XA, XB and rows
    YA, YB (x1 = x0 and y1 = y0 at the last column / row, where their weight is 0: the
    values the pair loads read), the weights WT (4, W) and the zero-flow flag Z. (Flags as
    int32: a bool variable here would cost the loop its vectorisation; see
    fgcli.kernels.blend.)"""
    Z[x] = I32(1) if (fx == F32(0.0)) & (fy == F32(0.0)) else I32(0)
    x0f, y0f, tx, ty, e, s = _unnormalise(fma(fx, kx, gxn_x), fma(fy, ky, gyy), hw, hh, wm1,
                                          hm1)
    x0 = I32(x0f)
    y0 = I32(y0f)
    # x0 + 1 < w, compared as floats (exact: integers below 2**24): in numba's integer
    # arithmetic it is an int64 sum, and the 64-bit compares cost the AVX2 loop 10-15 %
    xi = I32(1) if x0f < wm1 else I32(0)
    yi = I32(1) if y0f < hm1 else I32(0)
    XA[x] = x0
    XB[x] = x0 + xi
    YA[x] = y0
    YB[x] = y0 + yi
    WT[0, x] = s * e
    WT[1, x] = s * tx if xi != 0 else F32(0.0)
    WT[2, x] = ty * e if yi != 0 else F32(0.0)
    WT[3, x] = ty * tx if (xi & yi) != 0 else F32(0.0)


@njit(**INLINE)
def _taps_px(to, v, oy, x, y, xf, lo_y, hi_y, gxn_x, gyy, kx, ky, hw, hh, wm1, hm1, w, h, XA,
             XB, YA, YB, WT, Z, JX, JY):
    """_warp_px's coordinates at pixel x into row buffers: the valid flag (into row oy of
    v), the bilinear taps (bil_taps) and the nearest depth's pixel JX, JY."""
    rx = to[0, y, x]
    ry = to[1, y, x]
    v[oy, x] = (rx >= F32(-0.5) - xf) & (rx < F32(w - 0.5) - xf) & (ry >= lo_y) & (ry < hi_y)
    fx = sflow_b(rx)
    fy = sflow_b(ry)
    bil_taps(fx, fy, x, gxn_x, gyy, kx, ky, hw, hh, wm1, hm1, w, h, XA, XB, YA, YB, WT, Z)
    JX[x] = I32(clamp_b(np.floor(fx + (xf + F32(0.5))), F32(0.0), wm1))
    JY[x] = I32(clamp_b(np.floor(fy + (F32(y) + F32(0.5))), F32(0.0), hm1))


@njit(**ROWS)
def _warp_window_rows(ya, yb, c1, d1, to1, c0, d0, to0, two, gxn, gyn, kx, ky, s1, sd1, v1, s0,
                      sd0, v0, XA, XB, YA, YB, JX, JY, Z, WT):
    """warp_window_kernel's rows ya..yb (one chunk of its parallel loop)."""
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
        ro = I32(y * w)
        for x in range(w):
            _taps_px(to1, v1, y, x, y, F32(I32(x)), lo_y, hi_y, gxn[x], gyy, kx, ky, hw, hh, wm1,
                     hm1, w32, h32, XA, XB, YA, YB, WT, Z, JX, JY)
        for b in range(nb):
            bilinear16x3(c1, hw32, w32, h32, XA, XB, YA, YB, WT, Z, I32(16 * b), ro, s1, hw32,
                         ro)
            nearest16(d1, w32, h32, JX, JY, I32(16 * b), sd1, ro)
        for x in range(16 * nb, w):
            _warp_px(c1, d1, to1, s1, sd1, v1, x, y, y, F32(I32(x)), yf, lo_y, hi_y, gxn[x], gyy,
                     kx, ky, hw, hh, wm1, hm1, w32, h32, hw32)
        if two:
            for x in range(w):
                _taps_px(to0, v0, y, x, y, F32(I32(x)), lo_y, hi_y, gxn[x], gyy, kx, ky, hw, hh,
                         wm1, hm1, w32, h32, XA, XB, YA, YB, WT, Z, JX, JY)
            for b in range(nb):
                bilinear16x3(c0, hw32, w32, h32, XA, XB, YA, YB, WT, Z, I32(16 * b), ro, s0,
                             hw32, ro)
                nearest16(d0, w32, h32, JX, JY, I32(16 * b), sd0, ro)
            for x in range(16 * nb, w):
                _warp_px(c0, d0, to0, s0, sd0, v0, x, y, y, F32(I32(x)), yf, lo_y, hi_y, gxn[x],
                         gyy, kx, ky, hw, hh, wm1, hm1, w32, h32, hw32)


@njit(**KERNEL)
def warp_window_kernel(c1, d1, to1, c0, d0, to0, two, gxn, gyn, kx, ky, s1, sd1, v1, s0, sd0,
                       v0):
    """warp_pixels_kernel with the taps fetched 16 pixels at a time
    (fgcli.kernels._intrin.bilinear16x3 and nearest16: AVX-512 or AVX2); the last w % 16
    pixels of a row per pixel. The same values, bit for bit."""
    h, w = d1.shape
    nch = min(h, 64)
    for ch in prange(nch):
        ya = np.int64(ch) * h // nch
        yb = (np.int64(ch) + 1) * h // nch
        # (row buffers; the arrays go to the intrinsics whole: a reshaped view made here
        # would count as an alias and cost every loop its vectorisation)
        XA = np.empty(w, dtype=np.int32)
        XB = np.empty(w, dtype=np.int32)
        YA = np.empty(w, dtype=np.int32)
        YB = np.empty(w, dtype=np.int32)
        JX = np.empty(w, dtype=np.int32)
        JY = np.empty(w, dtype=np.int32)
        Z = np.empty(w, dtype=np.int32)
        WT = np.empty((4, w), dtype=np.float32)
        _warp_window_rows(ya, yb, c1, d1, to1, c0, d0, to0, two, gxn, gyn, kx, ky, s1, sd1, v1,
                          s0, sd0, v0, XA, XB, YA, YB, JX, JY, Z, WT)


# the mob-fgsr warp: 16-lane window fetches where the CPU has AVX-512 or AVX2 (numba's
# cache keys compiled code by CPU, so a cache never carries one machine's choice to another)
warp_kernel = warp_window_kernel if HAVE_WINDOW16 else warp_pixels_kernel


@njit(**KERNEL)
def mv_warp_kernel(img, depth, mv, scale, raw_depth_flow, gxn, gyn, kx, ky, out, dout):
    """mv-warp baseline (3-channel colour): colour warped by sanitize_mv(mv) * scale
    (bilinear), depth fetched at mv * scale (the raw vectors when raw_depth_flow, as the
    reference), nearest. C-contiguous colour and depth, flat_ok(h, w, 3)."""
    h, w = depth.shape
    hw = F32(w * 0.5)
    hh = F32(h * 0.5)
    wm1 = F32(w - 1)
    hm1 = F32(h - 1)
    w32 = I32(w)
    h32 = I32(h)
    hw32 = I32(h * w)
    for py in prange(h):
        y = np.int64(py)  # prange indices are unsigned: keep index arithmetic signed
        yf = F32(y)
        gyy = gyn[y]
        for x in range(w):
            mx = mv[0, y, x]
            my = mv[1, y, x]
            fx = sflow_b(smv_b(mx) * scale)
            fy = sflow_b(smv_b(my) * scale)
            zero = (fx == F32(0.0)) & (fy == F32(0.0))
            p, rs, xi, nw, ne, sw, se = _flat_coords(fx, fy, gxn[x], gyy, kx, ky, hw, hh, wm1,
                                                     hm1, w32, h32)
            for k in range(3):
                r = _bil_pair(img, mad32(I32(k), hw32, p), rs, xi, nw, ne, sw, se)
                out[k, y, x] = sval_b(img[k, y, x]) if zero else r
            rfx = sflow_b(mx * scale)
            rfy = sflow_b(my * scale)
            dx = rfx if raw_depth_flow else fx
            dy = rfy if raw_depth_flow else fy
            dout[y, x] = _nearest_depth32(depth, dx, dy, F32(I32(x)), yf, wm1, hm1, w32)

