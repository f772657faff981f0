"""The mip chain of fgcli.ops.pyramid: one 2x2 box-average level (torch's avg_pool2d with
ceil_mode, whose CPU kernel is not vectorised for this case: 45 ms for a 4-channel 1080p
level against 8 ms here), the whole chain in one call, pyramid_inpaint's dense part, and
its fill at the hole pixels (fill_from_levels) in one pass per hole."""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from fgcli.kernels._common import F32, INF, INLINE, KERNEL, dealt, sval_b
from fgcli.kernels._intrin import fma
from fgcli.kernels.warp import _grid_coords

U0 = np.uint8(0)
U1 = np.uint8(1)


@njit(**INLINE)
def _pool_row(src, dst, k, oy):
    """dst[k, oy, :] = avg_pool2d(src, 2, ceil_mode=True)'s row: each output the sum of
    the existing children in row-major order, from 0 (as torch's loop), divided by their
    count (so the last row / column of an odd size averages what exists)."""
    h = src.shape[1]
    w = src.shape[2]
    w2 = dst.shape[2]
    wf = w // 2
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


@njit(**KERNEL)
def pool2_kernel(src, dst):
    """dst = avg_pool2d(src, 2, ceil_mode=True) for (C, H, W) float32 (_pool_row)."""
    c = src.shape[0]
    h2 = dst.shape[1]
    for q in prange(c * h2):
        k = q // h2
        _pool_row(src, dst, k, q - k * h2)


def chain_layout(c1: int, h: int, w: int):
    """Where the mip levels 1.. of an (H, W) image with c1 channels lie in one flat
    float32 buffer, down to 1x1 (fgcli.ops.pyramid.weighted_pyramid's sizes): (hs, ws,
    offs), int64, index i = level i (index 0: level 0's size, not stored); level i is
    buffer[offs[i]:offs[i + 1]] as (c1, hs[i], ws[i])."""
    hs, ws = [h], [w]
    while hs[-1] > 1 or ws[-1] > 1:
        hs.append((hs[-1] + 1) // 2)
        ws.append((ws[-1] + 1) // 2)
    offs = [0, 0]
    for i in range(1, len(hs)):
        offs.append(offs[-1] + c1 * hs[i] * ws[i])
    return (np.array(hs, dtype=np.int64), np.array(ws, dtype=np.int64),
            np.array(offs, dtype=np.int64))


_PAR_LEVEL = 1 << 15  # a level of fewer elements pools on one thread (no wake-up)


@njit(**KERNEL)
def pool_chain_kernel(chain, hs, ws, offs):
    """Levels 2.. of a chain (chain_layout) from its level 1, each pool2_kernel of the one
    before (the same sums in the same order), in one call: the small levels on one thread
    (30 calls of pool2_kernel cost 2.2 ms per 1080p fsr3-interp frame, mostly waking
    threads)."""
    c1 = (offs[2] - offs[1]) // (hs[1] * ws[1])
    for i in range(2, hs.shape[0]):
        src = chain[offs[i - 1]:offs[i]].reshape((c1, hs[i - 1], ws[i - 1]))
        dst = chain[offs[i]:offs[i + 1]].reshape((c1, hs[i], ws[i]))
        h2 = hs[i]
        if offs[i + 1] - offs[i] >= _PAR_LEVEL:
            for q in prange(c1 * h2):
                k = q // h2
                _pool_row(src, dst, k, q - k * h2)
        else:
            for q in range(c1 * h2):
                k = q // h2
                _pool_row(src, dst, k, q - k * h2)


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
    n8 = w // 8
    for pq in prange(start.shape[0] - 1):
        q = np.int64(pq)
        k = start[q]
        if start[q + 1] == k:  # no hole in the pair (most pairs of a frame)
            continue
        for y in range(2 * q, min(2 * q + 2, h)):
            hr = hout[y]
            hv = hr[:n8 * 8].view(np.uint64)
            for b in range(n8 + 1):  # eight flags per test (the last "word": w % 8)
                if b < n8 and hv[b] == np.uint64(0):
                    continue
                for x in range(8 * b, min(8 * b + 8, w)):
                    if hr[x] != U0:
                        idx[k] = y * w + x
                        k += 1


@njit(**INLINE)
def _chain_sample(chain, o, hl, wl, c1, inv, xf, yf, smp):
    """fgcli.ops.pyramid._sample_level at one pixel (xf, yf) of level (c1, hl, wl)
    starting at chain[o], inv = 2**-i: smp[0:c1] (its float32 ops; the division by 2**i
    as the product with inv, which is exact: the same values)."""
    gx = (((xf + F32(0.5)) * inv) / F32(wl)) * F32(2.0) - F32(1.0)
    gy = (((yf + F32(0.5)) * inv) / F32(hl)) * F32(2.0) - F32(1.0)
    y0, x0, y1, x1, nw, ne, sw, se = _grid_coords(gx, gy, F32(wl * 0.5), F32(hl * 0.5),
                                                  F32(wl - 1), F32(hl - 1), wl, hl)
    i00 = o + y0 * wl + x0
    i01 = o + y0 * wl + x1
    i10 = o + y1 * wl + x0
    i11 = o + y1 * wl + x1
    n = hl * wl
    for k in range(c1):
        b = k * n
        smp[k] = fma(sval_b(chain[b + i11]), se,
                     fma(sval_b(chain[b + i10]), sw,
                         fma(sval_b(chain[b + i01]), ne, sval_b(chain[b + i00]) * nw)))


@njit(**KERNEL)
def fill_levels_kernel(chain, hs, ws, offs, idx, ms, nb, eps, out, filled):
    """fgcli.ops.pyramid.fill_from_levels at the holes idx (flat indices into (H, W),
    W = ws[0]) from the chain's levels 1.. (chain_layout, C + 1 channels), one pass per
    hole instead of a gather and selects per level over all of them: 'blend' (nb > 0):
    acc = sum over levels 1..nb of fma(sample, ms[i], acc) (torch's add_ with alpha),
    taken where its weight exceeds eps (float32), divided by the weight clamped at eps;
    then (and for 'first', nb = 0) the first level whose sampled weight exceeds eps.
    out (C, H * W) takes the sanitised result at each hole (0 where nothing holds any
    weight), filled (H * W,) uint8 1 where a level served (the rest is not written;
    filled of size 0: not wanted)."""
    c = out.shape[0]
    w = ws[0]
    nl = hs.shape[0]
    n = idx.shape[0]
    want = filled.shape[0] > 0
    nch = (n + 255) // 256  # (small chunks: holes deep in a hole read more levels)
    for pc in prange(nch):
        j0 = dealt(pc, nch) * 256  # (each thread's holes spread over the frame)
        acc = np.empty(c + 1, dtype=np.float32)
        smp = np.empty(c + 1, dtype=np.float32)
        res = np.empty(c, dtype=np.float32)
        for j in range(j0, min(n, j0 + 256)):
            q = idx[j]
            y = q // w
            xf = F32(q - y * w)
            yf = F32(y)
            done = False
            for k in range(c):
                res[k] = F32(0.0)
            if nb > 0:
                for k in range(c + 1):
                    acc[k] = F32(0.0)
                for i in range(1, nb + 1):
                    _chain_sample(chain, offs[i], hs[i], ws[i], c + 1, F32(0.5 ** i), xf, yf,
                                  smp)
                    for k in range(c + 1):
                        acc[k] = fma(smp[k], ms[i], acc[k])
                if acc[c] > eps:  # (then the reference's clamp at eps leaves it)
                    for k in range(c):
                        res[k] = acc[k] / acc[c]
                    done = True
            i = 1
            while not done and i < nl:
                _chain_sample(chain, offs[i], hs[i], ws[i], c + 1, F32(0.5 ** i), xf, yf, smp)
                if smp[c] > eps:
                    for k in range(c):
                        res[k] = smp[k] / smp[c]
                    done = True
                i += 1
            for k in range(c):
                out[k, q] = sval_b(res[k])
            if done and want:
                filled[q] = U1
