"""Nearest-depth dilation and the depth-aware forward splat (fgcli.ops.splat), as numba
kernels: one pass for the dilation, two for the splat (scatter with an atomic int64 min of
``depth bits << 32 | source index``, then resolve), no frame-sized temporaries beyond the
key buffer. Bit-identical to the torch reference (same float32 operations, FMA where torch
uses FMA)."""
from __future__ import annotations


import numpy as np
from numba import njit, prange

from fgcli.kernels._common import (F32, I64_MAX, INF, INLINE, KERNEL, ROWS, bits, clamp_b,
                                   sdepth_b, smv_b)
from fgcli.kernels._intrin import (HAVE_WINDOW16, atomic_min_i64, fetch16x2, fma, ld32, mad32,
                                   nearest16)

I32 = np.int32
WINDOW16 = HAVE_WINDOW16


@njit(**KERNEL)
def dilate_kernel(depth, mv, r, dout, mvout):
    """depth (H, W), mv (2, H, W) -> dout (H, W), mvout (2, H, W).

    Separable form of the reference's lexicographic (depth, flat index) minimum over the
    window: per row, a vertical minimum (depth, then the earlier row) of each column, then
    a horizontal minimum of those (depth, row, column) over the padded row buffer, then the
    centre keeps ties. Every inner loop runs over x with selects only (vectorised). On
    slopes a neighbour is nearer than the centre almost everywhere, so the vector is
    gathered at the winner for every pixel (no sparse patch pass)."""
    h, w = depth.shape
    nch = min(h, 64)
    for ch in prange(nch):
        ya = np.int64(ch) * h // nch
        yb = (np.int64(ch) + 1) * h // nch
        vd = np.empty(w + 2 * r, dtype=np.float32)  # vertical minimum, +inf pads
        vy = np.empty(w + 2 * r, dtype=np.int64)  # its row (pads: after every row)
        bd = np.empty(w, dtype=np.float32)
        by = np.empty(w, dtype=np.int64)
        bx = np.empty(w, dtype=np.int64)
        for j in range(r):
            vd[j] = INF
            vy[j] = h
            vd[w + r + j] = INF
            vy[w + r + j] = h
        for y in range(ya, yb):
            y0 = max(0, y - r)
            y1 = min(h - 1, y + r)
            for x in range(w):
                vd[x + r] = sdepth_b(depth[y0, x])
                vy[x + r] = y0
            for yy in range(y0 + 1, y1 + 1):
                for x in range(w):
                    d = sdepth_b(depth[yy, x])
                    t = d < vd[x + r]
                    vd[x + r] = d if t else vd[x + r]
                    vy[x + r] = yy if t else vy[x + r]
            for x in range(w):
                bd[x] = vd[x]
                by[x] = vy[x]
                bx[x] = x - r
            for j in range(1, 2 * r + 1):
                for x in range(w):
                    d = vd[x + j]
                    ry = vy[x + j]
                    t = (d < bd[x]) | ((d == bd[x]) & (ry < by[x]))
                    bd[x] = d if t else bd[x]
                    by[x] = ry if t else by[x]
                    bx[x] = x + j - r if t else bx[x]
            for x in range(w):
                dc = sdepth_b(depth[y, x])
                t = bd[x] < dc
                sy = by[x] if t else y
                sx = bx[x] if t else x
                dout[y, x] = bd[x] if t else dc
                mvout[0, y, x] = smv_b(mv[0, sy, sx])
                mvout[1, y, x] = smv_b(mv[1, sy, sx])


@njit(**INLINE)
def _tap(d, k, best, code):
    """One window tap of the 3x3 dilation: a strictly nearer depth takes the lead (taps in
    row-major order, so among equal depths the first keeps it)."""
    t = d < best
    return (d if t else best), (k if t else code)


@njit(**KERNEL)
def dilate3_kernel(depth, mv, dout, mvout):
    """dilate_kernel for r = 1, one pass per row: the window minimum taken tap by tap over
    a rolling buffer of three sanitised, +inf-padded depth rows (nine selects per pixel,
    the winner as a code 0..8; no index arrays), then the centre keeps ties and the vector
    is gathered at the winner (32-bit indexed loads: C-contiguous mv, 2 H W < 2**31). Same
    result as the separable kernel (and the reference)."""
    h, w = depth.shape
    w32 = I32(w)
    hw32 = I32(h * w)
    nch = min(h, 64)
    for ch in prange(nch):
        ya = np.int64(ch) * h // nch
        yb = (np.int64(ch) + 1) * h // nch
        D = np.empty((3, w + 2), dtype=np.float32)
        code = np.empty(w, dtype=np.int32)
        best = np.empty(w, dtype=np.float32)
        if WINDOW16:
            JX = np.empty(w, dtype=np.int32)
            JY = np.empty(w, dtype=np.int32)
            T = np.empty((2, w), dtype=np.float32)
        for r in range(ya - 1, yb + 1):
            sl = (r + 3) % 3
            D[sl, 0] = INF
            D[sl, w + 1] = INF
            rin = (r >= 0) & (r < h)
            rr = min(max(r, 0), h - 1)
            for x in range(w):
                D[sl, x + 1] = sdepth_b(depth[rr, x]) if rin else INF
            if r < ya + 1:
                continue
            y = r - 1
            sa = (y + 2) % 3  # row y - 1
            sb = y % 3
            sc = (y + 1) % 3
            for x in range(w):
                b = INF
                c = np.int32(4)
                b, c = _tap(D[sa, x], np.int32(0), b, c)
                b, c = _tap(D[sa, x + 1], np.int32(1), b, c)
                b, c = _tap(D[sa, x + 2], np.int32(2), b, c)
                b, c = _tap(D[sb, x], np.int32(3), b, c)
                b, c = _tap(D[sb, x + 1], np.int32(4), b, c)
                b, c = _tap(D[sb, x + 2], np.int32(5), b, c)
                b, c = _tap(D[sc, x], np.int32(6), b, c)
                b, c = _tap(D[sc, x + 1], np.int32(7), b, c)
                b, c = _tap(D[sc, x + 2], np.int32(8), b, c)
                dc = D[sb, x + 1]
                t = b < dc  # the centre keeps ties
                best[x] = b if t else dc
                code[x] = c if t else np.int32(4)
            if WINDOW16:
                for x in range(w):
                    k = np.int64(code[x])
                    q = (k * 11) >> 5
                    JY[x] = I32(y + q - 1)
                    JX[x] = I32(x + (k - 3 * q) - 1)
                    dout[y, x] = best[x]
                for blk in range(w // 16):
                    fetch16x2(mv, hw32, w32, I32(h), JX, JY, I32(16 * blk), T, I32(0), w32)
                for x in range(w // 16 * 16, w):
                    i = mad32(JY[x], w32, JX[x])
                    T[0, x] = ld32(mv, i)
                    T[1, x] = ld32(mv, mad32(hw32, I32(1), i))
                for x in range(w):
                    mvout[0, y, x] = smv_b(T[0, x])
                    mvout[1, y, x] = smv_b(T[1, x])
            else:
                for x in range(w):
                    k = np.int64(code[x])
                    q = (k * 11) >> 5  # k // 3 for k in 0..8, without a division
                    i = mad32(y + q - 1, w32, x + (k - 3 * q) - 1)  # the winner, flat
                    dout[y, x] = best[x]
                    mvout[0, y, x] = smv_b(ld32(mv, i))
                    mvout[1, y, x] = smv_b(ld32(mv, mad32(hw32, I32(1), i)))


@njit(**INLINE)
def _quad_src(ax, ay, xf, yf, w, h):
    """The quadratic displacement's read of frame 0 for a source at (xf, yf) with sanitised
    vector a: (p1 + a inside the frame, the column and row (int32) of the pixel nearest
    p1 + a, clamped)."""
    use = (ax >= F32(-0.5) - xf) & (ax < F32(w - 0.5) - xf) & \
          (ay >= F32(-0.5) - yf) & (ay < F32(h - 0.5) - yf)
    ix = I32(clamp_b(np.floor(ax + (xf + F32(0.5))), F32(0.0), F32(w - 1)))
    iy = I32(clamp_b(np.floor(ay + (yf + F32(0.5))), F32(0.0), F32(h - 1)))
    return use, ix, iy


@njit(**INLINE)
def _quad_mix(ax, ay, b0, b1, d0, d1, use, use_d0, tol, ca, cb):
    """Quadratic displacement p_t - p1 from the source's sanitised vector a, frame 0's raw
    vector (b0, b1) and depth d0 read at _quad_src's pixel, and the source's raw depth d1:
    b is used only when p1 + a is inside (use) and, with the depth check, when the depths
    agree; else b = a. Selects only."""
    d0s = sdepth_b(d0)
    d1s = sdepth_b(d1)
    same = (d0s == d1s) | (abs(d0s - d1s) <= min(d0s, d1s) * tol)
    use = use & (same | (not use_d0))
    bx = smv_b(b0) if use else ax
    by = smv_b(b1) if use else ay
    return fma(ax, ca, bx * cb), fma(ay, ca, by * cb)


@njit(**INLINE)
def _disp_quad(x, y, xf, yf, ax, ay, mv0, depth0, depth1, ca, cb, use_d0, tol, w, h):
    """_quad_src and _quad_mix for source (x, y), frame 0's values by 32-bit indexed
    loads (depth0 is depth1 itself when the check is off: a safe read, the value unused)."""
    use, ix, iy = _quad_src(ax, ay, xf, yf, w, h)
    i = mad32(iy, I32(w), ix)
    return _quad_mix(ax, ay, ld32(mv0, i), ld32(mv0, mad32(I32(w), I32(h), i)),
                     ld32(depth0, i), depth1[y, x], use, use_d0, tol, ca, cb)


@njit(**INLINE)
def _target(dx, dy, xf, yf, w, h):
    """Flat index (int32; (H+2)(W+2) < 2**31) in the (H+2) x (W+2) buffer with an
    off-screen ring of the target pixel of a source at (xf, yf) displaced by (dx, dy). (In
    32-bit integers: AVX2 has no vector float -> int64 conversion, see field.half_bits.)"""
    qx = clamp_b(np.floor(dx + (xf + F32(0.5))), F32(-1.0), F32(w)) + F32(1.0)
    qy = clamp_b(np.floor(dy + (yf + F32(0.5))), F32(-1.0), F32(h)) + F32(1.0)
    return mad32(I32(qy), I32(w + 2), I32(qx))


@njit(**INLINE)
def _resolve_px(k, x, y, quad, w0, depth1, mv1, disp, ca, w, hw, to1, to0, dout, valid,
                source):
    """Target pixel (x, y) from its winning key k (I64_MAX: a hole); quadratic: the
    source's displacement as the scatter stored it in disp; w0: write to0 too
    (quad and w0 are literals at every call, so each loop is compiled without the other
    case). The source's values are 32-bit indexed loads (w, hw = h * w: int32)."""
    ok = k != I64_MAX
    lo = k & 0xFFFFFFFF
    sy = (lo >> 16) if ok else y
    sx = (lo & 0xFFFF) if ok else np.int64(x)
    i = mad32(sy, w, sx)
    ax = smv_b(ld32(mv1, i))
    ay = smv_b(ld32(mv1, mad32(hw, I32(1), i)))
    if quad:
        dx = ld32(disp, i)
        dy = ld32(disp, mad32(hw, I32(1), i))
    else:
        dx = ax * ca
        dy = ay * ca
    _resolve_write(k, x, y, i, ax, ay, dx, dy, w0, to1, to0, dout, valid, source)


@njit(**INLINE)
def _resolve_write(k, x, y, i, ax, ay, dx, dy, w0, to1, to0, dout, valid, source):
    """The resolve's outputs at target (x, y) from its winning key k (I64_MAX: a hole),
    the source's flat index i, vector (ax, ay) and displacement (dx, dy)."""
    ok = k != I64_MAX
    source[y, x] = i if ok else I32(-1)
    valid[y, x] = ok
    dout[y, x] = np.int32(k >> 32).view(np.float32) if ok else INF
    to1[0, y, x] = -dx if ok else F32(0.0)
    to1[1, y, x] = -dy if ok else F32(0.0)
    if w0:
        to0[0, y, x] = ax - dx if ok else F32(0.0)
        to0[1, y, x] = ay - dy if ok else F32(0.0)


@njit(**KERNEL)
def splat_kernel(depth1, mv1, mv0, depth0, ca, cb, quad, use_d0, tol, buf, disp):
    """Scatter: the minimum of packed keys ``depth bits << 32 | y << 16 | x`` into buf,
    (H+2)*(W+2) with an off-screen ring (the (y, x) packing orders like the flat index);
    quadratic: every source's displacement into disp (2, H, W; stored as pairs, (H, W, 2),
    the loop was not vectorised: 2x slower). splat_resolve_kernel then reads the winners.
    Widths and heights are below 65536 and 2 H W < 2**31 (the wrapper checks).

    Scatter without atomics where no other thread can write: the source rows are cut into
    bands, even bands run in parallel, then odd ones; a source whose target row lies within
    half a band of its own band (its zone: zones of bands running together never overlap)
    takes a plain read-compare-write, any other is deferred to a last pass that uses an
    atomic minimum. An atomic per source serialises the cache misses (2-3x slower); the
    minimum is unique, so the result never depends on thread timing.

    Per row, the sources' targets (flat, int32) and keys' high words go into row buffers
    in a vectorised loop (32-bit: 8 lanes on AVX2, where int64 targets and keys held it at
    4), the scatter loop composes the keys; quadratic, with the 16-lane fetches
    (WINDOW16), frame 0's vectors and depths at p1 + a are fetched 16 sources at a time
    (fetch16x2, nearest16; LLVM leaves a loop with gathers scalar).
    A row whose sources all land on their own pixels (zero or sub-pixel displacements: the
    static parts of a frame) takes its minima as one vectorised pass over its own texels
    (within the band's zone; no two sources of the row share a target)."""
    h, w = depth1.shape
    w2 = w + 2
    nb = buf.shape[0]
    for i in prange(nb):
        buf[i] = I64_MAX
    bh = max(8, (h + 31) // 32)  # band height
    nband = (h + bh - 1) // bh
    half = bh // 2
    w32 = I32(w)
    h32 = I32(h)
    hw32 = I32(h * w)
    nblk = w // 16
    deferred = np.zeros(h * w, dtype=np.uint8)
    dq = np.empty(h * w, dtype=np.int64)
    ndef = np.zeros(nband, dtype=np.int64)  # deferred sources per band (one thread each)
    for phase in range(2):
        for bi in prange((nband - phase + 1) // 2):
            band = 2 * np.int64(bi) + phase
            ya = band * bh
            yb = min(h, ya + bh)
            # the zone's rows (buffer rows carry the +1 ring offset) as flat indices: a
            # flat index qy * w2 + qx (0 <= qx < w2) lies within them iff qy does
            zlo = (ya - half + 1) * w2
            zhi = (yb + half + 1) * w2
            # a row's targets (flat) and keys' high words: int32, eight vector lanes on AVX2
            Q = np.empty(w, dtype=np.int32)
            KH = np.empty(w, dtype=np.int32)
            if WINDOW16:
                JX = np.empty(w, dtype=np.int32)
                JY = np.empty(w, dtype=np.int32)
                U = np.empty(w, dtype=np.int32)
                T = np.empty((3, w), dtype=np.float32)
            for y in range(ya, yb):
                yf = F32(y)
                if WINDOW16 and quad:  # frame 0's reads into row buffers, 16 per fetch
                    for x in range(w):
                        use, JX[x], JY[x] = _quad_src(smv_b(mv1[0, y, x]), smv_b(mv1[1, y, x]),
                                                      F32(I32(x)), yf, w, h)
                        U[x] = I32(1) if use else I32(0)
                    for blk in range(nblk):
                        fetch16x2(mv0, hw32, w32, h32, JX, JY, I32(16 * blk), T, I32(0), w32)
                        if use_d0:  # (NaN read as +inf: the same after sdepth_b)
                            nearest16(depth0, w32, h32, JX, JY, I32(16 * blk), T, I32(2 * w))
                    for x in range(16 * nblk, w):
                        i = mad32(JY[x], w32, JX[x])
                        T[0, x] = ld32(mv0, i)
                        T[1, x] = ld32(mv0, mad32(hw32, I32(1), i))
                        T[2, x] = ld32(depth0, i)
                    for x in range(w):
                        xf = F32(I32(x))
                        ax = smv_b(mv1[0, y, x])
                        ay = smv_b(mv1[1, y, x])
                        dx, dy = _quad_mix(ax, ay, T[0, x], T[1, x], T[2, x], depth1[y, x],
                                           U[x] != I32(0), use_d0, tol, ca, cb)
                        disp[0, y, x] = dx
                        disp[1, y, x] = dy
                        Q[x] = _target(dx, dy, xf, yf, w, h)
                        KH[x] = bits(sdepth_b(depth1[y, x]))
                elif quad:
                    for x in range(w):
                        xf = F32(I32(x))
                        ax = smv_b(mv1[0, y, x])
                        ay = smv_b(mv1[1, y, x])
                        dx, dy = _disp_quad(x, y, xf, yf, ax, ay, mv0, depth0, depth1, ca, cb,
                                            use_d0, tol, w, h)
                        disp[0, y, x] = dx  # the resolve reads it back at the winner
                        disp[1, y, x] = dy
                        Q[x] = _target(dx, dy, xf, yf, w, h)
                        KH[x] = bits(sdepth_b(depth1[y, x]))
                else:
                    for x in range(w):
                        xf = F32(I32(x))
                        dx = smv_b(mv1[0, y, x]) * ca
                        dy = smv_b(mv1[1, y, x]) * ca
                        Q[x] = _target(dx, dy, xf, yf, w, h)
                        KH[x] = bits(sdepth_b(depth1[y, x]))
                yk = y << 16
                r = (y + 1) * w2 + 1  # (the row's own texels: r + x)
                own = I32(1)
                for x in range(w):
                    own &= I32(np.int64(Q[x]) == r + x)
                if own != 0:  # every source onto its own pixel: no target collides
                    ro = buf[r:r + w]
                    for x in range(w):
                        k = (np.int64(KH[x]) << 32) | yk | x
                        ro[x] = k if k < ro[x] else ro[x]
                    continue
                for x in range(w):
                    q = np.int64(Q[x])
                    if q >= zlo and q < zhi:
                        k = (np.int64(KH[x]) << 32) | yk | x
                        # (an unsigned index: q >= 0, _target's flat index into the
                        # ringed buffer, and numba then leaves out its negative-index
                        # wraparound: three instructions a source)
                        uq = np.uint64(q)
                        if k < buf[uq]:
                            buf[uq] = k
                    else:
                        deferred[y * w + x] = 1
                        dq[y * w + x] = q
                        ndef[band] += 1
    for py in prange(h):
        y = np.int64(py)
        if ndef[y // bh] == 0:  # usually every band: no row to scan
            continue
        for x in range(w):
            i = y * w + x
            if deferred[i] != 0:
                atomic_min_i64(buf, dq[i],
                               (np.int64(bits(sdepth_b(depth1[y, x]))) << 32) | (y << 16) | x)


@njit(**KERNEL)
def splat_resolve_pixels_kernel(buf, depth1, mv1, disp, ca, quad, w0, to1, to0, dout, valid,
                         source):
    """Every target pixel from its winning key in buf (splat_kernel's scatter).

    A kernel of its own: inside the scatter's kernel LLVM left these loops scalar (no
    gathers in the assembly; 10-11 ms at 1080p against 6-7 ms here). (splat_resolve_kernel:
    this one, or splat_resolve_window_kernel where the CPU has AVX-512.)"""
    h, w = depth1.shape
    w2 = w + 2
    w32 = I32(w)
    hw32 = I32(h * w)
    for py in prange(h):
        y = np.int64(py)
        r = (y + 1) * w2 + 1
        br = buf[r:r + w]  # (a row view: see _splat_resolve_window_rows)
        if quad and w0:
            for x in range(w):
                _resolve_px(br[x], x, y, True, True, depth1, mv1, disp, ca, w32, hw32,
                            to1, to0, dout, valid, source)
        elif quad:
            for x in range(w):
                _resolve_px(br[x], x, y, True, False, depth1, mv1, disp, ca, w32, hw32,
                            to1, to0, dout, valid, source)
        elif w0:
            for x in range(w):
                _resolve_px(br[x], x, y, False, True, depth1, mv1, disp, ca, w32, hw32,
                            to1, to0, dout, valid, source)
        else:
            for x in range(w):
                _resolve_px(br[x], x, y, False, False, depth1, mv1, disp, ca, w32, hw32,
                            to1, to0, dout, valid, source)


@njit(**INLINE)
def _winner_px(k, x, y, JX, JY):
    """The source pixel of target (x, y) from its key (itself for a hole), into JX, JY."""
    ok = k != I64_MAX
    lo = k & 0xFFFFFFFF
    JY[x] = I32(lo >> 16) if ok else I32(y)
    JX[x] = I32(lo & 0xFFFF) if ok else I32(x)


@njit(**INLINE)
def _resolve_from(k, x, y, quad, w0, T, ca, w, to1, to0, dout, valid, source):
    """_resolve_px with the source's vector (and quadratic displacement) already read
    into the row buffer T (4, W): mv1's two planes, then disp's."""
    ok = k != I64_MAX
    lo = k & 0xFFFFFFFF
    sy = (lo >> 16) if ok else y
    sx = (lo & 0xFFFF) if ok else np.int64(x)
    ax = smv_b(T[0, x])
    ay = smv_b(T[1, x])
    if quad:
        dx = T[2, x]
        dy = T[3, x]
    else:
        dx = ax * ca
        dy = ay * ca
    _resolve_write(k, x, y, mad32(sy, w, sx), ax, ay, dx, dy, w0, to1, to0, dout, valid,
                   source)


@njit(**ROWS)
def _splat_resolve_window_rows(ya, yb, buf, depth1, mv1, disp, ca, quad, w0, to1, to0, dout, valid,
                               source, JX, JY, T):
    """splat_resolve_window_kernel's rows ya..yb (one chunk of its parallel loop)."""
    h, w = depth1.shape
    w2 = w + 2
    w32 = I32(w)
    h32 = I32(h)
    hw32 = I32(h * w)
    nb = w // 16
    for y in range(ya, yb):
        # a row view: buf[r + x] with r of unknown sign (y runs from a chunk's bounds) keeps
        # numba's negative-index wraparound inside the loop, and LLVM made the loads gathers
        r = (y + 1) * w2 + 1
        br = buf[r:r + w]
        for x in range(w):
            _winner_px(br[x], x, y, JX, JY)
        for b in range(nb):
            fetch16x2(mv1, hw32, w32, h32, JX, JY, I32(16 * b), T, I32(0), w32)
            if quad:
                fetch16x2(disp, hw32, w32, h32, JX, JY, I32(16 * b), T, I32(2 * w), w32)
        for x in range(16 * nb, w):
            i = mad32(JY[x], w32, JX[x])
            T[0, x] = ld32(mv1, i)
            T[1, x] = ld32(mv1, mad32(hw32, I32(1), i))
            if quad:
                T[2, x] = ld32(disp, i)
                T[3, x] = ld32(disp, mad32(hw32, I32(1), i))
        if quad and w0:
            for x in range(w):
                _resolve_from(br[x], x, y, True, True, T, ca, w32, to1, to0, dout,
                              valid, source)
        elif quad:
            for x in range(w):
                _resolve_from(br[x], x, y, True, False, T, ca, w32, to1, to0, dout,
                              valid, source)
        elif w0:
            for x in range(w):
                _resolve_from(br[x], x, y, False, True, T, ca, w32, to1, to0, dout,
                              valid, source)
        else:
            for x in range(w):
                _resolve_from(br[x], x, y, False, False, T, ca, w32, to1, to0, dout,
                              valid, source)


@njit(**KERNEL)
def splat_resolve_window_kernel(buf, depth1, mv1, disp, ca, quad, w0, to1, to0, dout, valid,
                                source):
    """splat_resolve_pixels_kernel with the winners' vectors (and displacements) fetched
    16 target pixels at a time (fgcli.kernels._intrin.fetch16x2, AVX-512 only): per row,
    the sources into row buffers, the fetches, then the outputs. The same values."""
    h, w = depth1.shape
    nch = min(h, 64)
    for ch in prange(nch):
        ya = np.int64(ch) * h // nch
        yb = (np.int64(ch) + 1) * h // nch
        JX = np.empty(w, dtype=np.int32)
        JY = np.empty(w, dtype=np.int32)
        T = np.empty((4, w), dtype=np.float32)
        _splat_resolve_window_rows(ya, yb, buf, depth1, mv1, disp, ca, quad, w0, to1, to0, dout,
                                   valid, source, JX, JY, T)


# with AVX-512, the resolve's reads at the winners as 16-lane window fetches (numba's cache
# keys compiled code by CPU, so a cache never carries one machine's choice to another)
splat_resolve_kernel = splat_resolve_window_kernel if WINDOW16 else \
    splat_resolve_pixels_kernel
