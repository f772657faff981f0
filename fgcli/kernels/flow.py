"""FfxOpticalFlow-style block search (fgcli.ops.fsr3._block_level, integer vectors) as a
numba kernel: per block, the sum of absolute differences for every offset of the search
window over a per-block copy of the window (edge-replicated), with the reference's tie
rule. The sums are of 8-bit differences (at most 255 * block * block, far below 2**24), so
float32 holds every partial sum exactly and any summation order gives the same integer:
the kernel sums in float32 with reassociation allowed (``fastmath={"reassoc", "nsz"}``,
which lets LLVM vectorise the reduction 16 lanes wide; 1.5-1.7x over int64 sums, the
width numba widens integer arithmetic to). The result is identical to the torch
reference, not merely close."""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from fgcli.kernels._common import F32, INLINE, KERNEL, ROWS, step_codes
from fgcli.kernels._intrin import sad_search8
from fgcli.kernels.field import _lum

I64_MAX = np.int64((1 << 63) - 1)
# exact for sums of integers below 2**24 (see the module docstring); nothing else here
# is a float operation whose result could depend on the flags
SAD_MATH = {"reassoc", "nsz"}


@njit(inline="always", cache=True, fastmath=SAD_MATH)
def _sad8(wb, cb, dy, dx):
    """SAD of the 8x8 block cb against the window at (dy, dx): constant trip counts, so
    LLVM unrolls and vectorises the 64 differences and their sum."""
    s = F32(0.0)
    for r in range(8):
        for c in range(8):
            s += abs(wb[r + dy, c + dx] - cb[r, c])
    return s


@njit(inline="always", cache=True, fastmath=SAD_MATH)
def _sads16(wb, cb, dy):
    """The 16 SADs of the 8x8 block cb against the window row offset dy, dx = 0..15 (FSR 3's
    block and search sizes): one accumulator per dx, each window element loaded once per
    (r, c) for all sixteen, which LLVM packs into one 512-bit register. Written out: an
    accumulator array lives in memory and was no faster than _sad8 per offset; the
    sixteen named sums are 1.35x faster (equal vectors)."""
    a0 = a1 = a2 = a3 = a4 = a5 = a6 = a7 = F32(0.0)
    a8 = a9 = a10 = a11 = a12 = a13 = a14 = a15 = F32(0.0)
    for r in range(8):
        row = r + dy
        for c in range(8):
            v = cb[r, c]
            a0 += abs(wb[row, c] - v)
            a1 += abs(wb[row, c + 1] - v)
            a2 += abs(wb[row, c + 2] - v)
            a3 += abs(wb[row, c + 3] - v)
            a4 += abs(wb[row, c + 4] - v)
            a5 += abs(wb[row, c + 5] - v)
            a6 += abs(wb[row, c + 6] - v)
            a7 += abs(wb[row, c + 7] - v)
            a8 += abs(wb[row, c + 8] - v)
            a9 += abs(wb[row, c + 9] - v)
            a10 += abs(wb[row, c + 10] - v)
            a11 += abs(wb[row, c + 11] - v)
            a12 += abs(wb[row, c + 12] - v)
            a13 += abs(wb[row, c + 13] - v)
            a14 += abs(wb[row, c + 14] - v)
            a15 += abs(wb[row, c + 15] - v)
    return (a0, a1, a2, a3, a4, a5, a6, a7, a8, a9, a10, a11, a12, a13, a14, a15)


@njit(inline="always", cache=True)
def _block_window(cur, prev, oy, ox, py, px, block, search, cb, cst, wb, wst):
    """Copy block (oy, ox) of cur into cb (row r at cst * r, flat) and the search window
    of prev around its predicted position (oy + py, ox + px) into wb (row r at wst * r),
    edge-replicated; the arrays' element types convert (the float kernel's buffers are
    float32, the mpsadbw kernel's uint8)."""
    h, w = cur.shape
    win = block + 2 * search - 1
    for r in range(block):
        yy = min(oy + r, h - 1)
        for c in range(block):
            cb[cst * r + c] = cur[yy, min(ox + c, w - 1)]
    x0 = ox + px - search
    if x0 >= 0 and x0 + win <= w:  # inside: no clamping per element
        for r in range(win):
            yy = min(max(oy + py - search + r, 0), h - 1)
            for c in range(win):
                wb[wst * r + c] = prev[yy, x0 + c]
    else:
        for r in range(win):
            yy = min(max(oy + py - search + r, 0), h - 1)
            for c in range(win):
                wb[wst * r + c] = prev[yy, min(max(x0 + c, 0), w - 1)]


@njit(inline="always", cache=True)
def _argmin16(sads, dy, best, bi, bj):
    """The reference's tie rule over one window row's sixteen offsets (sads, dx = 0..15, at
    row dy of the 8x8 / -8..7 search): the least ``SAD * 64 + |dx - 8| + |dy - 8|``, the
    first in (dy, dx) order on ties; returns the running (best, bi, bj)."""
    ody = abs(dy - 8)
    for dx in range(16):
        key = np.int64(sads[dx]) * 64 + (abs(dx - 8) + ody)
        if key < best:
            best = key
            bi = dy
            bj = dx
    return best, bi, bj


@njit(**dict(KERNEL, fastmath=SAD_MATH))
def block_search_kernel(cur, prev, pred, block, search, out):
    """cur, prev (h, w) int32 8-bit luminances (frame 1, frame 0); pred (2, nby, nbx) int64
    predicted vectors -> out (2, nby, nbx) int64: pred + the offset in -search..search-1
    (per axis) whose SAD of the block against prev is least; ties to the smallest
    |offset| sum, then the first offset in (dy, dx) order (the reference's argmin of
    ``SAD * 64 + |dx| + |dy|``)."""
    nby = pred.shape[1]
    nbx = pred.shape[2]
    n_off = 2 * search
    win = block + n_off - 1
    for pby in prange(nby):
        by = np.int64(pby)  # prange indices are unsigned: keep index arithmetic signed
        cb = np.empty((block, block), dtype=np.float32)
        wb = np.empty((win, win), dtype=np.float32)
        for bx in range(nbx):
            oy = by * block
            ox = bx * block
            py = pred[1, by, bx]
            px = pred[0, by, bx]
            _block_window(cur, prev, oy, ox, py, px, block, search, cb.reshape(-1), block,
                          wb.reshape(-1), win)
            best = I64_MAX
            bi = 0
            bj = 0
            if block == 8 and search == 8:  # FSR 3's sizes: sixteen offsets at a time
                for dy in range(16):
                    best, bi, bj = _argmin16(_sads16(wb, cb, dy), dy, best, bi, bj)
                out[0, by, bx] = px + bj - search
                out[1, by, bx] = py + bi - search
                continue
            for dy in range(n_off):
                ody = abs(dy - search)
                for dx in range(n_off):
                    if block == 8:  # FSR 3's block size: the unrolled, vectorised SAD
                        s = _sad8(wb, cb, dy, dx)
                    else:
                        s = F32(0.0)
                        for r in range(block):
                            for c in range(block):
                                s += abs(wb[r + dy, c + dx] - cb[r, c])
                    key = np.int64(s) * 64 + (abs(dx - search) + ody)
                    if key < best:
                        best = key
                        bi = dy
                        bj = dx
            out[0, by, bx] = px + bj - search
            out[1, by, bx] = py + bi - search


def _order_keys():
    """The tie part of block_search_sad_kernel's keys per offset t = 16 dy + dx (dy, dx
    = 0..15 for -8..7): ``(|dx - 8| + |dy - 8|) << 8 | t``, so that ``SAD << 14 |`` it
    orders as the reference's ``SAD * 64 + |dx| + |dy|`` and then by (dy, dx)."""
    t = np.arange(256, dtype=np.int32)
    return ((np.abs(t % 16 - 8) + np.abs(t // 16 - 8)) << 8) | t


_ORDER = _order_keys()


@njit(**INLINE)
def _search_row(cur, prev, pred, out, by, cb, wb):
    """block_search_sad_kernel's block row by (cb, wb: its block and window buffers)."""
    h, w = cur.shape
    nbx = pred.shape[2]
    cf = cur.reshape(h * w)
    pf = prev.reshape(h * w)
    for bx in range(nbx):
        oy = by * 8
        ox = bx * 8
        py = pred[1, by, bx]
        px = pred[0, by, bx]
        y0 = oy + py - 8
        x0 = ox + px - 8
        if oy + 8 <= h and ox + 16 <= w and y0 >= 0 and y0 + 23 <= h and x0 >= 0 \
                and x0 + 24 <= w:  # in place (16 block bytes and 24 window bytes read)
            csrc, coff, cst = cf, oy * w + ox, w
            wsrc, woff, wst = pf, y0 * w + x0, w
        else:
            _block_window(cur, prev, oy, ox, py, px, 8, 8, cb, 16, wb, 24)
            csrc, coff, cst = cb, np.int64(0), np.int64(16)
            wsrc, woff, wst = wb, np.int64(0), np.int64(24)
        t = sad_search8(wsrc, woff, wst, csrc, coff, cst, _ORDER) & 255
        out[0, by, bx] = px + (t & 15) - 8
        out[1, by, bx] = py + (t >> 4) - 8


@njit(**KERNEL)
def block_search_sad_kernel(cur, prev, pred, out):
    """block_search_kernel for FSR 3's sizes (8x8 blocks, offsets -8..7) on x86: cur, prev
    (h, w) uint8 luminances (C-contiguous); the SADs by SSE4.1 mpsadbw
    (fgcli.kernels._intrin.sad_search8), exact integers, so the same vectors and the same
    tie rule as the float kernel: each offset's key ``SAD << 14 | _ORDER[t]`` (below
    2**28: SAD <= 16320) is unique and orders as the reference's tie rule, so the least
    key is the vector.

    A block and its window are read in place from the frames where they lie inside (every
    block but those at the edges); only the others are copied, edge-replicated. 1080p
    level: 10.1 ms (window copies, SADs to memory, a compare per offset) -> 2.5 ms
    (AVX2)."""
    for pby in prange(pred.shape[1]):
        by = np.int64(pby)  # prange indices are unsigned: keep index arithmetic signed
        cb = np.zeros(8 * 16, dtype=np.uint8)  # block rows of 16 bytes (8 used)
        wb = np.zeros(23 * 24, dtype=np.uint8)  # window rows of 24 bytes (23 used)
        _search_row(cur, prev, pred, out, by, cb, wb)


@njit(**INLINE)
def _median_row(f, out, y):
    """vector_median3_kernel's row y."""
    h, w = f.shape[1], f.shape[2]
    NX = np.empty((9, w), dtype=np.float32)  # the neighbours t of each pixel
    NY = np.empty((9, w), dtype=np.float32)
    C = np.empty(w, dtype=np.float32)
    BC = np.empty(w, dtype=np.float32)
    OX = np.empty(w, dtype=np.float32)
    OY = np.empty(w, dtype=np.float32)
    for t in range(9):
        yy = min(max(y + t // 3 - 1, 0), h - 1)
        o = t % 3 - 1
        for k in range(2):
            src = f[k, yy]
            dst = NX[t] if k == 0 else NY[t]
            if w >= 3:  # the interior through row views (no clamped, gathered indices;
                # a loop, not a slice assignment, which numba makes a parallel region of
                # its own outside a prange)
                di = dst[1:w - 1]
                si = src[1 + o:w - 1 + o]
                for x in range(w - 2):
                    di[x] = si[x]
                dst[0] = src[max(o, 0)]
                dst[w - 1] = src[min(w - 1 + o, w - 1)]
            else:
                for x in range(w):
                    dst[x] = src[min(max(x + o, 0), w - 1)]
    for i in range(9):
        xi = NX[i]
        yi = NY[i]
        for x in range(w):
            C[x] = F32(0.0)
        for j in range(9):
            xj = NX[j]
            yj = NY[j]
            for x in range(w):
                C[x] += abs(xj[x] - xi[x]) + abs(yj[x] - yi[x])
        if i == 4:
            for x in range(w):
                C[x] = C[x] - F32(1e-3)
        for x in range(w):
            t = (i == 0) | (C[x] < BC[x])
            BC[x] = C[x] if t else BC[x]
            OX[x] = xi[x] if t else OX[x]
            OY[x] = yi[x] if t else OY[x]
    for x in range(w):
        out[0, y, x] = OX[x]
        out[1, y, x] = OY[x]


@njit(**KERNEL)
def vector_median3_kernel(f, out):
    """fgcli.ops.fsr3._vector_median3 on an integer vector field: f, out (2, h, w)
    float32. Of the 3x3 neighbours (edge-replicated, row-major), the one whose summed L1
    distance to all nine is least, the centre's sum less 1e-3 (float32, as the reference:
    ties prefer the centre), the first of equal sums otherwise. The sums are of whole
    numbers below 2**24 (any order gives the same float32), and the centre's 1e-3 is
    taken off in float32 like the reference's, so the choice is the reference's. A row
    at a time, each candidate's sum over the row's pixels in a vector loop (the sums in
    the order a pixel-by-pixel loop takes them)."""
    for py in prange(f.shape[1]):
        _median_row(f, out, np.int64(py))




# ----------------------------------------------------------------------------- pyramid
# block_flow's luminance pyramid as bytes: the reference's levels are whole numbers 0..255
# held in float32 (round(clamp(nan_to_num(l), 0, 255)), then round(avg_pool2(level))), so
# uint8 holds them exactly and the searches take them without conversions.


@njit(**KERNEL)
def luma_u8_kernel(lum, out):
    """out (H, W) uint8 = round(clamp(nan_to_num(lum, nan=0), 0, 255)) (round half to
    even, as torch.round; +inf -> 255, -inf -> 0)."""
    h, w = out.shape
    for py in prange(h):
        y = np.int64(py)
        for x in range(w):
            v = lum[y, x]
            v = F32(0.0) if v != v else v
            v = F32(0.0) if v < F32(0.0) else v
            v = F32(255.0) if v > F32(255.0) else v
            out[y, x] = np.uint8(np.rint(v))


@njit(**INLINE)
def _round_mean(s, c):
    """round(s / c) half to even, for whole s >= 0 and c in 1, 2, 4 (s / c exact in
    float32: the reference's division and torch.round)."""
    q = s // c
    r2 = 2 * (s - q * c)
    q = q + 1 if r2 > c else q
    return q + (q & 1) if r2 == c else q


@njit(**INLINE)
def _pool_u8_row(src, dst, oy):
    """Output row oy of dst = round(avg_pool2d(src, 2, ceil_mode=True)) of a uint8 level
    (the children that exist: the last row / column of an odd size averages what is
    there), exactly the reference's float32 level."""
    h, w = src.shape
    w2 = dst.shape[1]
    wf = w // 2
    y0 = 2 * oy
    if y0 + 1 < h:
        for ox in range(wf):
            s = np.int32(src[y0, 2 * ox]) + np.int32(src[y0, 2 * ox + 1]) + \
                np.int32(src[y0 + 1, 2 * ox]) + np.int32(src[y0 + 1, 2 * ox + 1])
            dst[oy, ox] = np.uint8(_round_mean(s, np.int32(4)))
        if wf < w2:
            s = np.int32(src[y0, w - 1]) + np.int32(src[y0 + 1, w - 1])
            dst[oy, wf] = np.uint8(_round_mean(s, np.int32(2)))
    else:
        for ox in range(wf):
            s = np.int32(src[y0, 2 * ox]) + np.int32(src[y0, 2 * ox + 1])
            dst[oy, ox] = np.uint8(_round_mean(s, np.int32(2)))
        if wf < w2:
            dst[oy, wf] = src[y0, w - 1]


def flow_chain_layout(h: int, w: int, levels: int):
    """The block flow's pyramid (fgcli.kernels.ops._block_flow_u8: levels while both sides
    are 16 px or more, at most ``levels``) and its block fields, as flat buffers: (hs, ws,
    offs) of the byte levels (level i >= 1 at offs[i]:offs[i + 1]; level 0 is the
    luminance itself), (bh, bw, boffs) of the (2, bh[i], bw[i]) float32 fields, int64."""
    hs, ws = [h], [w]
    while len(hs) < levels and min(hs[-1], ws[-1]) >= 16:
        hs.append((hs[-1] + 1) // 2)
        ws.append((ws[-1] + 1) // 2)
    offs, boffs = [0, 0], [0]
    for i in range(1, len(hs)):
        offs.append(offs[-1] + hs[i] * ws[i])
    bh = [-(-x // 8) for x in hs]
    bw = [-(-x // 8) for x in ws]
    for i in range(len(hs)):
        boffs.append(boffs[-1] + 2 * bh[i] * bw[i])
    return tuple(np.array(v, dtype=np.int64) for v in (hs, ws, offs, bh, bw, boffs))


# the levels of fewer pixels / blocks than these run on one thread (waking the second costs
# 10-35 us here: more than a small level's work)
_PAR_POOL = 1 << 16
_PAR_SEARCH = 1024
_PAR_MEDIAN = 4096


@njit(**INLINE)
def _zeros_u8(n):
    """np.zeros(n, np.uint8) by a loop (np.zeros is a parallel region of its own outside a
    prange)."""
    a = np.empty(n, dtype=np.uint8)
    for k in range(n):
        a[k] = 0
    return a


@njit(**INLINE)
def _level_u8(l0, buf, hs, ws, offs, i):
    """Byte level i of a frame: its luminance l0 (i = 0), else its place in buf."""
    if i == 0:
        return l0
    return buf[offs[i]:offs[i + 1]].reshape((hs[i], ws[i]))


@njit(**KERNEL)
def block_flow_u8_kernel(l0, l1, buf0, buf1, hs, ws, offs, bh, bw, boffs, median, fbuf):
    """fgcli.kernels.ops._block_flow_u8's whole chain in one call (flow_chain_layout): the
    byte pyramids of both frames (_pool_u8_row's levels), then from the coarsest level
    to the finest the block search (block_search_sad_kernel's, predicted by twice the
    parent block's vector, the last row / column replicated) and the 3x3 vector median
    (vector_median3_kernel's) into fbuf (level i's field at boffs[i], float32); the
    small levels on one thread (_PAR_*: each call of a kernel woke the second thread, 28
    calls per 1080p frame before). The same vectors."""
    nl = hs.shape[0]
    for i in range(1, nl):
        h2 = hs[i]
        if h2 * ws[i] >= _PAR_POOL:
            for q in prange(2 * h2):
                k = q // h2
                src = _level_u8(l0 if k == 0 else l1, buf0 if k == 0 else buf1, hs, ws, offs,
                                i - 1)
                dst = _level_u8(l0, buf0 if k == 0 else buf1, hs, ws, offs, i)
                _pool_u8_row(src, dst, np.int64(q - k * h2))
        else:
            for k in range(2):
                src = _level_u8(l0 if k == 0 else l1, buf0 if k == 0 else buf1, hs, ws, offs,
                                i - 1)
                dst = _level_u8(l0, buf0 if k == 0 else buf1, hs, ws, offs, i)
                for q in range(h2):
                    _pool_u8_row(src, dst, np.int64(q))
    for lv in range(nl - 1, -1, -1):
        nby = bh[lv]
        nbx = bw[lv]
        pred = np.empty((2, nby, nbx), dtype=np.int64)  # (np.zeros: a parallel region)
        if lv == nl - 1:
            for c in range(2):
                for by in range(nby):
                    for bx in range(nbx):
                        pred[c, by, bx] = 0
        else:  # the parent block's vector, twice
            ph = bh[lv + 1]
            pw = bw[lv + 1]
            par = fbuf[boffs[lv + 1]:boffs[lv + 2]].reshape((2, ph, pw))
            for c in range(2):
                for by in range(nby):
                    sy = min(by // 2, ph - 1)
                    for bx in range(nbx):
                        pred[c, by, bx] = np.int64(par[c, sy, min(bx // 2, pw - 1)]) * 2
        cur = _level_u8(l1, buf1, hs, ws, offs, lv)
        prev = _level_u8(l0, buf0, hs, ws, offs, lv)
        out = np.empty((2, nby, nbx), dtype=np.int64)
        if nby * nbx >= _PAR_SEARCH:
            for pby in prange(nby):
                _search_row(cur, prev, pred, out, np.int64(pby), _zeros_u8(8 * 16),
                            _zeros_u8(23 * 24))
        else:
            cb = _zeros_u8(8 * 16)
            wb = _zeros_u8(23 * 24)
            for by in range(nby):
                _search_row(cur, prev, pred, out, np.int64(by), cb, wb)
        fl = fbuf[boffs[lv]:boffs[lv + 1]].reshape((2, nby, nbx))
        raw = np.empty((2, nby, nbx), dtype=np.float32) if median else fl
        for c in range(2):
            for by in range(nby):
                for bx in range(nbx):
                    raw[c, by, bx] = F32(out[c, by, bx])
        if median:
            if nby * nbx >= _PAR_MEDIAN:
                for py in prange(nby):
                    _median_row(raw, fl, np.int64(py))
            else:
                for y in range(nby):
                    _median_row(raw, fl, np.int64(y))


# ----------------------------------------------------------------------------- luma8

@njit(**INLINE)
def _clip01_bits(v):
    """The bits (int32) of luma8's Y = clip(v, 0, 1) of a luminance v: NaN -> 0,
    +inf -> 1, -inf -> 0, as _clip01 (field_luminance's plane, whose NaN -> 0 and
    +-inf -> +-BIG, clips the same way)."""
    v = F32(0.0) if v != v else v
    v = F32(1.0) if v > F32(1.0) else v
    return F32(F32(0.0) if v < F32(0.0) else v).view(np.int32)


@njit(**ROWS)
def _luma8_rows(ya, yb, color, lum, tab, b0, sh, bottom, out, B, I, E):
    """Rows ya..yb of luma8's codes (luma8_table's lookup: step_codes, 16 per gather) of
    the luminance of the sanitised colour (3, H, W), or with lum (H, W) not empty of that
    plane, into out (H, W) (float32 or uint8). B, I, E: int32 row buffers."""
    h, w = out.shape
    n1 = np.int32(tab.shape[0] - 1)
    plane = lum.shape[0] > 0
    for y in range(ya, yb):
        if plane:
            for x in range(w):
                B[x] = _clip01_bits(lum[y, x])
        else:
            for x in range(w):
                B[x] = _clip01_bits(_lum(color, y, x))
        step_codes(B, w, tab, b0, sh, n1, bottom, I, E)
        for x in range(w):
            out[y, x] = E[x]


@njit(**INLINE)
def _luma8_chunks(color, lum, tab, b0, sh, bottom, out):
    """The luma8 kernels' parallel loop: 64 chunks of rows, each with its row buffers."""
    h, w = out.shape
    nch = min(h, 64)
    for ch in prange(nch):
        ya = np.int64(ch) * h // nch
        yb = (np.int64(ch) + 1) * h // nch
        B = np.empty(w, dtype=np.int32)
        I = np.empty(w, dtype=np.int32)
        E = np.empty(w, dtype=np.int32)
        _luma8_rows(ya, yb, color, lum, tab, b0, sh, bottom, out, B, I, E)


@njit(**KERNEL)
def luma8_kernel(color, tab, b0, sh, bottom, out):
    """fgcli.ops.fsr3.luma8 (the codes of the luminance of the sanitised colour): out
    (H, W) float32. tab, b0, sh, bottom: packed_steps(luma8_table) (int32)."""
    _luma8_chunks(color, np.empty((0, 0), dtype=np.float32), tab, b0, sh, bottom, out)


@njit(**KERNEL)
def luma8_u8_plane_kernel(lum, tab, b0, sh, bottom, out):
    """fgcli.ops.fsr3.luma8_u8_of: the bytes of a luminance plane lum (H, W) float32 ->
    out (H, W) uint8."""
    _luma8_chunks(np.empty((3, 0, 0), dtype=np.float32), lum, tab, b0, sh, bottom, out)


@njit(**KERNEL)
def luma8_u8_kernel(color, tab, b0, sh, bottom, out):
    """fgcli.ops.fsr3.luma8_u8 (luma8_kernel's codes as bytes): out (H, W) uint8."""
    _luma8_chunks(color, np.empty((0, 0), dtype=np.float32), tab, b0, sh, bottom, out)
