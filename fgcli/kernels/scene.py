"""Scene-cut histogram score (fgcli.ops.scene.scene_change_score_tensor): the subsampled
luma and the per-region counts as numba loops, the rest as the reference's torch ops.

The reference spends ~1.5 ms per 1080p pair on per-op overhead (about twenty torch ops on
85K samples, a strided copy of both frames). Here the luma before its gamma comes from
one loop over the samples (the same float32 products and sums, no contraction), the gamma
is the reference's own torch ``pow`` (so no libm difference can move a sample to another
bin), the counts from a second loop (round half to even, as torch.round), and the
normalisation and divergence are the reference's torch code on the (2, 9, 32) counts: the
score is the reference's, bit for bit.

Only the level of a sample's gamma counts, and that is a step function of the luma's
float32 bits: scene_bins_kernel takes it from tables made from torch's own pow
(fgcli.kernels.ops._scene_levels: a lookup by the top bits, windows around each step
where both of torch's pow paths were evaluated), so the luma, the level and the counts
are one pass with no pow (1.8x faster); samples the tables leave open
(torch's vector and scalar pow disagree there, so the reference's level depends on the
sample's position) send the frame the first way."""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from fgcli.kernels._common import F32, INLINE, KERNEL, clamp_b, sval_b

LUT_SHIFT = 14  # scene_bins_kernel's buckets: float32 bit patterns >> 14 (16384 each)

SERIAL = dict(KERNEL, parallel=False)  # the counts: one += per sample into 2 x 9 x 32 bins


@njit(**KERNEL)
def scene_luma_kernel(c0, c1, s, out):
    """c0, c1 (3, H, W); out (2, ceil(H / s), ceil(W / s)): the luma of every s-th pixel
    of every s-th row (pixel [::s, ::s]) of sanitised colour clipped to [0, 1], before
    the gamma. (Parallel: each sample is a cache miss in each plane, ~0.4 ms at 1080p on
    one thread.)"""
    hs, ws = out.shape[1], out.shape[2]
    lo = F32(0.0)
    hi = F32(1.0)
    for fi in prange(2 * hs):
        f = np.int64(fi) // hs
        i = np.int64(fi) - f * hs
        c = c0 if f == 0 else c1
        y = i * s
        for j in range(ws):
            x = j * s
            r = clamp_b(sval_b(c[0, y, x]), lo, hi)
            g = clamp_b(sval_b(c[1, y, x]), lo, hi)
            b = clamp_b(sval_b(c[2, y, x]), lo, hi)
            out[f, i, j] = (F32(0.2126) * r + F32(0.7152) * g) + F32(0.0722) * b


@njit(**SERIAL)
def scene_counts_kernel(luma, bins, regions, out):
    """luma (B, h, w) in [0, 1] after the gamma -> out (B, regions**2, bins) += pixel
    counts per region and quantised level (round(luma * (bins - 1)), half to even)."""
    n, h, w = luma.shape
    kb = F32(bins - 1)
    col = np.empty(w, dtype=np.int64)  # each column's region column, times bins
    for x in range(w):
        col[x] = min(x * regions // w, regions - 1) * bins
    for f in range(n):
        flat = out[f].reshape(-1)
        for y in range(h):
            base = min(y * regions // h, regions - 1) * regions * bins
            for x in range(w):
                q = min(max(np.int64(np.rint(luma[f, y, x] * kb)), 0), bins - 1)
                flat[base + col[x] + q] += F32(1.0)


@njit(**INLINE)
def _level(b, lut, lo, tab):
    """The quantised level of a luma whose float32 bits are b (scene_bins_kernel): from
    lut by its top bits, or where that bucket holds a window (lut -1), by the windows: the
    number of windows below b, or inside window k its table entry (-1: disputed)."""
    b = max(b, np.int32(0))  # (-0.0: level 0)
    q = np.int32(lut[b >> LUT_SHIFT])
    if q >= 0:
        return q
    r = np.int32(tab.shape[1])
    q = np.int32(0)
    for k in range(lo.shape[0]):
        o = b - lo[k]
        if o >= r:
            q += np.int32(1)
        elif o >= 0:
            return np.int32(tab[k, o])
    return q


@njit(**KERNEL)
def scene_bins_kernel(c0, c1, s, lut, lo, tab, regions, bins, out):
    """scene_luma_kernel's sampled luma, its gamma level round(luma^(1/2.2) * (bins - 1))
    and scene_counts_kernel's counts into out (2, regions**2, bins) (zeros), in one pass
    with no pow: the level of a luma comes from its float32 bits (_level; lut, lo, tab:
    fgcli.kernels.ops._scene_levels, made from torch's own pow). Returns the number of
    samples whose level the tables leave open (torch's two pow paths disagree there: the
    caller then takes the reference's way). One task per frame and band of region rows."""
    hs, ws = -(-c0.shape[1] // s), -(-c0.shape[2] // s)
    lo_c = F32(0.0)
    hi_c = F32(1.0)
    col = np.empty(ws, dtype=np.int64)  # each sample column's region column, times bins
    for j in range(ws):
        col[j] = min(j * regions // ws, regions - 1) * bins
    bad = np.zeros(2 * regions, dtype=np.int64)
    for t in prange(2 * regions):
        f = t // regions
        band = t - f * regions
        c = c0 if f == 0 else c1
        flat = out[f].reshape(-1)
        n = 0
        for i in range(hs):
            if min(i * regions // hs, regions - 1) != band:
                continue
            y = i * s
            base = band * regions * bins
            for j in range(ws):
                x = j * s
                r = clamp_b(sval_b(c[0, y, x]), lo_c, hi_c)
                g = clamp_b(sval_b(c[1, y, x]), lo_c, hi_c)
                b = clamp_b(sval_b(c[2, y, x]), lo_c, hi_c)
                lum = (F32(0.2126) * r + F32(0.7152) * g) + F32(0.0722) * b
                q = _level(F32(lum).view(np.int32), lut, lo, tab)
                if q < 0:
                    n += 1
                else:
                    flat[base + col[j] + q] += F32(1.0)
        bad[t] = n
    return bad.sum()
