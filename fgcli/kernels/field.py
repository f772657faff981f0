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

from fgcli.kernels._common import (F32, INLINE, KERNEL, ROWS, clamp_b, dealt, f2i64, sdepth_b,
                                   smv_b, step_code, step_codes, sval_b)
from fgcli.kernels._intrin import (HAVE_F16C, HAVE_WINDOW16, atomic_max_u32, bilinear16x1,
                                   fmin16x2, half_bits_f16c, ld32, mad32, run16, umax16x2)
from fgcli.kernels.pyramid import U0, U1, _pool_rows
from fgcli.kernels.warp import I32, _bil_pair, _flat_coords, bil_taps

_PRIMARY = np.uint32(1 << 31)
# the entries' bilinear luminance taps (_row_samples): 16 pixels per window fetch where the
# CPU has AVX-512 (fgcli.kernels._intrin; a module constant: numba's cache keys code by CPU)
WINDOW16 = HAVE_WINDOW16


@njit(**INLINE)
def _taps(px, py, h, w, thr):
    """The reference's _footprint for one position: base column/row in the (h+2) x (w+2)
    buffer (int32: the callers' buffers have fewer than 2**31 texels; half the vector
    lanes of int64, ~1 ms less per 1080p scatter) and the four taps' write flags (weight >
    thr), order (0,0), (1,0), (0,1), (1,1). (numba sums two int32 as int64: the outer I32
    keeps the callers' compares and products at 32 bits, 8 vector lanes on AVX2.)"""
    x = clamp_b(px, F32(-2.0), F32(w + 1.0))
    y = clamp_b(py, F32(-2.0), F32(h + 1.0))
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = x - x0
    fy = y - y0
    ex = F32(1.0) - fx
    ey = F32(1.0) - fy
    xa = I32(I32(clamp_b(x0, F32(-1.0), F32(w))) + I32(1))
    xb = I32(I32(clamp_b(x0 + F32(1.0), F32(-1.0), F32(w))) + I32(1))
    ya = I32(I32(clamp_b(y0, F32(-1.0), F32(h))) + I32(1))
    yb = I32(I32(clamp_b(y0 + F32(1.0), F32(-1.0), F32(h))) + I32(1))
    return xa, xb, ya, yb, ex * ey > thr, fx * ey > thr, ex * fy > thr, fx * fy > thr


@njit(**INLINE)
def _run_flags(q0, dx, dy, cont, m):
    """The footprint scatters' runs: cont[j] = 1 where source j + 1 continues source j's
    footprint one texel to the right (the same tap offsets, the next base texel), else 0
    (cont[m - 1] = 0). Sources j .. j + 15 are one run when run16(cont, j). (Slices: an
    index with a signed offset stops LLVM from vectorising the loop. A prefix count of run
    starts, int64, served the test before: its serial loop took ~0.9 ns a source, 1.85 ms
    per 1080p pass on one Zen 3 thread.)"""
    qa, qb = q0[1:m], q0[0:m - 1]
    xa_, xb_ = dx[1:m], dx[0:m - 1]
    ya_, yb_ = dy[1:m], dy[0:m - 1]
    c = cont[0:m - 1]
    for j in range(m - 1):
        c[j] = np.uint8((qa[j] == I32(qb[j] + I32(1))) & (xa_[j] == xb_[j])
                        & (ya_[j] == yb_[j]))
    if m > 0:
        cont[m - 1] = 0


@njit(**INLINE)
def _max4(buf, q, dx, dy, k0, k1, k2, k3):
    """One footprint's maxima: entries k0 .. k3 into its taps q, q + dx, q + dy,
    q + dy + dx of buf (q >= 0, dx and dy >= 0: unsigned indices, so numba leaves out its
    negative-index wraparound, three instructions a tap, as splat_kernel)."""
    q = np.uint64(q)
    q1 = q + np.uint64(dx)
    q2 = q + np.uint64(dy)
    q3 = q2 + np.uint64(dx)
    buf[q] = max(buf[q], k0)
    buf[q1] = max(buf[q1], k1)
    buf[q2] = max(buf[q2], k2)
    buf[q3] = max(buf[q3], k3)


@njit(**INLINE)
def _scatter_max(buf, px, py, ky, m, h, w, thr, q0, dx, dy, k0, k1, k2, k3, brk):
    """The footprint scatter of m sources (positions px, py, entries ky: arrays of at least
    m) into buf: their footprints in a vectorised pass into q0, dx, dy, k0 .. k3 (buffers
    of at least m), then the maxima, 16 sources per vector operation where they are one
    run (_run_flags), else one by one."""
    w2 = I32(w + 2)
    z = np.uint32(0)
    for j in range(m):
        xa, xb, ya, yb, t00, t10, t01, t11 = _taps(px[j], py[j], h, w, thr)
        a = ky[j]
        q0[j] = ya * w2 + xa
        dx[j] = xb - xa
        dy[j] = (yb - ya) * w2
        k0[j] = a if t00 else z  # entries are > 0: 0 never wins
        k1[j] = a if t10 else z
        k2[j] = a if t01 else z
        k3[j] = a if t11 else z
    _run_flags(q0, dx, dy, brk, m)
    j = 0
    while j < m:
        if j + 16 <= m and run16(brk, j):  # 16 sources, one run
            q = q0[j]
            umax16x2(buf, q, k0, k1, j, dx[j])  # (dx is 0 or 1: _taps' columns)
            umax16x2(buf, q + dy[j], k2, k3, j, dx[j])
            j += 16
        else:
            # (unsigned indices, all >= 0: no negative-index wraparound, as splat_kernel)
            _max4(buf, q0[j], dx[j], dy[j], k0[j], k1[j], k2[j], k3[j])
            j += 1


@njit(**INLINE)
def _bands(h):
    """The band height and count of the two-component scatters (field_scatter_prio_kernel,
    field_scatter_block_kernel): about 16 bands (at least 8 rows each), so a source whose
    footprint lands within half a band (34 rows at 1080p) of its own band is written in
    the parallel passes."""
    bh = max(8, (h + 15) // 16)
    return bh, (h + bh - 1) // bh


@njit(**INLINE)
def _zone(ya, yb, bh, w, nb):
    """The flat range [zlo, zhi) of a band of source rows ya .. yb - 1 (buffer rows carry
    the ring's +1) widened by half a band each way, clamped onto the buffer's nb texels
    (every index is in 0 .. nb - 1): the zones of bands that run together (every other
    band) do not overlap. int32 (nb < 2**31)."""
    half = bh // 2
    w2 = np.int64(w + 2)
    zlo = max(np.int64(0), (ya - half + 1) * w2)
    zhi = min(np.int64(nb), (yb + half + 1) * w2)
    return I32(zlo), I32(zhi)


@njit(**INLINE)
def _scatter_pair(buf0, buf1, px, py, ka, kb, m, h, w, thr, zlo, zhi, q0, dx, dy, tf, inz,
                  k0, k1, k2, k3, brk):
    """_scatter_max of m sources into both components' buffers (entries ka into buf0, kb
    into buf1), the footprints and runs worked out once for both, the sources whose
    footprint lies in the zone [zlo, zhi) (_zone: no other thread writes there
    meanwhile) alone: inz[j] = 1 for those. Returns the number of the others (the caller
    defers them to _scatter_one)."""
    w2 = I32(w + 2)
    z = np.uint32(0)
    nout = 0
    for j in range(m):
        xa, xb, ya, yb, t00, t10, t01, t11 = _taps(px[j], py[j], h, w, thr)
        q = I32(ya * w2 + xa)
        q0[j] = q
        dx[j] = xb - xa
        dy[j] = I32((yb - ya) * w2)
        tf[j] = I32(t00) | (I32(t10) << I32(1)) | (I32(t01) << I32(2)) | (I32(t11) << I32(3))
        ok = (q >= zlo) & (I32(yb * w2 + xb) < zhi)
        inz[j] = I32(ok)
        nout += np.int64(not ok)
    _run_flags(q0, dx, dy, brk, m)
    for c in range(2):
        buf = buf0 if c == 0 else buf1
        ky = ka if c == 0 else kb
        for j in range(m):
            a = ky[j]
            f = tf[j]
            k0[j] = a if (f & I32(1)) != I32(0) else z  # entries are > 0: 0 never wins
            k1[j] = a if (f & I32(2)) != I32(0) else z
            k2[j] = a if (f & I32(4)) != I32(0) else z
            k3[j] = a if (f & I32(8)) != I32(0) else z
        j = 0
        while j < m:
            # 16 sources, one run, in the zone (a run's texels are consecutive: its first
            # and last footprints bound the others')
            if j + 16 <= m and run16(brk, j) and (inz[j] & inz[j + 15]) != I32(0):
                q = q0[j]
                umax16x2(buf, q, k0, k1, j, dx[j])
                umax16x2(buf, q + dy[j], k2, k3, j, dx[j])
                j += 16
            else:
                if inz[j] != I32(0):
                    _max4(buf, q0[j], dx[j], dy[j], k0[j], k1[j], k2[j], k3[j])
                j += 1
    return nout


@njit(**INLINE)
def _defer_row(inz, y, w, dq, base, nd):
    """Append row y's sources outside the zone (inz[x] == 0) to dq at base + nd (flat
    source indices, int32); returns the new count."""
    for x in range(w):
        dq[base + nd] = I32(y * w + x)
        nd += np.int64(inz[x] == I32(0))
    return nd


@njit(**INLINE)
def _scatter_one(buf, px, py, a, h, w, thr):
    """One source's footprint maxima (entry a) into buf, plainly (the deferred sources:
    one component per thread)."""
    xa, xb, ya, yb, t00, t10, t01, t11 = _taps(px, py, h, w, thr)
    w2 = np.int64(w + 2)
    z = np.uint32(0)
    _max4(buf, ya * w2 + xa, xb - xa, (yb - ya) * w2, a if t00 else z, a if t10 else z,
          a if t01 else z, a if t11 else z)


_CHUNK = 2048  # sources per vectorised footprint pass


@njit(**KERNEL)
def field_scatter_kernel(pos, key0, key1, h, w, thr, buf0, buf1):
    """vector_field's primary scatter, one component per thread (prange over the two).
    pos (2, N) float32 footprint positions; key0, key1 (N,) uint32 primary entries of the
    components -> buf0, buf1 ((h+2)*(w+2),) uint32, zeroed here, the maximum entry written
    into each texel (the caller crops the ring). One buffer per component: below glibc's
    mmap threshold (fgcli.sysutil.tune_allocator), so a frame's buffers reuse the last
    frame's memory instead of faulting in fresh pages (a (2, N) pair did, about 5 ms each).
    The footprints are worked out in vectorised passes over chunks of sources (slices: an
    index with a signed offset stops LLVM from vectorising), then a plain loop takes the
    maxima, as unconditional stores of max(old, new) (uint32 entries and buffers, not the
    reference's int64: the packed entries are below 2**32, and with half the bytes and no
    data-dependent branches this loop took 8.6 ms against 10.0 per 1080p field). Where
    16 sources in a row continue each other's footprints one texel to the right (smooth
    motion: the same tap offsets, consecutive base texels) their four taps are four
    16-lane maxima (fgcli.kernels._intrin.umax16; max does not depend on the order of
    writes): ~20 % less time on the benchmark's scene, no change on footage with large,
    varied motion.

    Two kernels (this one, then field_walk_kernel), not two prange loops in one: numba
    fuses consecutive parallel loops of the same length, which would run a walk before
    the other component's primaries exist."""
    n = pos.shape[1]
    for pc in prange(2):
        c = np.int64(pc)
        buf = buf0 if c == 0 else buf1
        for q in range(buf.shape[0]):
            buf[q] = 0
        q0 = np.empty(_CHUNK, dtype=np.int32)
        dx = np.empty(_CHUNK, dtype=np.int32)
        dy = np.empty(_CHUNK, dtype=np.int32)
        k0 = np.empty(_CHUNK, dtype=np.uint32)
        k1 = np.empty(_CHUNK, dtype=np.uint32)
        k2 = np.empty(_CHUNK, dtype=np.uint32)
        k3 = np.empty(_CHUNK, dtype=np.uint32)
        brk = np.empty(_CHUNK, dtype=np.uint8)
        for s in range(0, n, _CHUNK):
            m = min(_CHUNK, n - s)
            _scatter_max(buf, pos[0, s:s + m], pos[1, s:s + m],
                         key0[s:s + m] if c == 0 else key1[s:s + m], m, h, w, thr, q0, dx, dy,
                         k0, k1, k2, k3, brk)


@njit(**INLINE)
def _walk(buf0, buf1, px, py, d0, d1, di, a0, a1, steps, w, h):
    """One source's secondary walk back from its footprint (vector_field's): at most
    ``steps`` unit steps (d0, d1) from (px, py) while the step is within its length di and
    it has hit at most 3 primary texels; its entries a0, a1 (below 2**31) into the padded
    fields buf0, buf1 ((h + 2) * (w + 2), flat) by atomic maxima. A texel holding a primary
    entry (2**31 and above) keeps it whatever is written there, so nothing is written
    there (on a moving camera ~95 % of the steps, the walk hitting the texels its
    neighbours' footprints cover); a texel's primary flag is the same in both fields (each
    source wrote both at the same taps with the same priority bits) and never changes
    during the walk (a secondary entry only replaces a smaller one), so the count is
    buf0's, read while other threads write. The maxima do not depend on the order of the
    writes: the serial walk's fields, whatever the threads."""
    w2 = w + 2
    hits = 0
    for k in range(1, steps + 1):
        if not (di >= F32(k)) or hits > 3:
            break
        kf = F32(k)
        qx = px - d0 * kf
        qy = py - d1 * kf
        xi = f2i64(clamp_b(np.floor(qx), F32(-1.0), F32(w))) + 1
        yi = f2i64(clamp_b(np.floor(qy), F32(-1.0), F32(h))) + 1
        if xi < 1 or xi > w or yi < 1 or yi > h:
            continue
        q = yi * w2 + xi
        if buf0[q] >= _PRIMARY:
            hits += 1
            continue
        if a0 > buf0[q]:  # (entries only grow: one read already at or above a0 is final)
            atomic_max_u32(buf0, q, a0)
        if a1 > buf1[q]:
            atomic_max_u32(buf1, q, a1)


@njit(**KERNEL)
def field_walk_kernel(pos, key0, key1, dist, d, h, w, steps, buf0, buf1):
    """vector_field's secondary walk after field_scatter_kernel, both components in one
    walk (_walk): dist (N,) float32 walk lengths, d (2, N) unit steps, at most ``steps``
    steps; sources in row order (N = h * w), rows dealt out to the threads in chunks."""
    nch = min(h, 64)
    for pch in prange(nch):
        ch = dealt(pch, nch)  # (each thread's chunks spread over the frame)
        for i in range(ch * h // nch * w, (ch + 1) * h // nch * w):
            di = dist[i]
            if di >= F32(1.0):
                _walk(buf0, buf1, pos[0, i], pos[1, i], d[0, i], d[1, i], di,
                      key0[i] - _PRIMARY, key1[i] - _PRIMARY, steps, w, h)


@njit(**KERNEL)
def depth_scatter_pair_kernel(depth, mv, lens, short, squared, ks, thr, out):
    """reconstruct_depths' two scatters with the sources computed in the kernel (the
    reference's depth_sources: sanitised depth, sanitised vector zeroed when its length
    is shorter than ``short``, position p + v * ks[t], each product and sum rounded on its
    own): depth (H, W), mv (2, H, W), ks (2,) float32 -> out (2, H, W) float32 (set to
    +inf here), the minimum depth written into each texel's footprint taps. The length
    test: ``squared``: the squared length (length_kernel's sum) >= short, a threshold
    that gives torch.sqrt's answer (fgcli.kernels.ops._sqrt_at_least); else lens (H, W)
    (torch.sqrt of length_kernel's squares, MKL's as the reference's) >= short.

    No off-screen ring (the reference's discard texels): an off-screen tap writes +inf
    into an on-screen texel (its coordinates clamped), which changes nothing, so the
    output needs no crop and copy (2 ms per 1080p pair).

    One target time per thread (prange over the two). Per row, the footprints are worked
    out in vectorised loops into row buffers, then a plain loop takes the minima: the
    float work no longer sits in the serial loop, and no torch pass runs in between
    (torch's idle OpenMP threads spin for a while after each op and slowed a second
    Python thread by half). 16 sources continuing each other's footprints one texel to
    the right (field_scatter_kernel's runs) take four 16-lane minima (fgcli.kernels.
    _intrin.fmin16; the sanitised depths hold no NaN, so the minimum is unique): 8.6 ->
    7.5 ms per 1080p pair on the benchmark's frames, in one process. A row whose vectors
    are all zero once the short ones are zeroed (the static parts of a frame) writes each
    source's depth into its own texel, no footprint worked out."""
    h, w = depth.shape
    h32 = I32(h)
    w32 = I32(w)
    inf = F32(np.inf)
    for pt in prange(2):
        t = np.int64(pt)
        bufs = out[t].reshape(h * w)
        for q in range(h * w):
            bufs[q] = inf
        k = ks[t]
        # a source on its own texel (zero vector, k finite: p + 0 k = p) writes that texel
        # alone: weight 1 there, 0 at the other three taps (for 0 <= thr < 1, the tap rule)
        own = (thr >= F32(0.0)) & (thr < F32(1.0)) & (abs(k) < inf)
        q0 = np.empty(w, dtype=np.int32)
        dx = np.empty(w, dtype=np.int32)
        dy = np.empty(w, dtype=np.int32)
        z0 = np.empty(w, dtype=np.float32)
        z1 = np.empty(w, dtype=np.float32)
        z2 = np.empty(w, dtype=np.float32)
        z3 = np.empty(w, dtype=np.float32)
        brk = np.empty(w, dtype=np.uint8)
        kp = np.empty(w, dtype=np.float32)
        for y in range(h):
            yf = F32(y)
            dr = depth[y]
            mx = mv[0, y]
            my = mv[1, y]
            if squared:
                for x in range(w):
                    vx = smv_b(mx[x])
                    vy = smv_b(my[x])
                    kp[x] = F32(1.0) if vx * vx + vy * vy >= short else F32(0.0)
            else:
                for x in range(w):
                    kp[x] = F32(1.0) if lens[y, x] >= short else F32(0.0)
            if own:
                moving = I32(0)
                for x in range(w):
                    moving |= I32((smv_b(mx[x]) * kp[x] != F32(0.0)) |
                                  (smv_b(my[x]) * kp[x] != F32(0.0)))
                if moving == 0:  # a row of zero (or zeroed short) vectors: own texels
                    r = y * w
                    for x in range(w):
                        bufs[r + x] = min(bufs[r + x], sdepth_b(dr[x]))
                    continue
            for x in range(w):
                vx = smv_b(mx[x])
                vy = smv_b(my[x])
                keep = kp[x]
                px = F32(I32(x)) + (vx * keep) * k
                py = yf + (vy * keep) * k
                xa, xb, ya, yb, t00, t10, t01, t11 = _taps(px, py, h, w, thr)
                z = sdepth_b(dr[x])
                # ring columns / rows (0, w + 1 / h + 1) are off-screen
                oxa = (xa >= I32(1)) & (xa <= w32)
                oxb = (xb >= I32(1)) & (xb <= w32)
                oya = (ya >= I32(1)) & (ya <= h32)
                oyb = (yb >= I32(1)) & (yb <= h32)
                ca = I32(min(max(xa, I32(1)), w32) - I32(1))
                cb = I32(min(max(xb, I32(1)), w32) - I32(1))
                ra = I32(min(max(ya, I32(1)), h32) - I32(1))
                rb = I32(min(max(yb, I32(1)), h32) - I32(1))
                q0[x] = ra * w32 + ca
                dx[x] = cb - ca
                dy[x] = (rb - ra) * w32
                z0[x] = z if t00 & oxa & oya else inf
                z1[x] = z if t10 & oxb & oya else inf
                z2[x] = z if t01 & oxa & oyb else inf
                z3[x] = z if t11 & oxb & oyb else inf
            _run_flags(q0, dx, dy, brk, w)  # 16 sources of one run: four 16-lane minima
            x = 0
            while x < w:
                if x + 16 <= w and run16(brk, x):
                    q = q0[x]
                    fmin16x2(bufs, q, z0, z1, x, dx[x])  # (dx is 0 or 1)
                    fmin16x2(bufs, q + dy[x], z2, z3, x, dx[x])
                    x += 16
                else:
                    q = np.uint64(q0[x])  # (unsigned: see _scatter_max)
                    q1 = q + np.uint64(dx[x])
                    q2 = q + np.uint64(dy[x])
                    q3 = q2 + np.uint64(dx[x])
                    bufs[q] = min(bufs[q], z0[x])
                    bufs[q1] = min(bufs[q1], z1[x])
                    bufs[q2] = min(bufs[q2], z2[x])
                    bufs[q3] = min(bufs[q3], z3[x])
                    x += 1


# ----------------------------------------------------------------------------- entries

_LR, _LG, _LB = F32(0.2126), F32(0.7152), F32(0.0722)  # fgcli.ops.color.REC709_LUMA


@njit(**INLINE)
def half_bits_int(v):
    """IEEE binary16 bits (round to nearest even) of a finite float32 within +-65504, as
    torch's ``.to(torch.float16).view(torch.int16) & 0xFFFF`` (checked against torch for
    every such float32), as an int32, in integer arithmetic (half_bits where the CPU has no
    F16C). numba has no float16 type. In 32-bit arithmetic: AVX2 has no float -> int64
    conversion, and with one LLVM kept the packing loops at four lanes with scalar
    conversions."""
    x = np.float32(v).view(np.int32)
    sign = np.int32((x >> 16) & 0x8000)
    a = np.int32(x & 0x7FFFFFFF)
    # a subnormal half (|v| < 2**-14) is the integer multiple of 2**-24, rounded to even
    # (below 1024; the clamp keeps the conversion in range where its result goes unused)
    sub = np.int32(np.rint(min(abs(v) * F32(16777216.0), F32(1024.0))))
    nrm = np.int32((a + np.int32(0xFFF) + ((a >> 13) & 1) - np.int32(0x38000000)) >> 13)
    return np.int32(sign | (sub if a < np.int32(0x38800000) else nrm))


@njit(**INLINE)
def _half_bits_f16c(v):
    """half_bits_int's value by the CPU's conversion (fgcli.kernels._intrin.half_bits_f16c);
    the packing of the field entries, ~0.4 ns per value in integer arithmetic, took ~1 ms
    of each 1080p scatter that way (Zen 3)."""
    return half_bits_f16c(np.float32(v))


# (a module constant: numba's cache keys compiled code by CPU)
half_bits = _half_bits_f16c if HAVE_F16C else half_bits_int


@njit(**INLINE)
def _lum(c, y, x):
    """luminance(sanitize_values(c)) at one pixel."""
    return (sval_b(c[0, y, x]) * _LR + sval_b(c[1, y, x]) * _LG) + sval_b(c[2, y, x]) * _LB


@njit(**INLINE)
def _pack(prio, comp):
    """pack_entries for one component: prio << 16 | half bits of the clamped component, as
    a uint32 (prio: 0 .. 65535; 32-bit arithmetic, see half_bits)."""
    c = clamp_b(comp, F32(-65504.0), F32(65504.0))
    return np.uint32(np.int32(prio << 16) | half_bits(c))


@njit(**INLINE)
def _depth_rank(dv, tab, b0, sh, n1, bottom):
    """fgcli.ops.fsr3.depth_priority of one depth: d = sanitize_depth(dv), then its table
    lookup (step_code: packed_steps(depth_priority_table), one int32 gather): 1023 - the
    step; depth 0 -> 1023. int32 arithmetic (d >= 0: its bits are too; step is 1..1023):
    16-lane gathers, and a float -> int32 conversion, which AVX2 has (float -> int64
    needs AVX-512; LLVM made the loop scalar for it: ~1.2x slower on Zen 3)."""
    v = sdepth_b(dv)
    return _rank_of(step_code(v, tab, b0, sh, n1, bottom), v > F32(0.0))


@njit(**INLINE)
def _rank_of(step, positive):
    """A depth's priority from its step-table code: 1023 - the step; 1023 where the depth
    is not positive (int32)."""
    return np.int32(1023) - (step if positive else np.int32(0))


@njit(**KERNEL)
def depth_rank_kernel(depth, tab, b0, sh, bottom, hi):
    """fgcli.ops.fsr3.depth_priority (_depth_rank): hi (H, W) int64."""
    h, w = hi.shape
    n1 = np.int32(tab.shape[0] - 1)
    for py in prange(h):
        y = np.int64(py)
        for x in range(w):
            hi[y, x] = np.int64(_depth_rank(depth[y, x], tab, b0, sh, n1, bottom))


@njit(**KERNEL)
def luma_plane_kernel(c, out):
    """out (H, W) = sanitize_values(luminance(sanitize_values(c))): the value the entries'
    bilinear read takes at each tap."""
    h, w = out.shape
    for py in prange(h):
        y = np.int64(py)
        for x in range(w):
            out[y, x] = sval_b(_lum(c, y, x))


@njit(**INLINE)
def _row_samples(l0, V0, V1, y, gxn, gyn, kx, ky, h, w, s0, ins, XA, XB, YA, YB, Z, WT):
    """s0[x] = frame 0's luminance l0 read bilinearly at (x, y) + (V0[x], V1[x])
    (sanitised vectors; grid_sample's arithmetic, zero vectors exact) and ins[x] = 1.0
    where that point is on screen, for the pixels of row y. XA .. WT: bil_taps' row
    buffers (the caller's: with the window fetches only)."""
    hw = F32(w * 0.5)
    hh = F32(h * 0.5)
    wm1 = F32(w - 1)
    hm1 = F32(h - 1)
    w32 = I32(w)
    h32 = I32(h)
    nb = w // 16 if WINDOW16 else 0  # pixels 0 .. 16 nb - 1 of a row: window fetches
    yf = F32(y)
    gyy = gyn[y]
    lo_y = F32(-0.5) - yf
    hi_y = F32(h - 0.5) - yf
    moving = I32(1)
    if WINDOW16:  # a row of zero vectors (static parts of a frame): its own pixels
        moving = I32(0)
        for x in range(w):
            moving |= I32((V0[x] != F32(0.0)) | (V1[x] != F32(0.0)))
        if moving == 0:
            for x in range(16 * nb):
                s0[x] = sval_b(l0[y, x])  # (what the fetch gives along zero vectors)
                ins[x] = F32(1.0)
    if WINDOW16 and moving != 0:  # the taps into row buffers (bil_taps), 16 pixels per fetch
        for x in range(w):
            vx = smv_b(V0[x])
            vy = smv_b(V1[x])
            xf = F32(I32(x))
            ins[x] = F32((vx >= F32(-0.5) - xf) & (vx < F32(w - 0.5) - xf) &
                         (vy >= lo_y) & (vy < hi_y))
            bil_taps(vx, vy, x, gxn[x], gyy, kx, ky, hw, hh, wm1, hm1, w32, h32, XA, XB,
                     YA, YB, WT, Z)
        for b in range(nb):
            bilinear16x1(l0, I32(0), w32, h32, XA, XB, YA, YB, WT, Z, I32(16 * b),
                         I32(y * w), s0, I32(0), I32(0))
    for x in range(16 * nb, w):
        vx = smv_b(V0[x])
        vy = smv_b(V1[x])
        xf = F32(I32(x))
        ins[x] = F32((vx >= F32(-0.5) - xf) & (vx < F32(w - 0.5) - xf) & (vy >= lo_y)
                     & (vy < hi_y))
        zero = (vx == F32(0.0)) & (vy == F32(0.0))
        # (pair loads: l0 is sanitised, so _bil_pair's sanitising changes nothing)
        p, rs, xi, nw, ne, sw, se = _flat_coords(vx, vy, gxn[x], gyy, kx, ky, hw, hh, wm1,
                                                 hm1, w32, h32)
        r = _bil_pair(l0, p, rs, xi, nw, ne, sw, se)
        s0[x] = l0[y, x] if zero else r


@njit(**INLINE)
def _agreement(a, b, inside):
    """agreement_priority of the samples a (frame 0) and b (frame 1), times inside: the
    5-bit lo of an entry (int64)."""
    a = (F32(0.0) if a < F32(0.0) else a) + F32(0.001)
    b = (F32(0.0) if b < F32(0.0) else b) + F32(0.001)
    r = (a if a < b else b) / (b if a < b else a)
    r = F32(1.0) if r != r else r
    lo = f2i64(clamp_b(np.rint(r * F32(31.0)), F32(0.0), F32(31.0)))
    return lo if inside != F32(0.0) else np.int64(0)


@njit(**INLINE)
def _prio(hv, lo):
    """An entry's 16-bit priority: primary flag | hi (clamped to 10 bits) | lo."""
    hv = 0 if hv < 0 else (1023 if hv > 1023 else hv)
    return (hv << 5) | lo | 32768


@njit(**ROWS)
def _agreement_block_rows(ya, yb, l0, c1, vec, sh, gxn, gyn, kx, ky, lo, V0, V1, XA, XB, YA, YB, Z,
                          WT, s0, ins):
    """agreement_block_kernel's rows ya..yb (one chunk of its parallel loop)."""
    h, w = lo.shape
    for y in range(ya, yb):
        by = y >> sh  # (the block row)
        for x in range(w):
            xb = np.int64(x) >> sh
            V0[x] = vec[0, by, xb]
            V1[x] = vec[1, by, xb]
        _row_samples(l0, V0, V1, y, gxn, gyn, kx, ky, h, w, s0, ins, XA, XB, YA, YB, Z, WT)
        for x in range(w):
            lo[y, x] = np.uint8(_agreement(s0[x], _lum(c1, y, x), ins[x]))


@njit(**KERNEL)
def agreement_block_kernel(l0, c1, vec, sh, gxn, gyn, kx, ky, lo):
    """The per-pixel part of the entries of a field whose vectors vec (2, ., .) are per
    block of 2**sh x 2**sh pixels (each pixel takes its block's): lo (H, W) uint8 = the
    5-bit agreement of frame 0's luminance l0 at p + v with frame 1's at p (0 where p + v
    is off screen). field_scatter_block_kernel makes the entries from it and the blocks'
    vectors and priorities as it scatters them: no frame-sized positions and entries (four
    planes, 33 MB at 1080p) written here and read back there."""
    h, w = lo.shape
    nch = min(h, 64)
    for pch in prange(nch):
        ch = dealt(pch, nch)  # (each thread's chunks spread over the frame)
        ya = ch * h // nch
        yb = (ch + 1) * h // nch
        V0 = np.empty(w, dtype=np.float32)
        V1 = np.empty(w, dtype=np.float32)
        XA = np.empty(w, dtype=np.int32)
        XB = np.empty(w, dtype=np.int32)
        YA = np.empty(w, dtype=np.int32)
        YB = np.empty(w, dtype=np.int32)
        Z = np.empty(w, dtype=np.int32)
        WT = np.empty((4, w), dtype=np.float32)
        s0 = np.empty(w, dtype=np.float32)
        ins = np.empty(w, dtype=np.float32)
        _agreement_block_rows(ya, yb, l0, c1, vec, sh, gxn, gyn, kx, ky, lo, V0, V1, XA, XB, YA,
                              YB, Z, WT, s0, ins)


@njit(**KERNEL)
def field_scatter_block_kernel(vec, hi, sh, lo, a1, thr, buf0, buf1):
    """field_scatter_kernel for a field of block vectors (agreement_block_kernel's): each
    row's sources are made into row buffers as field_scatter_prio_kernel makes them from
    the upsampled blocks (the block's sanitised vector and priority, the pixel's agreement
    lo (H, W) uint8, positions p + a1 v), then scattered into both components' buffers
    (_scatter_pair), in bands as field_scatter_prio_kernel's. A row of blocks' vectors,
    priorities and column positions are made once per band."""
    h, w = lo.shape
    nb = buf0.shape[0]
    for i in prange(nb):
        buf0[i] = 0
        buf1[i] = 0
    bh, nband = _bands(h)
    dq = np.empty(h * w, dtype=np.int32)
    ndef = np.zeros(nband, dtype=np.int64)
    # a source at its own texel (zero vector) writes that texel alone: weight 1 there,
    # 0 at the other three taps (for 0 <= thr < 1, the reference's tap rule)
    own = (thr >= F32(0.0)) & (thr < F32(1.0))
    for phase in range(2):
        for bi in prange((nband - phase + 1) // 2):
            band = 2 * np.int64(bi) + phase
            ya = band * bh
            yb = min(h, ya + bh)
            zlo, zhi = _zone(ya, yb, bh, w, nb)
            PX = np.empty(w, dtype=np.float32)
            PY = np.empty(w, dtype=np.float32)
            KA = np.empty(w, dtype=np.uint32)
            KB = np.empty(w, dtype=np.uint32)
            V0 = np.empty(w, dtype=np.float32)
            V1 = np.empty(w, dtype=np.float32)
            HR = np.empty(w, dtype=np.int32)  # (32-bit packing: see half_bits)
            q0 = np.empty(w, dtype=np.int32)
            dx = np.empty(w, dtype=np.int32)
            dy = np.empty(w, dtype=np.int32)
            tf = np.empty(w, dtype=np.int32)
            inz = np.empty(w, dtype=np.int32)
            k0 = np.empty(w, dtype=np.uint32)
            k1 = np.empty(w, dtype=np.uint32)
            k2 = np.empty(w, dtype=np.uint32)
            k3 = np.empty(w, dtype=np.uint32)
            brk = np.empty(w, dtype=np.uint8)
            still = False
            nd = np.int64(0)
            for y in range(ya, yb):
                by = y >> sh
                if y == ya or by != (y - 1) >> sh:  # a new row of blocks: its sources' values
                    moving = I32(0)
                    for x in range(w):
                        xb = np.int64(x) >> sh
                        V0[x] = smv_b(vec[0, by, xb])
                        V1[x] = smv_b(vec[1, by, xb])
                        HR[x] = np.int32(_prio(hi[by, xb], np.int64(0)))
                        moving |= I32((V0[x] != F32(0.0)) | (V1[x] != F32(0.0)))
                    for x in range(w):
                        PX[x] = F32(I32(x)) + V0[x] * a1
                    still = own & (moving == 0)
                if still:  # a row of blocks with zero vectors: each source at its own texel
                    r = (y + 1) * (w + 2) + 1
                    ra = buf0[r:r + w]
                    rb = buf1[r:r + w]
                    for x in range(w):
                        e = HR[x] | np.int32(lo[y, x])
                        ra[x] = max(ra[x], _pack(e, V0[x]))
                        rb[x] = max(rb[x], _pack(e, V1[x]))
                    continue
                yf = F32(y)
                for x in range(w):
                    e = HR[x] | np.int32(lo[y, x])
                    KA[x] = _pack(e, V0[x])
                    KB[x] = _pack(e, V1[x])
                    PY[x] = yf + V1[x] * a1
                if _scatter_pair(buf0, buf1, PX, PY, KA, KB, w, h, w, thr, zlo, zhi, q0, dx,
                                 dy, tf, inz, k0, k1, k2, k3, brk) > 0:
                    nd = _defer_row(inz, y, w, dq, ya * w, nd)
            ndef[band] = nd
    for pc in prange(2):
        c = np.int64(pc)
        buf = buf0 if c == 0 else buf1
        for band in range(nband):
            base = band * bh * w
            for k in range(ndef[band]):
                i = np.int64(dq[base + k])
                y = i // w
                x = i - y * w
                by = y >> sh
                xb = np.int64(x) >> sh
                v0 = smv_b(vec[0, by, xb])
                v1 = smv_b(vec[1, by, xb])
                e = np.int32(_prio(hi[by, xb], np.int64(0))) | np.int32(lo[y, x])
                _scatter_one(buf, F32(I32(x)) + v0 * a1, F32(y) + v1 * a1,
                             _pack(e, v0 if c == 0 else v1), h, w, thr)


@njit(**ROWS)
def _entries_prio_rows(ya, yb, l0, c1, vec, hi, a1, gxn, gyn, kx, ky, prio, sec, dist, XA, XB, YA,
                       YB, Z, WT, s0, ins, depth, tab, b0, sh, bottom, tw, cnt, B, I, E):
    """entries_prio_kernel's rows ya..yb (one chunk of its parallel loop)."""
    h, w = prio.shape
    fromd = depth.shape[0] > 0
    n1 = np.int32(tab.shape[0] - 1)
    for y in range(ya, yb):
        _row_samples(l0, vec[0, y], vec[1, y], y, gxn, gyn, kx, ky, h, w, s0, ins, XA, XB, YA,
                     YB, Z, WT)
        if fromd:  # the priorities from the depths as they go (no int64 plane)
            # (_depth_rank a row at a time: the table's lookups by 16-lane gathers)
            for x in range(w):
                B[x] = F32(sdepth_b(depth[y, x])).view(np.int32)
            step_codes(B, w, tab, b0, sh, n1, bottom, I, E)
            for x in range(w):
                hv = np.int64(_rank_of(E[x], B[x] > np.int32(0)))
                prio[y, x] = np.uint16(_prio(hv, _agreement(s0[x], _lum(c1, y, x), ins[x])))
        else:
            for x in range(w):
                prio[y, x] = np.uint16(_prio(hi[y, x], _agreement(s0[x], _lum(c1, y, x),
                                                                  ins[x])))
        if sec:  # the squared lengths of the secondary walk (torch takes the sqrt)
            n = 0
            for x in range(w):
                t0 = smv_b(vec[0, y, x]) * a1
                t1 = smv_b(vec[1, y, x]) * a1
                d2 = t0 * t0 + t1 * t1
                dist[y, x] = d2
                n += np.int64(d2 >= tw)
            cnt[y] = n


@njit(**KERNEL)
def entries_prio_kernel(l0, c1, vec, hi, a1, gxn, gyn, kx, ky, prio, sec, dist, depth, tab, b0,
                        sh, bottom, tw, cnt):
    """fgcli.ops.fsr3.field_entries' per-pixel part (l0: luma_plane_kernel's plane of
    frame 0, so a tap is one gather, not three; C-contiguous, flat_ok(h, w, 1): the taps
    are pair loads): frame 0's luminance read bilinearly at p + v (grid_sample's
    arithmetic, on-screen test; 16 pixels per window fetch where the CPU has AVX-512:
    WINDOW16), its 5-bit agreement with frame 1's luminance at p, and prio (H, W) uint16 =
    the 16-bit priority (primary flag | hi clamped to 10 bits | agreement). hi (H, W)
    int64, or with depth (H, W) (not empty: hi is not read) depth_rank_kernel's values
    made here (tab, b0, sh, bottom: packed_steps(depth_priority_table); the game field's,
    without a 16 MB int64 plane written and read back per 1080p frame). With ``sec``:
    dist (H, W) = the squared length of (1 - alpha) v (the reference's products and sum),
    and cnt (H,) the number in each row at or above tw (float32: those whose torch.sqrt
    reaches 1, the pixels that walk); the caller takes torch.sqrt of those (MKL's, not
    IEEE's: fgcli.kernels.geom; walk_sources_kernel).

    The positions and packed entries are not written here: field_scatter_prio_kernel and
    field_walk_prio_kernel make them from the vectors and prio as they go (2 bytes per
    pixel written here, not 16 of positions and entries, read back by both threads of the
    scatter and by the walk; with the walk's unit steps no longer stored either, the game
    field went from 21.1 to 19.7 ms median per 1080p frame, old and new code in one process
    with the CLI's allocator settings)."""
    h, w = prio.shape
    nch = min(h, 64)
    for pch in prange(nch):
        ch = dealt(pch, nch)  # (each thread's chunks spread over the frame)
        ya = ch * h // nch
        yb = (ch + 1) * h // nch
        XA = np.empty(w, dtype=np.int32)
        XB = np.empty(w, dtype=np.int32)
        YA = np.empty(w, dtype=np.int32)
        YB = np.empty(w, dtype=np.int32)
        Z = np.empty(w, dtype=np.int32)
        WT = np.empty((4, w), dtype=np.float32)
        s0 = np.empty(w, dtype=np.float32)
        ins = np.empty(w, dtype=np.float32)
        B = np.empty(w, dtype=np.int32)  # (the depth ranks' row buffers: step_codes)
        I = np.empty(w, dtype=np.int32)
        E = np.empty(w, dtype=np.int32)
        _entries_prio_rows(ya, yb, l0, c1, vec, hi, a1, gxn, gyn, kx, ky, prio, sec, dist, XA, XB,
                           YA, YB, Z, WT, s0, ins, depth, tab, b0, sh, bottom, tw, cnt, B, I, E)


@njit(**KERNEL)
def walk_sources_kernel(dist, tw, start, vals):
    """The squared lengths at or above tw (entries_prio_kernel's walking pixels) listed in
    row order into vals (float32): row y's from start[y] (the prefix sums of its cnt), for
    torch.sqrt of those alone (a few percent of the frame on a still camera) instead of
    the whole plane; walk_back_kernel puts the roots back."""
    h, w = dist.shape
    for py in prange(h):
        y = np.int64(py)
        k = start[y]
        if start[y + 1] == k:
            continue
        for x in range(w):
            if dist[y, x] >= tw:
                vals[k] = dist[y, x]
                k += 1


@njit(**KERNEL)
def walk_back_kernel(dist, tw, start, vals, rmax):
    """walk_sources_kernel's values (their roots by now) back into dist at the pixels they
    came from (the same scan: dist at or above tw, row order) and each row's largest in
    rmax (h,) (0 where none; the roots are finite: lengths of sanitised vectors). A scatter
    by a list of flat indices (numpy's fancy assignment) took ~3 ms per 1080p frame with
    the camera moving, where nearly every pixel walks."""
    h, w = dist.shape
    for py in prange(h):
        y = np.int64(py)
        k = start[y]
        m = F32(0.0)
        if start[y + 1] != k:
            for x in range(w):
                if dist[y, x] >= tw:
                    v = vals[k]
                    dist[y, x] = v
                    m = v if v > m else m
                    k += 1
        rmax[y] = m


@njit(**KERNEL)
def field_scatter_prio_kernel(vec, prio, a1, thr, buf0, buf1):
    """field_scatter_kernel of entries_prio_kernel's sources: each row's positions
    p + a1 v (a1 = 1 - alpha) and packed entries (prio << 16 | half bits of the sanitised
    component, the reference's pack_entries) made into row buffers, then scattered into
    both components' buffers at once (_scatter_pair: one footprint per source).

    Bands of source rows (_bands), every other band in parallel, then the rest: a band
    writes the sources whose footprint lies within its zone (_zone; zones of bands that run
    together do not overlap), and defers the others to a last pass, one component per
    thread (_scatter_one). The maximum does not depend on the order of writes, so the
    result is the same. (One component per thread over the whole frame worked out every
    footprint twice and used two threads at most.) A row of zero
    vectors (the static parts of a frame) writes each source into its own texel, as
    field_scatter_block_kernel's rows of still blocks."""
    h, w = prio.shape
    nb = buf0.shape[0]
    for i in prange(nb):
        buf0[i] = 0
        buf1[i] = 0
    # (field_scatter_block_kernel's rule for a source on its own texel, a1 finite)
    own = (thr >= F32(0.0)) & (thr < F32(1.0)) & (abs(a1) < F32(np.inf))
    bh, nband = _bands(h)
    dq = np.empty(h * w, dtype=np.int32)  # the deferred sources, band b's from b * bh * w
    ndef = np.zeros(nband, dtype=np.int64)
    for phase in range(2):
        for bi in prange((nband - phase + 1) // 2):
            band = 2 * np.int64(bi) + phase
            ya = band * bh
            yb = min(h, ya + bh)
            zlo, zhi = _zone(ya, yb, bh, w, nb)
            PX = np.empty(w, dtype=np.float32)
            PY = np.empty(w, dtype=np.float32)
            KA = np.empty(w, dtype=np.uint32)
            KB = np.empty(w, dtype=np.uint32)
            q0 = np.empty(w, dtype=np.int32)
            dx = np.empty(w, dtype=np.int32)
            dy = np.empty(w, dtype=np.int32)
            tf = np.empty(w, dtype=np.int32)
            inz = np.empty(w, dtype=np.int32)
            k0 = np.empty(w, dtype=np.uint32)
            k1 = np.empty(w, dtype=np.uint32)
            k2 = np.empty(w, dtype=np.uint32)
            k3 = np.empty(w, dtype=np.uint32)
            brk = np.empty(w, dtype=np.uint8)
            nd = np.int64(0)
            for y in range(ya, yb):
                yf = F32(y)
                moving = I32(0)
                for x in range(w):
                    pr = np.int32(prio[y, x])
                    v0 = smv_b(vec[0, y, x])
                    v1 = smv_b(vec[1, y, x])
                    KA[x] = _pack(pr, v0)
                    KB[x] = _pack(pr, v1)
                    PX[x] = F32(I32(x)) + v0 * a1
                    PY[x] = yf + v1 * a1
                    moving |= I32((v0 != F32(0.0)) | (v1 != F32(0.0)))
                if own and moving == 0:  # a row of zero vectors: each source at its own texel
                    r = (y + 1) * (w + 2) + 1
                    ra = buf0[r:r + w]
                    rb = buf1[r:r + w]
                    for x in range(w):
                        ra[x] = max(ra[x], KA[x])
                        rb[x] = max(rb[x], KB[x])
                    continue
                if _scatter_pair(buf0, buf1, PX, PY, KA, KB, w, h, w, thr, zlo, zhi, q0, dx,
                                 dy, tf, inz, k0, k1, k2, k3, brk) > 0:
                    nd = _defer_row(inz, y, w, dq, ya * w, nd)
            ndef[band] = nd
    for pc in prange(2):
        c = np.int64(pc)
        buf = buf0 if c == 0 else buf1
        for band in range(nband):
            base = band * bh * w
            for k in range(ndef[band]):
                i = np.int64(dq[base + k])
                y = i // w
                x = i - y * w
                v0 = smv_b(vec[0, y, x])
                v1 = smv_b(vec[1, y, x])
                _scatter_one(buf, F32(I32(x)) + v0 * a1, F32(y) + v1 * a1,
                             _pack(np.int32(prio[y, x]), v0 if c == 0 else v1), h, w, thr)


@njit(**INLINE)
def _walk_texel(px, py, d0, d1, kf, w32, h32, w2):
    """Step kf of a walk (_walk's texel): (1 when it is on the frame else 0, its flat index
    in the padded field, clamped onto it either way), int32 (_pixel_field checks that the
    padded field's indices fit). _walk spells the same rule in int64 (the general path's
    frames need not fit int32); written through this helper there, the walk took 1.06x
    as long on blade (kernels A/B, captured 1080p inputs, Zen 3); the kernel tests hold
    both to the reference's fields."""
    xi = I32(clamp_b(np.floor(px - d0 * kf), F32(-1.0), F32(w32))) + I32(1)
    yi = I32(clamp_b(np.floor(py - d1 * kf), F32(-1.0), F32(h32))) + I32(1)
    on = (xi >= I32(1)) & (xi <= w32) & (yi >= I32(1)) & (yi <= h32)
    return I32(on), mad32(yi, w2, xi)


@njit(**INLINE)
def _walk_pixel(vec, prio, di, x, y, a1, steps, buf0, buf1):
    """_walk of pixel (x, y) of entries_prio_kernel's sources (walk length di >= 1): its
    position p + a1 v, unit step (the reference's sanitize_mv(v) / dist.clamp(min=1e-6))
    and entries made here."""
    h, w = prio.shape
    vx = smv_b(vec[0, y, x])
    vy = smv_b(vec[1, y, x])
    cl = F32(1e-6) if di < F32(1e-6) else di
    pr = np.int64(prio[y, x])
    _walk(buf0, buf1, F32(I32(x)) + vx * a1, F32(y) + vy * a1, vx / cl, vy / cl, di,
          np.uint32(_pack(pr, vx)) - _PRIMARY, np.uint32(_pack(pr, vy)) - _PRIMARY, steps, w, h)


@njit(**ROWS)
def _walk_prio_rows(ya, yb, vec, prio, dist, cnt, a1, steps, buf0, buf1, done, Q):
    """field_walk_prio_kernel's rows ya..yb, with the chunk's row buffers done (W,) and Q
    (4, W) int32. In a row where at least a quarter of the pixels walk (a moving camera:
    all of them) the walks that end at their fourth step having hit a primary texel at
    each are found first and skipped: they write nothing (_walk). On a moving camera that
    is most of them (the texels behind a source are its neighbours' footprints; 93 % on
    the orbit scene at 1080p). Their first four texels in a vectorised loop, then the
    four reads in a scalar one (LLVM does not gather on Zen 3: a loop with the reads left
    every step scalar), then the other walks as before."""
    h, w = prio.shape
    w32 = I32(w)
    h32 = I32(h)
    w2 = I32(w + 2)
    for y in range(ya, yb):
        yf = F32(y)
        dr = dist[y]
        n = cnt[y]
        if n == 0:
            continue
        quick = steps >= 4 and 4 * n >= w
        if quick:
            for x in range(w):
                di = dr[x]
                vx = smv_b(vec[0, y, x])
                vy = smv_b(vec[1, y, x])
                cl = F32(1e-6) if di < F32(1e-6) else di
                px = F32(I32(x)) + vx * a1
                py = yf + vy * a1
                d0 = vx / cl
                d1 = vy / cl
                o1, q1 = _walk_texel(px, py, d0, d1, F32(1.0), w32, h32, w2)
                o2, q2 = _walk_texel(px, py, d0, d1, F32(2.0), w32, h32, w2)
                o3, q3 = _walk_texel(px, py, d0, d1, F32(3.0), w32, h32, w2)
                o4, q4 = _walk_texel(px, py, d0, d1, F32(4.0), w32, h32, w2)
                done[x] = I32(di >= F32(4.0)) & o1 & o2 & o3 & o4
                Q[0, x] = q1
                Q[1, x] = q2
                Q[2, x] = q3
                Q[3, x] = q4
            for x in range(w):
                if done[x] != 0:
                    p = (ld32(buf0, Q[0, x]) & ld32(buf0, Q[1, x]) & ld32(buf0, Q[2, x])
                         & ld32(buf0, Q[3, x]))
                    done[x] = I32(p >> np.uint32(31))  # (all four primary: 2**31 and above)
            for x in range(w):
                if dr[x] >= F32(1.0) and done[x] == 0:
                    _walk_pixel(vec, prio, dr[x], x, y, a1, steps, buf0, buf1)
        else:
            for x in range(w):
                if dr[x] >= F32(1.0):
                    _walk_pixel(vec, prio, dr[x], x, y, a1, steps, buf0, buf1)


@njit(**KERNEL)
def field_walk_prio_kernel(vec, prio, dist, cnt, a1, steps, buf0, buf1):
    """field_walk_kernel of entries_prio_kernel's sources (dist (H, W): the walk lengths,
    torch.sqrt of its squares; cnt (H,) int64: the pixels of each row that walk, or more
    (none: the row is skipped; a quarter of the row or more: the quick pass)): a walking
    pixel's position, entries and unit step (the reference's sanitize_mv(v) /
    dist.clamp(min=1e-6)) made as it starts (_walk_pixel), walks that would write nothing
    found first (_walk_prio_rows)."""
    h, w = prio.shape
    nch = min(h, 64)
    for pch in prange(nch):
        ch = dealt(pch, nch)  # (each thread's chunks spread over the frame)
        done = np.empty(w, dtype=np.int32)
        Q = np.empty((4, w), dtype=np.int32)
        _walk_prio_rows(ch * h // nch, (ch + 1) * h // nch, vec, prio, dist, cnt, a1, steps,
                        buf0, buf1, done, Q)


@njit(**KERNEL)
def length_kernel(mv, ss):
    """ss (H, W) = the squared length of sanitize_mv(mv) (the reference's _length before
    its torch.sqrt)."""
    h, w = ss.shape
    for py in prange(h):
        y = np.int64(py)
        for x in range(w):
            vx = smv_b(mv[0, y, x])
            vy = smv_b(mv[1, y, x])
            ss[y, x] = vx * vx + vy * vy


@njit(**INLINE)
def half_value(b):
    """The float32 value of binary16 bits b (0..0xFFFF), then NaN -> 0 and +-inf ->
    +-65504 (unpack_vector_field's nan_to_num); exact, as torch's conversion."""
    # (fields re-typed int32: numba computes integer operations in int64, and the unpacking
    # loops ran on 64-bit lanes)
    b = I32(b)
    sign = I32((b >> 15) & 1)
    e = I32((b >> 10) & 0x1F)
    m = I32(b & 0x3FF)
    sub = F32(m) * F32(5.960464477539063e-08)  # m * 2**-24, exact
    nrm = np.int32(((e + 112) << 23) | (m << 13)).view(np.float32)
    v = sub if e == I32(0) else nrm
    v = F32(65504.0) if e == I32(31) else v
    v = -v if sign == I32(1) else v
    return F32(0.0) if (e == I32(31)) & (m != I32(0)) else v


@njit(**KERNEL)
def field_fill_prep_kernel(field, o, out, hout, valid, lev1, nh):
    """fill_packed_field's unpacking and inpaint_prep_kernel's dense part in one pass:
    field (2, H, W) int64 or uint32 packed entries (o = 1: the scatter's padded buffer
    (2, H + 2, W + 2), read inside its ring) -> out (2, H, W) = unpack_vector_field's
    vectors (finite: already sanitised), valid (H, W) uint8 = written, hout = its
    negation (the holes), lev1 (3, h2, w2) = the pooled [v * w, w] with w =
    fill_vector_field's weight float32(prio) / 65535 (0 at holes), nh (h2,) the holes of
    each pair of rows. The unpacked planes, the weight and the separate passes over them
    (unpack, weight, dense part: ~110 MB at 1080p) are never made."""
    h, w = hout.shape
    h2 = lev1.shape[1]
    w2 = I32(w + 2 * o)
    plane = I32((h + 2 * o) * (w + 2 * o))
    for pq in prange(h2):
        q = np.int64(pq)
        y0 = 2 * q
        nr = 2 if y0 + 1 < h else 1
        wr = np.empty((2, w), dtype=np.float32)
        pr = np.empty((2, w), dtype=np.float32)
        n = 0
        for r in range(nr):
            y = y0 + r
            b = mad32(y + o, w2, I32(o))
            for x in range(w):
                i = mad32(I32(x), I32(1), b)
                f0 = ld32(field, i)
                f1 = ld32(field, mad32(plane, I32(1), i))
                p = I32((f1 >> 16) & 0xFFFF)
                ok = p > I32(0)
                m = F32(ok)
                out[0, y, x] = half_value(f0 & 0xFFFF) * m
                out[1, y, x] = half_value(f1 & 0xFFFF) * m
                valid[y, x] = U1 if ok else U0
                hout[y, x] = U0 if ok else U1
                wr[r, x] = (F32(p) / F32(65535.0)) * m
            for x in range(w):
                n += np.int64(hout[y, x])
        nh[q] = n
        for k in range(3):
            for r in range(nr):
                y = y0 + r
                if k < 2:
                    for x in range(w):
                        pr[r, x] = out[k, y, x] * wr[r, x]
                else:
                    for x in range(w):
                        pr[r, x] = wr[r, x]
            _pool_rows(pr, nr, w, lev1, k, q)
