"""Mob-FGSR gap fill (splat-crack refinement, 'nearest' candidate) and the extrapolation
hole rule (fgcli.ops.fill) as one-pass numba kernels reading only pre-fill values, like
the reference. Bit-identical to the torch reference."""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from fgcli.kernels._common import (ALL1, F32, INF, INLINE, KERNEL, NONE8, bits, clamp_b, f2i64,
                                   sdepth_b, smv_b)

I32 = np.int32

# 3x3 neighbours, row-major, centre included (index 4)
DY9 = np.array([-1, -1, -1, 0, 0, 0, 1, 1, 1], dtype=np.int64)
DX9 = np.array([-1, 0, 1, -1, 0, 1, -1, 0, 1], dtype=np.int64)


@njit(**INLINE)
def _row_px(valid, depth, rr, x, rin):
    """Pixel x of the rolling row buffers: (gap-fill depth, +inf at holes; valid 0 / 1)."""
    vv = (valid[rr, x] != 0) & rin
    return (sdepth_b(depth[rr, x]) if vv else INF), (np.uint8(1) if vv else np.uint8(0))


@njit(**INLINE)
def _keep_px(D, V, sa, sb, sc, x, f1):
    """The 2x2-block rule at pixel x of the rolling buffers (rows sa, sb, sc = y - 1, y,
    y + 1; column x + 1 is the pixel), as selects: the candidates are the valid
    neighbours nearer than the limit (every valid one around a hole); the pixel is kept
    when one of its four 2x2 blocks holds none."""
    limit = D[sb, x + 1] * f1
    hc = V[sb, x + 1] == 0
    n0 = (V[sa, x] != 0) & ((D[sa, x] < limit) | hc)
    n1 = (V[sa, x + 1] != 0) & ((D[sa, x + 1] < limit) | hc)
    n2 = (V[sa, x + 2] != 0) & ((D[sa, x + 2] < limit) | hc)
    n3 = (V[sb, x] != 0) & ((D[sb, x] < limit) | hc)
    n5 = (V[sb, x + 2] != 0) & ((D[sb, x + 2] < limit) | hc)
    n6 = (V[sc, x] != 0) & ((D[sc, x] < limit) | hc)
    n7 = (V[sc, x + 1] != 0) & ((D[sc, x + 1] < limit) | hc)
    n8 = (V[sc, x + 2] != 0) & ((D[sc, x + 2] < limit) | hc)
    return ((not n0) & (not n1) & (not n3)) | ((not n1) & (not n2) & (not n5)) | \
        ((not n3) & (not n6) & (not n7)) | ((not n5) & (not n7) & (not n8))


@njit(**INLINE)
def _nearest_candidate(D, V, sa, sb, sc, x, f1):
    """The candidate a filled pixel x takes: the nearest (0..8 row-major; ties to the
    first in that order)."""
    limit = D[sb, x + 1] * f1
    hc = V[sb, x + 1] == 0
    best = -1
    bd = INF
    for k in range(9):
        s = sa if k < 3 else (sb if k < 6 else sc)
        j = x + 1 + DX9[k]
        dk = D[s, j]
        if k != 4 and V[s, j] != 0 and (dk < limit or hc) and (best < 0 or dk < bd):
            best = k
            bd = dk
    return best


@njit(**INLINE)
def _fallback_px(fb, fbd, has0, has_fbd, c1, c0, to1, to0, depth, y, x):
    """The fallback fields at hole (y, x): vectors fb scaled by c1 (and c0 into to0 when
    has0), the depth fbd when has_fbd."""
    mx = smv_b(fb[0, y, x])
    my = smv_b(fb[1, y, x])
    to1[0, y, x] = mx * c1
    to1[1, y, x] = my * c1
    if has0:
        to0[0, y, x] = mx * c0
        to0[1, y, x] = my * c0
    if has_fbd:
        depth[y, x] = sdepth_b(fbd[y, x])


@njit(**INLINE)
def _extrap_hole(mv1, depth1, x, y, yf, alpha, f1, has0, w, h, wm1, hm1):
    """fill_extrap_holes at hole (x, y): (to1 x, to1 y, depth, to0 x, to0 y), to0 zero
    when not has0."""
    xf = F32(I32(x))
    mx = smv_b(mv1[0, y, x]) * alpha
    my = smv_b(mv1[1, y, x]) * alpha
    sx = xf + mx
    sy = yf + my
    inside = (sx >= F32(-0.5)) & (sx < F32(w - 0.5)) & (sy >= F32(-0.5)) & \
        (sy < F32(h - 0.5))
    ix = f2i64(clamp_b(np.floor(sx + F32(0.5)), F32(0.0), wm1))
    iy = f2i64(clamp_b(np.floor(sy + F32(0.5)), F32(0.0), hm1))
    ds = sdepth_b(depth1[iy, ix])
    do = sdepth_b(depth1[y, x])
    bg = inside & (not (ds < do * f1))
    vx = mx if bg else F32(0.0)
    vy = my if bg else F32(0.0)
    ox = F32(0.0)
    oy = F32(0.0)
    if has0:
        jx = f2i64(clamp_b(np.floor((xf + vx) + F32(0.5)), F32(0.0), wm1))
        jy = f2i64(clamp_b(np.floor((yf + vy) + F32(0.5)), F32(0.0), hm1))
        ox = vx + smv_b(mv1[0, jy, jx])
        oy = vy + smv_b(mv1[1, jy, jx])
    return vx, vy, (ds if bg else do), ox, oy


@njit(**INLINE)
def _d(depth, valid, y, x):
    """Gap-fill depth: sanitised, +inf at holes."""
    return sdepth_b(depth[y, x]) if valid[y, x] else INF


@njit(**KERNEL)
def gap_fill_kernel(to1, to0, has0, depth, valid, source, f1, fb, fbd, has_fb, has_fbd, c1,
                    c0, o_to1, o_to0, o_depth, o_valid, o_source, o_filled, o_holes):
    """to1/to0 (2, H, W) (to0 and o_to0 only read and written when has0), depth (H, W),
    valid (H, W) bool, source (H, W) int32; f1 = the float32 factor (1 - threshold);
    fb (2, H, W) / fbd (H, W) fallback fields (used when has_fb / has_fbd); c1, c0 the
    fallback coefficients. Writes the o_* arrays.

    Per row: the 2x2-block candidate rule for every pixel (vectorised selects over a
    rolling 3-row buffer of padded depths), the nearest candidate of the few pixels that
    take one (scalar), the outputs as if no pixel were filled (contiguous, vectorised),
    then the filled pixels' neighbour values (scalar, few)."""
    h, w = depth.shape
    nch = min(h, 64)
    for ch in prange(nch):
        ya = np.int64(ch) * h // nch
        yb = (np.int64(ch) + 1) * h // nch
        D = np.empty((3, w + 2), dtype=np.float32)
        V = np.empty((3, w + 2), dtype=np.uint8)  # (a bool buffer stops vectorisation)
        fill = np.empty(w, dtype=np.uint8)
        off = np.empty(w, dtype=np.int64)  # chosen neighbour (0..8 row-major) of fxs[i]
        fxs = np.empty(w, dtype=np.int64)
        for r in range(ya - 1, yb + 1):
            # row r of the gap-fill depth (+inf at holes) and of valid into slot r % 3,
            # padded with +inf / 0 (rows outside the image: all pads)
            sl = (r + 3) % 3
            D[sl, 0] = INF
            V[sl, 0] = 0
            D[sl, w + 1] = INF
            V[sl, w + 1] = 0
            rin = (r >= 0) & (r < h)
            rr = min(max(r, 0), h - 1)
            for x in range(w):
                D[sl, x + 1], V[sl, x + 1] = _row_px(valid, depth, rr, x, rin)
            if r < ya + 1:
                continue
            y = r - 1
            sa = (y + 2) % 3  # row y - 1
            sb = y % 3
            sc = (y + 1) % 3
            # the 2x2-block rule for every pixel, as selects (vectorised)
            for x in range(w):
                fill[x] = np.uint8(0) if _keep_px(D, V, sa, sb, sc, x, f1) else np.uint8(1)
            # the nearest candidate of the few pixels that take one (scalar; ties to the
            # first in row-major order)
            nf = 0  # filled pixels of this row (their x in fxs[:nf])
            for x in range(w):
                if fill[x] == 0:
                    continue
                best = _nearest_candidate(D, V, sa, sb, sc, x, f1)
                off[nf] = best
                fxs[nf] = x
                nf += 1
            # every pixel as if it kept its own values (contiguous, vectorised; one output
            # plane per loop: one loop writing all of them ran ~1.2x slower) ...
            for x in range(w):
                o_to1[0, y, x] = to1[0, y, x]
            for x in range(w):
                o_to1[1, y, x] = to1[1, y, x]
            if has0:
                for x in range(w):
                    o_to0[0, y, x] = to0[0, y, x]
                for x in range(w):
                    o_to0[1, y, x] = to0[1, y, x]
            for x in range(w):
                o_source[y, x] = source[y, x]
            for x in range(w):
                v = valid[y, x]
                o_depth[y, x] = sdepth_b(depth[y, x]) if v else INF
                o_filled[y, x] = False
                o_valid[y, x] = v
                o_holes[y, x] = not v
            # ... the holes the fallback fields cover (scalar, usually few) ...
            if has_fb:
                for x in range(w):
                    if valid[y, x]:
                        continue
                    _fallback_px(fb, fbd, has0, has_fbd, c1, c0, o_to1, o_to0, o_depth, y, x)
            # ... then the few filled ones take their neighbour's (after the fallback, as the
            # reference)
            for i in range(nf):
                x = fxs[i]
                sy = y + DY9[off[i]]
                sx = x + DX9[off[i]]
                o_to1[0, y, x] = to1[0, sy, sx]
                o_to1[1, y, x] = to1[1, sy, sx]
                if has0:
                    o_to0[0, y, x] = to0[0, sy, sx]
                    o_to0[1, y, x] = to0[1, sy, sx]
                o_depth[y, x] = _d(depth, valid, sy, sx)
                o_source[y, x] = source[sy, sx]
                o_filled[y, x] = True
                o_valid[y, x] = True
                o_holes[y, x] = False


@njit(**KERNEL)
def gap_fill_inplace_kernel(to1, to0, has0, depth, valid, source, f1, fb, fbd, has_fb,
                            has_fbd, c1, c0, o_filled, o_holes):
    """gap_fill_kernel writing into its input planes (to1, to0, depth, valid as uint8,
    source), with the same result: what the copy to fresh planes cost (six planes read
    and written, about 100 MB per 1080p frame) is spared.

    Three passes, each reading only values no pass has yet written: (1) per row, the
    block rule and each filled pixel's chosen neighbour (an int8 code per pixel, -1
    none), filled / holes, and whether the row's depth is already clean (sanitised, +inf
    at holes: as the splat writes it); (2) the chosen neighbours' pre-fill values,
    packed per row after a prefix sum of the rows' counts; (3) the writes: clean depth
    where it was not, the fallback at holes, then the filled pixels. The sparse loops (the
    filled pixels, the holes: ~2 % and ~4 % of the pixels with a moving camera) test eight
    pixels' flags as one 64-bit word and skip the words with none, instead of a branch per
    pixel (1.1-1.4x faster on Zen 3)."""
    h, w = depth.shape
    nch = min(h, 64)
    n8 = w // 8
    code = np.empty((h, w), dtype=np.int8)
    nrow = np.zeros(h + 1, dtype=np.int64)  # filled pixels per row (row y at y + 1)
    fix = np.zeros(h, dtype=np.uint8)  # rows whose depth needs cleaning
    for ch in prange(nch):
        ya = np.int64(ch) * h // nch
        yb = (np.int64(ch) + 1) * h // nch
        D = np.empty((3, w + 2), dtype=np.float32)
        V = np.empty((3, w + 2), dtype=np.uint8)
        fill = np.empty(w, dtype=np.uint8)
        fw = fill[:n8 * 8].view(np.uint64)
        for r in range(ya - 1, yb + 1):
            sl = (r + 3) % 3
            D[sl, 0] = INF
            V[sl, 0] = 0
            D[sl, w + 1] = INF
            V[sl, w + 1] = 0
            rin = (r >= 0) & (r < h)
            rr = min(max(r, 0), h - 1)
            for x in range(w):
                D[sl, x + 1], V[sl, x + 1] = _row_px(valid, depth, rr, x, rin)
            if r < ya + 1:
                continue
            y = r - 1
            sa = (y + 2) % 3  # row y - 1
            sb = y % 3
            sc = (y + 1) % 3
            for x in range(w):  # the 2x2-block rule, as gap_fill_kernel
                fill[x] = np.uint8(0) if _keep_px(D, V, sa, sb, sc, x, f1) else np.uint8(1)
            m = np.int32(0)  # any bit of the clean depth that differs from the plane's
            for x in range(w):
                m |= bits(D[sb, x + 1]) ^ bits(depth[y, x])
            fix[y] = np.uint8(1) if m != 0 else np.uint8(0)
            # (a loop of its own: merged into the scalar loop below, or with counts added
            # to it, the pass ran 1.5x slower)
            for x in range(w):
                code[y, x] = np.int8(-1)
            nf = 0
            for b in range(n8 + 1):  # (the last "word": the row's w % 8 pixels)
                if b < n8 and fw[b] == np.uint64(0):
                    continue
                for x in range(8 * b, min(8 * b + 8, w)):
                    if fill[x] == 0:
                        continue
                    best = _nearest_candidate(D, V, sa, sb, sc, x, f1)
                    code[y, x] = np.int8(best)
                    nf += 1
            nrow[y + 1] = nf
            for x in range(w):
                o_filled[y, x] = fill[x] != 0
                o_holes[y, x] = (valid[y, x] == 0) & (fill[x] == 0)
    for y in range(h):
        nrow[y + 1] += nrow[y]
    n = max(nrow[h], 1)
    cv = np.empty((5, n), dtype=np.float32)  # to1 x, y, to0 x, y, depth
    cs = np.empty(n, dtype=np.int32)
    for py in prange(h):
        y = np.int64(py)
        i = nrow[y]
        if nrow[y + 1] == i:
            continue
        cw = code[y, :n8 * 8].view(np.uint64)
        for b in range(n8 + 1):
            if b < n8 and cw[b] == NONE8:
                continue
            for x in range(8 * b, min(8 * b + 8, w)):
                k = code[y, x]
                if k < 0:
                    continue
                sy = y + DY9[k]
                sx = x + DX9[k]
                cv[0, i] = to1[0, sy, sx]
                cv[1, i] = to1[1, sy, sx]
                if has0:
                    cv[2, i] = to0[0, sy, sx]
                    cv[3, i] = to0[1, sy, sx]
                cv[4, i] = sdepth_b(depth[sy, sx])  # (a candidate is valid)
                cs[i] = source[sy, sx]
                i += 1
    for py in prange(h):
        y = np.int64(py)
        if fix[y] != 0:
            for x in range(w):
                depth[y, x] = sdepth_b(depth[y, x]) if valid[y, x] != 0 else INF
        if has_fb:  # every hole (filled ones are overwritten next, as the reference)
            # eight pixels' flags per test, a word without a hole skipped (a loop over
            # the row with the hole test inside was vectorised into masked loads and
            # stores at every pixel, whose stalls cost ~4 ms per 1080p frame)
            vr = valid[y]
            vw = valid[y, :n8 * 8].view(np.uint64)
            for b in range(n8 + 1):
                if b < n8 and vw[b] == ALL1:
                    continue
                for x in range(8 * b, min(8 * b + 8, w)):
                    if vr[x] != 0:
                        continue
                    _fallback_px(fb, fbd, has0, has_fbd, c1, c0, to1, to0, depth, y, x)
        i = nrow[y]
        if nrow[y + 1] == i:
            continue
        cw = code[y, :n8 * 8].view(np.uint64)
        for b in range(n8 + 1):
            if b < n8 and cw[b] == NONE8:
                continue
            for x in range(8 * b, min(8 * b + 8, w)):
                if code[y, x] < 0:
                    continue
                to1[0, y, x] = cv[0, i]
                to1[1, y, x] = cv[1, i]
                if has0:
                    to0[0, y, x] = cv[2, i]
                    to0[1, y, x] = cv[3, i]
                depth[y, x] = cv[4, i]
                source[y, x] = cs[i]
                valid[y, x] = np.uint8(1)
                i += 1


@njit(**KERNEL)
def extrap_fill_kernel(mv1, depth1, to1, to0, has0, valid, depth_t, alpha, f1,
                       o_to1, o_to0, o_depth, o_holes):
    """fill_extrap_holes: holes (valid False) take alpha * mv1(q) when frame 1's depth at
    the pixel nearest q + alpha * mv1(q) is background (else zero motion), and, when has0,
    to0 = to1 + mv1(nearest q + to1).

    Per row: every pixel as if it were valid (contiguous copies, vectorised), then the
    holes, usually few, one by one (the rule's two gathers only where it applies)."""
    h, w = depth1.shape
    wm1 = F32(w - 1)
    hm1 = F32(h - 1)
    for py in prange(h):
        y = np.int64(py)  # prange indices are unsigned: keep index arithmetic signed
        yf = F32(y)
        for x in range(w):
            ok = valid[y, x]
            o_to1[0, y, x] = to1[0, y, x]
            o_to1[1, y, x] = to1[1, y, x]
            o_depth[y, x] = sdepth_b(depth_t[y, x])
            o_holes[y, x] = not ok
        if has0:
            for x in range(w):
                o_to0[0, y, x] = to0[0, y, x]
                o_to0[1, y, x] = to0[1, y, x]
        for x in range(w):
            if valid[y, x]:
                continue
            vx, vy, dd, ox, oy = _extrap_hole(mv1, depth1, x, y, yf, alpha, f1, has0, w, h,
                                              wm1, hm1)
            o_to1[0, y, x] = vx
            o_to1[1, y, x] = vy
            o_depth[y, x] = dd
            if has0:
                o_to0[0, y, x] = ox
                o_to0[1, y, x] = oy


@njit(**KERNEL)
def extrap_fill_inplace_kernel(mv1, depth1, to1, to0, has0, valid, depth_t, alpha, f1,
                               o_holes):
    """extrap_fill_kernel writing into its input planes (to1, to0, depth_t): each hole
    reads only its own pixel's planes and frame 1's, so no pass order matters; the depth
    of the other pixels is cleaned (sanitised) only in rows where it is not already."""
    h, w = depth1.shape
    wm1 = F32(w - 1)
    hm1 = F32(h - 1)
    for py in prange(h):
        y = np.int64(py)  # prange indices are unsigned: keep index arithmetic signed
        yf = F32(y)
        m = np.int32(0)
        for x in range(w):
            o_holes[y, x] = not valid[y, x]
            m |= bits(sdepth_b(depth_t[y, x])) ^ bits(depth_t[y, x])
        if m != 0:
            for x in range(w):
                depth_t[y, x] = sdepth_b(depth_t[y, x])
        for x in range(w):
            if valid[y, x]:
                continue
            vx, vy, dd, ox, oy = _extrap_hole(mv1, depth1, x, y, yf, alpha, f1, has0, w, h,
                                              wm1, hm1)
            to1[0, y, x] = vx
            to1[1, y, x] = vy
            depth_t[y, x] = dd
            if has0:
                to0[0, y, x] = ox
                to0[1, y, x] = oy
