"""FSR 3's per-pixel passes (fgcli.ops.fsr3) as numba kernels, each one pass over the
frame with no frame-sized temporaries:

- ``disocclusion_kernel``: both disocclusion masks (``disocclusion_masks``: four bilinear
  depth taps toward each frame, the same-surface test, the agreeing weight against the
  threshold);
- ``interp_game_kernel`` + ``interp_flow_kernel``: the interpolation pass
  (``interpolate_fsr3``, linear space): the game
  and optical-flow sample pairs (grid_sample's bilinear arithmetic, as fgcli.kernels.warp),
  the mask lerp weight, the colour similarities, the bias and the final lerp.

Exactness: every value is the reference's float32 operation sequence (the scalars rounded
to float32 as torch rounds a Python float operand, FMAs where torch's vectorised kernels
use them: grid_sample and lerp), so outputs are bit-identical on FMA builds of torch
(tests/test_kernels.py). One deliberate difference: the reference's tap index is computed
in float32 (``y * w + x``), which is exact below 2**24 pixels; the kernel's is integer (the
reference was fixed to int64 arithmetic at the same time, so both agree at every size)."""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from fgcli.kernels._common import (F32, INF, INLINE, KERNEL, ROWS, clamp_b, dealt, sdepth_b,
                                   sflow_b, smv_b, sval_b)
from fgcli.kernels.blend import _lerp_b
from fgcli.kernels.pyramid import _pool_rows
from fgcli.kernels._intrin import (HAVE_WINDOW16, bilinear16x3, ld_pair, mad32, nearest16,
                                   taps16)
from fgcli.kernels.warp import I32, _bil_pair, _flat_coords, _nearest_depth32, bil_taps

# the colour samples' taps fetched 16 pixels at a time (fgcli.kernels._intrin.bilinear16x3,
# AVX-512; a module constant, so numba compiles only the branch this CPU runs)
WINDOW16 = HAVE_WINDOW16


@njit(**INLINE)
def _tap(z, xi, yi, wt, zt, thr, wm1, hm1):
    """One bilinear tap of _tap_mask with the depth z there (sanitised): its weight when
    on-screen and the same surface as zt (or farther), else 0 (added to the running sum as
    the reference's ``wt * (on & ok)``)."""
    on = (xi >= F32(0.0)) & (xi <= wm1) & (yi >= F32(0.0)) & (yi <= hm1)
    diff = abs(z - zt)
    mn = z if z < zt else zt
    ok = (z == zt) | (mn * thr >= diff) | (z > zt)
    return wt * F32(on & ok)


@njit(**INLINE)
def _row_pair(d, yi, px, x0, w, wm1, hm1):
    """The sanitised depths at the reference's clamped taps (clamp(x0), clamp(x0 + 1)) of
    row clamp(yi), from one pair load at column px = clamp(x0, 0, w - 2): x0 <= 0 gives
    px = 0, x0 >= w - 1 gives px + 1 = w - 1 for the clamped x0 (needs w >= 2)."""
    iy = I32(clamp_b(yi, F32(0.0), hm1))
    a, b = ld_pair(d, mad32(iy, w, px))
    z0 = b if x0 >= wm1 else a
    z1 = a if x0 + F32(1.0) <= F32(0.0) else b
    return sdepth_b(z0), sdepth_b(z1)


@njit(**INLINE)
def _tap_mask(d, x, y, zt, thr, w, h, wm1, hm1):
    """fgcli.ops.fsr3._tap_mask at one position (x, y) (index coordinates); w, h int32,
    d C-contiguous with flat_ok(h, w, 1)."""
    x = clamp_b(x, F32(-2.0), F32(w + 1.0))
    y = clamp_b(y, F32(-2.0), F32(h + 1.0))
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = x - x0
    fy = y - y0
    ex = F32(1.0) - fx
    ey = F32(1.0) - fy
    x1 = x0 + F32(1.0)
    y1 = y0 + F32(1.0)
    px = I32(clamp_b(x0, F32(0.0), wm1 - F32(1.0)))
    z00, z10 = _row_pair(d, y0, px, x0, w, wm1, hm1)
    z01, z11 = _row_pair(d, y1, px, x0, w, wm1, hm1)
    acc = F32(0.0)
    acc += _tap(z00, x0, y0, ex * ey, zt, thr, wm1, hm1)
    acc += _tap(z10, x1, y0, fx * ey, zt, thr, wm1, hm1)
    acc += _tap(z01, x0, y1, ex * fy, zt, thr, wm1, hm1)
    acc += _tap(z11, x1, y1, fx * fy, zt, thr, wm1, hm1)
    return acc


@njit(**INLINE)
def _mask_taps(x, y, i, w, h, wm1, hm1, XA, XB, YA, YB):
    """_tap_mask's taps at position (x, y) (the clamped columns and rows _row_pair reads)
    into the row buffers of fgcli.kernels._intrin.taps16, at i."""
    x0 = np.floor(clamp_b(x, F32(-2.0), F32(w + 1.0)))
    y0 = np.floor(clamp_b(y, F32(-2.0), F32(h + 1.0)))
    XA[i] = I32(clamp_b(x0, F32(0.0), wm1))
    XB[i] = I32(clamp_b(x0 + F32(1.0), F32(0.0), wm1))
    YA[i] = I32(clamp_b(y0, F32(0.0), hm1))
    YB[i] = I32(clamp_b(y0 + F32(1.0), F32(0.0), hm1))


@njit(**INLINE)
def _tail_taps(d, x, XA, XB, YA, YB, T):
    """taps16's four reads for one pixel (a row's last w % 16)."""
    T[0, x] = d[YA[x], XA[x]]
    T[1, x] = d[YA[x], XB[x]]
    T[2, x] = d[YB[x], XA[x]]
    T[3, x] = d[YB[x], XB[x]]


@njit(**INLINE)
def _tap_mask_t(T, i, x, y, zt, thr, w, h, wm1, hm1):
    """_tap_mask with the four depths already fetched into T[:, i] (taps16)."""
    x = clamp_b(x, F32(-2.0), F32(w + 1.0))
    y = clamp_b(y, F32(-2.0), F32(h + 1.0))
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = x - x0
    fy = y - y0
    ex = F32(1.0) - fx
    ey = F32(1.0) - fy
    x1 = x0 + F32(1.0)
    y1 = y0 + F32(1.0)
    acc = F32(0.0)
    acc += _tap(sdepth_b(T[0, i]), x0, y0, ex * ey, zt, thr, wm1, hm1)
    acc += _tap(sdepth_b(T[1, i]), x1, y0, fx * ey, zt, thr, wm1, hm1)
    acc += _tap(sdepth_b(T[2, i]), x0, y1, ex * fy, zt, thr, wm1, hm1)
    acc += _tap(sdepth_b(T[3, i]), x1, y1, fx * fy, zt, thr, wm1, hm1)
    return acc


@njit(**ROWS)
def _disocclusion_rows(ya, yb, depth_t, depth_prev, depth1, vec, a, b, thr, threshold, mp, mc, XA,
                       XB, YA, YB, T):
    """disocclusion_kernel's rows ya..yb (one chunk of its parallel loop). A row of zero
    vectors (_moving_row: +-0; NaN counts as moving) reads each pixel's own depths, no taps
    (where a and b are finite: q + 0 a = q)."""
    h, w = depth_t.shape
    own = (abs(a) < F32(np.inf)) & (abs(b) < F32(np.inf))
    wm1 = F32(w - 1)
    hm1 = F32(h - 1)
    w32 = I32(w)
    h32 = I32(h)
    nblk = w // 16
    for y in range(ya, yb):
        yf = F32(y)
        if own and _moving_row(vec, y, w) == 0:
            # a row of zero vectors: each pixel's taps lie on itself, where the weight is 1
            # and at the other three 0 (0 * a flag adds +0.0), so its sum is its own tap's
            # flag (on screen)
            for x in range(w):
                zt = sdepth_b(depth_t[y, x])
                mp[y, x] = F32(_tap(sdepth_b(depth_prev[y, x]), F32(I32(x)), yf, F32(1.0), zt,
                                    thr, wm1, hm1) >= threshold)
                mc[y, x] = F32(_tap(sdepth_b(depth1[y, x]), F32(I32(x)), yf, F32(1.0), zt,
                                    thr, wm1, hm1) >= threshold)
            continue
        if WINDOW16:  # the taps into row buffers, fetched 16 pixels at a time, then the sums
            for x in range(w):
                _mask_taps(F32(I32(x)) + smv_b(vec[0, y, x]) * a, yf + smv_b(vec[1, y, x]) * a, x,
                           w32, h32, wm1, hm1, XA, XB, YA, YB)
            for blk in range(nblk):
                taps16(depth_prev, w32, h32, XA, XB, YA, YB, I32(16 * blk), T)
            for x in range(16 * nblk, w):
                _tail_taps(depth_prev, x, XA, XB, YA, YB, T)
            for x in range(w):
                vx = smv_b(vec[0, y, x])
                vy = smv_b(vec[1, y, x])
                zt = sdepth_b(depth_t[y, x])
                acc = _tap_mask_t(T, x, F32(I32(x)) + vx * a, yf + vy * a, zt, thr, w32, h32, wm1,
                                  hm1)
                mp[y, x] = F32(acc >= threshold)
            for x in range(w):
                _mask_taps(F32(I32(x)) - smv_b(vec[0, y, x]) * b, yf - smv_b(vec[1, y, x]) * b, x,
                           w32, h32, wm1, hm1, XA, XB, YA, YB)
            for blk in range(nblk):
                taps16(depth1, w32, h32, XA, XB, YA, YB, I32(16 * blk), T)
            for x in range(16 * nblk, w):
                _tail_taps(depth1, x, XA, XB, YA, YB, T)
            for x in range(w):
                vx = smv_b(vec[0, y, x])
                vy = smv_b(vec[1, y, x])
                zt = sdepth_b(depth_t[y, x])
                acc = _tap_mask_t(T, x, F32(I32(x)) - vx * b, yf - vy * b, zt, thr, w32, h32, wm1,
                                  hm1)
                mc[y, x] = F32(acc >= threshold)
        else:
            for x in range(w):
                vx = smv_b(vec[0, y, x])
                vy = smv_b(vec[1, y, x])
                zt = sdepth_b(depth_t[y, x])
                acc = _tap_mask(depth_prev, F32(I32(x)) + vx * a, yf + vy * a, zt, thr, w32, h32,
                                wm1, hm1)
                mp[y, x] = F32(acc >= threshold)
            for x in range(w):
                vx = smv_b(vec[0, y, x])
                vy = smv_b(vec[1, y, x])
                zt = sdepth_b(depth_t[y, x])
                acc = _tap_mask(depth1, F32(I32(x)) - vx * b, yf - vy * b, zt, thr, w32, h32, wm1,
                                hm1)
                mc[y, x] = F32(acc >= threshold)


@njit(**KERNEL)
def disocclusion_kernel(depth_t, depth_prev, depth1, vec, a, b, thr, threshold, mp, mc):
    """Both masks: toward the previous frame the taps of depth_prev at ``q + a v``, toward
    the current frame those of depth1 at ``q - b v`` (a = alpha, b = 1 - alpha as float32);
    1.0 where the agreeing weight reaches ``threshold``, else 0.0. C-contiguous depths,
    flat_ok(h, w, 1)."""
    h, w = depth_t.shape
    nch = min(h, 64)
    for pch in prange(nch):
        ch = dealt(pch, nch)  # (each thread's chunks spread over the frame)
        ya = ch * h // nch
        yb = (ch + 1) * h // nch
        XA = np.empty(w, dtype=np.int32)
        XB = np.empty(w, dtype=np.int32)
        YA = np.empty(w, dtype=np.int32)
        YB = np.empty(w, dtype=np.int32)
        T = np.empty((4, w), dtype=np.float32)
        _disocclusion_rows(ya, yb, depth_t, depth_prev, depth1, vec, a, b, thr, threshold, mp, mc,
                           XA, XB, YA, YB, T)


@njit(**INLINE)
def _inside(rx, ry, xf, lo_y, hi_y, w):
    """inside_mask of the flow (rx, ry) at pixel column xf (w int32)."""
    return (rx >= F32(-0.5) - xf) & (rx < F32(w - 0.5) - xf) & (ry >= lo_y) & (ry < hi_y)


@njit(**INLINE)
def _sample(c, rx, ry, x, y, xf, lo_y, hi_y, gxn_x, gyy, kx, ky, hw, hh, wm1, hm1, w, h,
            hw32, out, ox):
    """backward_warp(c, flow)[:, y, x] (bilinear, border clamp; zero flow exact) into
    out[:, ox]; returns inside_mask of the flow (rx, ry are finite: sanitised vectors times
    a float32 scalar). w, h, hw32 = h * w: int32 (the taps are pair loads,
    fgcli.kernels.warp._bil_pair)."""
    valid = _inside(rx, ry, xf, lo_y, hi_y, w)
    zero = (rx == F32(0.0)) & (ry == F32(0.0))
    p, rs, xi, nw, ne, sw, se = _flat_coords(rx, ry, gxn_x, gyy, kx, ky, hw, hh, wm1, hm1, w, h)
    for k in range(3):
        r = _bil_pair(c, mad32(I32(k), hw32, p), rs, xi, nw, ne, sw, se)
        out[k, ox] = sval_b(c[k, y, x]) if zero else r
    return valid


@njit(**INLINE)
def _max_nan(p, q):
    """torch.maximum: NaN when either is NaN."""
    m = p if p >= q else q
    m = p if p != p else m
    return q if q != q else m


@njit(**INLINE)
def _similarity(pa, pb, ox, eps, eps2):
    """color_similarity of the pixels pa[:, ox], pb[:, ox]."""
    a0, a1, a2 = pa[0, ox], pa[1, ox], pa[2, ox]
    b0, b1, b2 = pb[0, ox], pb[1, ox], pb[2, ox]
    m2 = _max_nan(a0 * a0 + a1 * a1 + a2 * a2, b0 * b0 + b1 * b1 + b2 * b2)
    s = (a0 * b0 + a1 * b1 + a2 * b2) / (eps if m2 < eps else m2)
    return F32(1.0) if m2 <= eps2 else s


@njit(**INLINE)
def _moving_row(v, y, w):
    """1 when a vector of row y of v (2, H, W) is not zero (NaN counts as not zero), else
    0: the row's samples along v are then its pixels themselves (_centres). (The first
    pixel first: a moving row, as a moving camera gives every row, costs no scan.)"""
    if w > 0 and ((v[0, y, 0] != F32(0.0)) | (v[1, y, 0] != F32(0.0))):
        return I32(1)
    m = I32(0)
    for x in range(w):
        m |= I32((v[0, y, x] != F32(0.0)) | (v[1, y, x] != F32(0.0)))
    return m


@njit(**INLINE)
def _centres(c, y, w, out, ins):
    """The samples of row y along zero vectors (what the taps and fetches give there: the
    sanitised pixels, every point on screen): out[k, x] = sval_b(c[k, y, x]), ins[x] = 1
    (ins None: not written)."""
    for k in range(3):
        for x in range(w):
            out[k, x] = sval_b(c[k, y, x])
    if ins is not None:
        for x in range(w):
            ins[x] = F32(1.0)


@njit(**INLINE)
def _samples_along(c, v, s, y, gxn, gyy, kx, ky, hw, hh, wm1, hm1, w32, h32, hw32, lo_y, hi_y,
                   XA, XB, YA, YB, WT, Z, out, ins):
    """Row y of backward_warp(c, s * v) (3-plane colour, sanitised vectors v (2, H, W) times
    the float32 scale s) into the row buffer out (3, W), and its inside_mask into ins
    (None: not made): the taps into bil_taps' row buffers XA .. Z, 16 pixels per window
    fetch, the last w % 16 one by one (_sample); a row of zero vectors takes its pixels
    (_centres: no taps, no fetch)."""
    w = out.shape[1]
    if _moving_row(v, y, w) == 0:
        _centres(c, y, w, out, ins)
        return
    nblk = w // 16
    for x in range(w):
        rx = smv_b(v[0, y, x]) * s
        ry = smv_b(v[1, y, x]) * s
        if ins is not None:
            ins[x] = F32(_inside(rx, ry, F32(I32(x)), lo_y, hi_y, w32))
        bil_taps(rx, ry, x, gxn[x], gyy, kx, ky, hw, hh, wm1, hm1, w32, h32, XA, XB, YA, YB,
                 WT, Z)
    for blk in range(nblk):
        bilinear16x3(c, hw32, w32, h32, XA, XB, YA, YB, WT, Z, I32(16 * blk), I32(y * w), out,
                     w32, I32(0))
    for x in range(16 * nblk, w):
        _sample(c, smv_b(v[0, y, x]) * s, smv_b(v[1, y, x]) * s, x, y, F32(I32(x)), lo_y, hi_y,
                gxn[x], gyy, kx, ky, hw, hh, wm1, hm1, w32, h32, hw32, out, x)


# Row buffers are float32, never bool, and each row loop does one kind of work: a bool row
# buffer, or the optical-flow samples in the same prange body as the game samples, kept
# LLVM from vectorising the gathers (4-10x slower at 1080p). Hence two kernels.


@njit(**ROWS)
def _interp_game_rows(ya, yb, c0, c1, vec, mask_prev, mask_cur, has_of, a, na, nb, gxn, gyn, kx,
                      ky, out, holes, T, G, S, P, C, in0, in1, XA, XB, YA, YB, WT, Z):
    """interp_game_kernel's rows ya..yb (one chunk of its parallel loop)."""
    h, w = mask_prev.shape
    hw = F32(w * 0.5)
    hh = F32(h * 0.5)
    wm1 = F32(w - 1)
    hm1 = F32(h - 1)
    w32 = I32(w)
    h32 = I32(h)
    hw32 = I32(h * w)
    eps = F32(1e-6)
    eps2 = F32(1e-6 * 1e-6)
    for y in range(ya, yb):
        yf = F32(y)
        gyy = gyn[y]
        lo_y = F32(-0.5) - yf
        hi_y = F32(h - 0.5) - yf
        if WINDOW16:  # taps into row buffers, then 16 pixels per fetch, the rest per pixel
            _samples_along(c0, vec, a, y, gxn, gyy, kx, ky, hw, hh, wm1, hm1, w32, h32, hw32,
                           lo_y, hi_y, XA, XB, YA, YB, WT, Z, P, in0)
            _samples_along(c1, vec, na, y, gxn, gyy, kx, ky, hw, hh, wm1, hm1, w32, h32, hw32,
                           lo_y, hi_y, XA, XB, YA, YB, WT, Z, C, in1)
        else:
            for x in range(w):
                in0[x] = F32(_sample(c0, smv_b(vec[0, y, x]) * a, smv_b(vec[1, y, x]) * a, x,
                                     y, F32(I32(x)), lo_y, hi_y, gxn[x], gyy, kx, ky, hw, hh, wm1,
                                     hm1, w32, h32, hw32, P, x))
            for x in range(w):
                in1[x] = F32(_sample(c1, smv_b(vec[0, y, x]) * na, smv_b(vec[1, y, x]) * na,
                                     x, y, F32(I32(x)), lo_y, hi_y, gxn[x], gyy, kx, ky, hw, hh,
                                     wm1, hm1, w32, h32, hw32, C, x))
        for x in range(w):
            mx = mask_prev[y, x] * in0[x]
            my = mask_cur[y, x] * in1[x]
            T[y, x] = clamp_b((a + nb * (F32(1.0) - mx)) - a * (F32(1.0) - my), F32(0.0),
                              F32(1.0))
            holes[y, x] = (mx <= F32(0.0)) & (my <= F32(0.0))
            G[y, x] = F32((mx > F32(0.0)) != (my > F32(0.0)))
        for k in range(3):
            for x in range(w):
                r = _lerp_b(P[k, x], C[k, x], T[y, x])
                out[k, y, x] = r if has_of else sval_b(r)
        if has_of:
            for x in range(w):
                S[y, x] = _similarity(P, C, x, eps, eps2)


@njit(**KERNEL)
def interp_game_kernel(c0, c1, vec, mask_prev, mask_cur, has_of, a, na, nb, gxn, gyn, kx, ky,
                       out, holes, T, G, S):
    """interpolate_fsr3's game path (linear space, 3-channel colour): out = lerp(P, C, t)
    (sanitised unless ``has_of``), holes, and for the optical-flow pass the lerp weight
    T = t, G = 1.0 where exactly one mask is 0 (the game path decides), S = the game
    samples' colour similarity. a = alpha, na = -(1 - alpha) (the scale of the vectors
    toward frame 1), nb = 1 - alpha, all float32."""
    h, w = mask_prev.shape
    nch = min(h, 64)
    for pch in prange(nch):
        ch = dealt(pch, nch)  # (each thread's chunks spread over the frame)
        ya = ch * h // nch
        yb = (ch + 1) * h // nch
        # (row buffers allocated here one by one: unpacked from a helper's tuple they would
        # count as aliases and no loop of the kernel would be vectorised)
        P = np.empty((3, w), dtype=np.float32)
        C = np.empty((3, w), dtype=np.float32)
        in0 = np.empty(w, dtype=np.float32)
        in1 = np.empty(w, dtype=np.float32)
        XA = np.empty(w, dtype=np.int32)
        XB = np.empty(w, dtype=np.int32)
        YA = np.empty(w, dtype=np.int32)
        YB = np.empty(w, dtype=np.int32)
        WT = np.empty((4, w), dtype=np.float32)
        Z = np.empty(w, dtype=np.int32)
        _interp_game_rows(ya, yb, c0, c1, vec, mask_prev, mask_cur, has_of, a, na, nb, gxn, gyn,
                          kx, ky, out, holes, T, G, S, P, C, in0, in1, XA, XB, YA, YB, WT, Z)


@njit(**KERNEL)
def interp_flow_kernel(c0, c1, of_vec, a, na, gxn, gyn, kx, ky, T, G, S, out, bias):
    """interpolate_fsr3's optical-flow path after interp_game_kernel: the flow samples,
    their lerp by T, the bias clamp(S_game / S_of, 0, 1) (1 where G), the final lerp and
    the sanitising of the output."""
    h, w = T.shape
    hw = F32(w * 0.5)
    hh = F32(h * 0.5)
    wm1 = F32(w - 1)
    hm1 = F32(h - 1)
    w32 = I32(w)
    h32 = I32(h)
    hw32 = I32(h * w)
    nblk = w // 16
    eps = F32(1e-6)
    eps2 = F32(1e-6 * 1e-6)
    for py in prange(h):
        y = np.int64(py)
        yf = F32(y)
        gyy = gyn[y]
        lo_y = F32(-0.5) - yf
        hi_y = F32(h - 0.5) - yf
        Po = np.empty((3, w), dtype=np.float32)
        Co = np.empty((3, w), dtype=np.float32)
        if WINDOW16:  # as interp_game_kernel
            # (bil_taps' row buffers, allocated here: unpacked from a helper's tuple they
            # would count as aliases and no loop of the kernel would be vectorised)
            XA = np.empty(w, dtype=np.int32)
            XB = np.empty(w, dtype=np.int32)
            YA = np.empty(w, dtype=np.int32)
            YB = np.empty(w, dtype=np.int32)
            WT = np.empty((4, w), dtype=np.float32)
            Z = np.empty(w, dtype=np.int32)
            for x in range(w):
                bil_taps(smv_b(of_vec[0, y, x]) * a, smv_b(of_vec[1, y, x]) * a, x, gxn[x],
                         gyy, kx, ky, hw, hh, wm1, hm1, w32, h32, XA, XB, YA, YB, WT, Z)
            for blk in range(nblk):
                bilinear16x3(c0, hw32, w32, h32, XA, XB, YA, YB, WT, Z, I32(16 * blk),
                             I32(y * w), Po, w32, I32(0))
            for x in range(16 * nblk, w):
                _sample(c0, smv_b(of_vec[0, y, x]) * a, smv_b(of_vec[1, y, x]) * a, x, y,
                        F32(I32(x)), lo_y, hi_y, gxn[x], gyy, kx, ky, hw, hh, wm1, hm1, w32, h32,
                        hw32, Po, x)
            for x in range(w):
                bil_taps(smv_b(of_vec[0, y, x]) * na, smv_b(of_vec[1, y, x]) * na, x, gxn[x],
                         gyy, kx, ky, hw, hh, wm1, hm1, w32, h32, XA, XB, YA, YB, WT, Z)
            for blk in range(nblk):
                bilinear16x3(c1, hw32, w32, h32, XA, XB, YA, YB, WT, Z, I32(16 * blk),
                             I32(y * w), Co, w32, I32(0))
            for x in range(16 * nblk, w):
                _sample(c1, smv_b(of_vec[0, y, x]) * na, smv_b(of_vec[1, y, x]) * na, x, y,
                        F32(I32(x)), lo_y, hi_y, gxn[x], gyy, kx, ky, hw, hh, wm1, hm1, w32, h32,
                        hw32, Co, x)
        else:
            for x in range(w):
                _sample(c0, smv_b(of_vec[0, y, x]) * a, smv_b(of_vec[1, y, x]) * a, x, y,
                        F32(I32(x)), lo_y, hi_y, gxn[x], gyy, kx, ky, hw, hh, wm1, hm1, w32, h32,
                        hw32, Po, x)
            for x in range(w):
                _sample(c1, smv_b(of_vec[0, y, x]) * na, smv_b(of_vec[1, y, x]) * na, x, y,
                        F32(I32(x)), lo_y, hi_y, gxn[x], gyy, kx, ky, hw, hh, wm1, hm1, w32, h32,
                        hw32, Co, x)
        for x in range(w):
            s_of = _similarity(Po, Co, x, eps, eps2)
            b = S[y, x] / (eps if s_of < eps else s_of)
            b = F32(1.0) if s_of <= F32(0.0) else b
            b = clamp_b(b, F32(0.0), F32(1.0))
            bias[y, x] = F32(1.0) if (b != b) | (G[y, x] != F32(0.0)) else b
        for k in range(3):
            for x in range(w):
                cof = _lerp_b(Po[k, x], Co[k, x], T[y, x])
                out[k, y, x] = sval_b(_lerp_b(cof, out[k, y, x], bias[y, x]))


@njit(**ROWS)
def _interp_window_rows(ya, yb, c0, c1, vec, of_vec, mask_prev, mask_cur, a, na, nb, gxn, gyn, kx,
                        ky, out, holes, bias, XA, XB, YA, YB, WT, Z, P, C, O, in0, in1, T, G, S,
                        pool, lev1, nh, PR):
    """interp_window_kernel's rows ya..yb (one chunk of its parallel loop; ya even)."""
    h, w = mask_prev.shape
    hw = F32(w * 0.5)
    hh = F32(h * 0.5)
    wm1 = F32(w - 1)
    hm1 = F32(h - 1)
    w32 = I32(w)
    h32 = I32(h)
    hw32 = I32(h * w)
    eps = F32(1e-6)
    eps2 = F32(1e-6 * 1e-6)
    for y in range(ya, yb):
        yf = F32(y)
        gyy = gyn[y]
        lo_y = F32(-0.5) - yf
        hi_y = F32(h - 0.5) - yf
        # the game samples toward both frames
        _samples_along(c0, vec, a, y, gxn, gyy, kx, ky, hw, hh, wm1, hm1, w32, h32, hw32, lo_y,
                       hi_y, XA, XB, YA, YB, WT, Z, P, in0)
        _samples_along(c1, vec, na, y, gxn, gyy, kx, ky, hw, hh, wm1, hm1, w32, h32, hw32, lo_y,
                       hi_y, XA, XB, YA, YB, WT, Z, C, in1)
        for x in range(w):
            mx = mask_prev[y, x] * in0[x]
            my = mask_cur[y, x] * in1[x]
            T[x] = clamp_b((a + nb * (F32(1.0) - mx)) - a * (F32(1.0) - my), F32(0.0),
                           F32(1.0))
            holes[y, x] = (mx <= F32(0.0)) & (my <= F32(0.0))
            G[x] = F32((mx > F32(0.0)) != (my > F32(0.0)))
        for k in range(3):
            for x in range(w):
                O[k, x] = _lerp_b(P[k, x], C[k, x], T[x])
        for x in range(w):
            S[x] = _similarity(P, C, x, eps, eps2)
        # the optical-flow samples (into P and C: the game ones are used up)
        _samples_along(c0, of_vec, a, y, gxn, gyy, kx, ky, hw, hh, wm1, hm1, w32, h32, hw32,
                       lo_y, hi_y, XA, XB, YA, YB, WT, Z, P, None)
        _samples_along(c1, of_vec, na, y, gxn, gyy, kx, ky, hw, hh, wm1, hm1, w32, h32, hw32,
                       lo_y, hi_y, XA, XB, YA, YB, WT, Z, C, None)
        for x in range(w):
            s_of = _similarity(P, C, x, eps, eps2)
            b = S[x] / (eps if s_of < eps else s_of)
            b = F32(1.0) if s_of <= F32(0.0) else b
            b = clamp_b(b, F32(0.0), F32(1.0))
            bias[y, x] = F32(1.0) if (b != b) | (G[x] != F32(0.0)) else b
        for k in range(3):
            for x in range(w):
                cof = _lerp_b(P[k, x], C[k, x], T[x])
                out[k, y, x] = sval_b(_lerp_b(cof, O[k, x], bias[y, x]))
        if pool and (y & 1 == 1 or y == h - 1):  # a pair of rows done: its level-1 texels
            q = y >> 1
            y0 = 2 * q
            nr = y - y0 + 1
            n = 0
            for r in range(nr):
                for x in range(w):
                    n += np.int64(holes[y0 + r, x])
            nh[q] = n
            for k in range(4):
                for r in range(nr):
                    if k < 3:
                        for x in range(w):
                            PR[r, x] = out[k, y0 + r, x] * (F32(0.0) if holes[y0 + r, x]
                                                             else F32(1.0))
                    else:
                        for x in range(w):
                            PR[r, x] = F32(0.0) if holes[y0 + r, x] else F32(1.0)
                _pool_rows(PR, nr, w, lev1, k, q)


@njit(**KERNEL)
def interp_window_kernel(c0, c1, vec, of_vec, mask_prev, mask_cur, a, na, nb, gxn, gyn, kx, ky,
                         out, holes, bias, pool, lev1, nh):
    """interp_game_kernel and interp_flow_kernel (with the optical-flow path) in one pass,
    row by row, every colour sample through the 16-lane window fetches (AVX-512 or AVX2:
    HAVE_WINDOW16): the lerp weight, the mask flags, the game samples' similarity and their
    lerp stay in row buffers instead of six frame-sized planes written and read back. The
    same operations, bit for bit. ``pool``: also the colour inpainting's level 1 of each
    pair of rows as they are done (lev1 (4, h2, w2), nh (h2,): what inpaint_prep_kernel
    makes of the output and its holes, the same sums; chunks of whole pairs), while the
    rows are in cache instead of read again by the inpainting (else lev1 and nh are not
    written)."""
    h, w = mask_prev.shape
    h2 = (h + 1) // 2
    nch = min(h2, 64)
    for pch in prange(nch):
        ch = dealt(pch, nch)  # (each thread's chunks spread over the frame)
        ya = 2 * (ch * h2 // nch)
        yb = min(h, 2 * ((ch + 1) * h2 // nch))
        # (row buffers allocated here one by one: see interp_game_kernel)
        XA = np.empty(w, dtype=np.int32)
        XB = np.empty(w, dtype=np.int32)
        YA = np.empty(w, dtype=np.int32)
        YB = np.empty(w, dtype=np.int32)
        WT = np.empty((4, w), dtype=np.float32)
        Z = np.empty(w, dtype=np.int32)
        P = np.empty((3, w), dtype=np.float32)
        C = np.empty((3, w), dtype=np.float32)
        O = np.empty((3, w), dtype=np.float32)  # the game path's lerp
        in0 = np.empty(w, dtype=np.float32)
        in1 = np.empty(w, dtype=np.float32)
        T = np.empty(w, dtype=np.float32)
        G = np.empty(w, dtype=np.float32)
        S = np.empty(w, dtype=np.float32)
        PR = np.empty((2, w), dtype=np.float32)  # (a pair of rows' products, pooled)
        _interp_window_rows(ya, yb, c0, c1, vec, of_vec, mask_prev, mask_cur, a, na, nb, gxn, gyn,
                            kx, ky, out, holes, bias, XA, XB, YA, YB, WT, Z, P, C, O, in0, in1, T,
                            G, S, pool, lev1, nh, PR)


@njit(**INLINE)
def _nearest_at(v, s, p, lim):
    """sample_nearest's clamped column (or row) of pixel p (float32) moved by the
    sanitised component v times s: floor(sflow(v s) + (p + 0.5)) clamped to [0, lim], as
    int32 (fgcli.kernels.warp._nearest_depth32's)."""
    return I32(clamp_b(np.floor(sflow_b(v * s) + (p + F32(0.5))), F32(0.0), lim))


@njit(**ROWS)
def _depth_rows(ya, yb, depth_t, depth0, depth1, vec, a, na, out, JX, JY, S0, S1):
    """interpolated_depth of rows ya..yb: sanitize_depth(depth_t), and where that is +inf
    the minimum of the sanitised depth0 at the nearest pixel to q + a v and depth1 at
    q + na v. The row first (vectorised, counting its +inf); then a row with a few takes
    them one by one (their columns listed in JX), a row with many (sky) fetches both
    frames' nearest depths 16 pixels at a time (nearest16, into the row buffers S0, S1 by
    JX, JY; AVX-512 or AVX2: WINDOW16) and its +inf pixels take their minimum. (One pass
    with the lookups under a branch was vectorised into masked gathers, which cost as
    much with no lane active: 1080p, Zen 5, 2.3 ms per frame with no +inf at all.)"""
    h, w = depth_t.shape
    wm1 = F32(w - 1)
    hm1 = F32(h - 1)
    w32 = I32(w)
    h32 = I32(h)
    nb = w // 16 if WINDOW16 else 0
    for y in range(ya, yb):
        yf = F32(y)
        n = 0
        for x in range(w):
            z = sdepth_b(depth_t[y, x])
            out[y, x] = z
            n += np.int64(z == INF)
        if n == 0:
            continue
        if n * 4 <= w or nb == 0:  # a few: those pixels one by one
            m = 0
            for x in range(w):
                JX[m] = I32(x)
                m += np.int64(out[y, x] == INF)
            for k in range(m):
                x = np.int64(JX[k])
                vx = smv_b(vec[0, y, x])
                vy = smv_b(vec[1, y, x])
                xf = F32(I32(x))
                z0 = sdepth_b(_nearest_depth32(depth0, sflow_b(vx * a), sflow_b(vy * a), xf,
                                               yf, wm1, hm1, w32))
                z1 = sdepth_b(_nearest_depth32(depth1, sflow_b(vx * na), sflow_b(vy * na),
                                               xf, yf, wm1, hm1, w32))
                out[y, x] = z0 if z0 < z1 else z1
            continue
        # many (sky): the whole row's lookups, 16 pixels per fetch
        for x in range(w):
            JX[x] = _nearest_at(smv_b(vec[0, y, x]), a, F32(I32(x)), wm1)
            JY[x] = _nearest_at(smv_b(vec[1, y, x]), a, yf, hm1)
        for b in range(nb):
            nearest16(depth0, w32, h32, JX, JY, I32(16 * b), S0, I32(0))
        for x in range(w):
            JX[x] = _nearest_at(smv_b(vec[0, y, x]), na, F32(I32(x)), wm1)
            JY[x] = _nearest_at(smv_b(vec[1, y, x]), na, yf, hm1)
        for b in range(nb):
            nearest16(depth1, w32, h32, JX, JY, I32(16 * b), S1, I32(0))
        for x in range(16 * nb, w):
            vx = smv_b(vec[0, y, x])
            vy = smv_b(vec[1, y, x])
            xf = F32(I32(x))
            S0[x] = _nearest_depth32(depth0, sflow_b(vx * a), sflow_b(vy * a), xf, yf, wm1,
                                     hm1, w32)
            S1[x] = _nearest_depth32(depth1, sflow_b(vx * na), sflow_b(vy * na), xf, yf, wm1,
                                     hm1, w32)
        for x in range(w):
            z0 = sdepth_b(S0[x])
            z1 = sdepth_b(S1[x])
            z = out[y, x]
            out[y, x] = (z0 if z0 < z1 else z1) if z == INF else z


@njit(**KERNEL)
def interp_depth_kernel(depth_t, depth0, depth1, vec, a, na, out):
    """interpolated_depth (_depth_rows): a = alpha, na = -(1 - alpha), float32;
    C-contiguous depths of fewer than 2**31 pixels."""
    h, w = depth_t.shape
    nch = min(h, 64)
    for pch in prange(nch):
        ch = dealt(pch, nch)  # (each thread's chunks spread over the frame)
        ya = ch * h // nch
        yb = (ch + 1) * h // nch
        JX = np.empty(w, dtype=np.int32)
        JY = np.empty(w, dtype=np.int32)
        S0 = np.empty(w, dtype=np.float32)
        S1 = np.empty(w, dtype=np.float32)
        _depth_rows(ya, yb, depth_t, depth0, depth1, vec, a, na, out, JX, JY, S0, S1)


@njit(**KERNEL)
def scale_mv_kernel(vec, s, out):
    """output_vectors: out = sanitize_mv(vec) * s (float32 (2, h, w), s float32 as torch
    rounds a Python scalar), one pass."""
    h, w = vec.shape[1], vec.shape[2]
    for py in prange(h):
        y = np.int64(py)
        for c in range(2):
            for x in range(w):
                out[c, y, x] = smv_b(vec[c, y, x]) * s


@njit(**KERNEL)
def sample_flow_kernel(vec, ya, yb, wy0, wy1, xa, xb, wx0, wx1, out):
    """sample_flow_field per pixel: the bilinear mean of the unpacked block field vec
    (2, fh, fw) float32 at each pixel, from the per-row / per-column taps and weights of
    flow_field_coords (int64 indices, float32 weights, 0 off the grid); the reference's
    float32 products and sums in its order -> out (2, h, w)."""
    h = ya.shape[0]
    w = xa.shape[0]
    for py in prange(h):
        y = np.int64(py)
        r0 = ya[y]
        r1 = yb[y]
        a0 = wy0[y]
        a1 = wy1[y]
        for k in range(2):
            for x in range(w):
                c0 = xa[x]
                c1 = xb[x]
                w00 = a0 * wx0[x]
                w10 = a0 * wx1[x]
                w01 = a1 * wx0[x]
                w11 = a1 * wx1[x]
                sw = ((w00 + w10) + w01) + w11
                acc = ((vec[k, r0, c0] * w00 + vec[k, r0, c1] * w10) + vec[k, r1, c0] * w01) \
                    + vec[k, r1, c1] * w11
                d = sw if sw >= F32(1e-30) else F32(1e-30)
                out[k, y, x] = acc / d if sw > F32(0.0) else F32(0.0)
