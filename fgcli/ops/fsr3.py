"""FSR 3 frame interpolation (FidelityFX Frame Interpolation 1.0 + FfxOpticalFlow), as pure
tensor functions: one function per pass of shared/seeds/003 and ALGORITHMS.md.

Frames: "0" the previous (older) rendered frame, "1" the current one; alpha the generated
time in [0, 1] (FSR 3 interpolates at 0.5; fgen generalises every "0.5" to the time:
a surface at p1 in frame 1 with vector v = mv1(p1) sits at ``p1 + (1 - alpha) v`` at time
alpha and at ``p1 + v`` in frame 0). Index coordinates (pixel centre of column x is x).

Vector fields of the interpolated frame are stored as FSR 3 does: per component an entry
``priority << 16 | half-float bits`` written with an atomic max (scatter_reduce 'amax'),
priority = ``primary (1 bit) << 15 | depth or magnitude priority (10 bits) << 5 |
colour-agreement priority (5 bits)``. fgen stores the full frame-1 -> frame-0 vector v
(FSR 3 stores 0.5 v; same thing at alpha = 0.5). A field entry of 0 means "not written".

Passes (ops below): reconstruct_depths, vector_field (game / optical-flow field),
unpack_vector_field + fill_vector_field (pyramid inpainting, fgcli.ops.pyramid; both
in one op: fill_packed_field),
luma8, block_flow / dis_flow (optical flow), disocclusion_masks, interpolate_fsr3,
pyramid_inpaint (colour).
"""
from __future__ import annotations

import functools
import math

import numpy as np
import torch
import torch.nn.functional as F

from fgcli.ops._util import (all_set, check_alpha, check_same, check_tensor, reads_back,
                             sanitize_depth, sanitize_mv, sanitize_values)
from fgcli.ops.color import luminance
from fgcli.ops.pyramid import pyramid_inpaint
from fgcli.ops.warp import backward_warp

KSEP = 1.37e-5  # FSR 2/3 minimum triangle separation constant
SHORT_MV = 0.1  # px: shorter vectors are zeroed in depth reconstruction
TAP_THRESHOLD = 0.05  # bilinear-footprint taps with a smaller weight are not written
HALF_MAX = 65504.0


# ----------------------------------------------------------------------------- helpers

def _length(x: torch.Tensor, keepdim: bool = False) -> torch.Tensor:
    """Euclidean length over dim 0 (channels): ``sqrt(sum x^2)``. Same values as
    ``x.norm(dim=0)``, but torch's norm reduction over the leading (strided) dimension is
    about 80x slower on CPU (7 ms vs 0.1 ms for a (3, 144, 256) tensor, one thread)."""
    return (x * x).sum(dim=0, keepdim=keepdim).sqrt()


def _footprint(pos: torch.Tensor, h: int, w: int, thr: float = TAP_THRESHOLD):
    """Bilinear footprint of positions pos (2, N) (index coords): four (flat index into a
    (h+2) x (w+2) buffer with a discard ring, mask) pairs; a tap is written when its
    bilinear weight exceeds thr. Off-screen taps land on the ring."""
    x = pos[0].clamp(-2.0, w + 1.0)
    y = pos[1].clamp(-2.0, h + 1.0)
    x0 = torch.floor(x)
    y0 = torch.floor(y)
    fx = x - x0
    fy = y - y0
    out = []
    for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        wt = (fx if dx else 1.0 - fx) * (fy if dy else 1.0 - fy)
        xi = (x0 + dx).clamp(-1, w).add_(1).to(torch.int64)
        yi = (y0 + dy).clamp(-1, h).add_(1).to(torch.int64)
        out.append((yi * (w + 2) + xi, wt > thr))
    return out


def _crop(buf: torch.Tensor, h: int, w: int) -> torch.Tensor:
    return buf.view(-1, h + 2, w + 2)[:, 1:h + 1, 1:w + 1]


def _positions(h, w, dev):
    yy, xx = torch.meshgrid(torch.arange(h, dtype=torch.float32, device=dev),
                            torch.arange(w, dtype=torch.float32, device=dev), indexing="ij")
    return torch.stack([xx, yy]).view(2, -1)


def camera_kfov(projection=None, width: int = 16, height: int = 9,
                fov_deg: float = 60.0) -> float:
    """FSR's Kfov = |corner ray| / |centre ray| = sqrt(1 + tan(fovx/2)^2 + tan(fovy/2)^2),
    from a 4x4 projection (P[0][0] = 1/tan(fovx/2), P[1][1] = 1/tan(fovy/2)) or, without
    one, from a vertical fov (default 60 degrees) and the aspect ratio."""
    if projection is not None:
        p00, p11 = float(projection[0][0]), float(projection[1][1])
        if math.isfinite(p00) and math.isfinite(p11) and p00 != 0 and p11 != 0:
            return math.sqrt(1.0 + 1.0 / p00 ** 2 + 1.0 / p11 ** 2)
    ty = math.tan(math.radians(fov_deg) / 2)
    tx = ty * width / max(height, 1)
    return math.sqrt(1.0 + tx * tx + ty * ty)


# ----------------------------------------------------------------------------- pass 1

def depth_sources(depth, mv, alpha, short_mv=SHORT_MV):
    """reconstruct_depths' sources: (depth (N,), [positions (2, N) at the previous frame,
    at the interpolated frame], (h, w))."""
    depth = check_tensor(depth, "depth", 1, allow_batch=False)
    mv = check_tensor(mv, "mv", 2, allow_batch=False)
    check_same(depth, "depth", (mv, "mv"))
    a = check_alpha(alpha)
    h, w = depth.shape[-2:]
    d = sanitize_depth(depth).reshape(-1)
    v = sanitize_mv(mv).reshape(2, -1)
    v = v * (_length(v, keepdim=True) >= short_mv)
    p = _positions(h, w, depth.device)
    return d, [p + v * k for k in (1.0, 1.0 - a)], (h, w)


def reconstruct_depths(depth: torch.Tensor, mv: torch.Tensor, alpha: float = 0.5,
                       short_mv: float = SHORT_MV, tap_threshold: float = TAP_THRESHOLD):
    """FSR 3 previous-frame and interpolated-frame depth reconstruction.

    Each pixel p of frame 1 (usually 3x3 nearest-depth dilated depth and vector, see
    dilate_nearest_depth) splats its depth over the bilinear footprint of ``p + v``
    (previous frame) and of ``p + (1 - alpha) v`` (interpolated frame) with an atomic min
    (scatter_reduce 'amin': the nearest surface wins). Vectors shorter than short_mv px
    are zeroed; footprint taps with bilinear weight <= tap_threshold are not written.

    Args:
        depth: (1, H, W) linear depth (NaN -> +inf, negative -> 0). mv: (2, H, W) px.
        alpha: generated time in [0, 1].

    Returns:
        (depth_prev, depth_t), each (1, H, W): +inf where nothing landed (and sky).
    """
    d, pos, (h, w) = depth_sources(depth, mv, alpha, short_mv)
    outs = []
    for p in pos:
        buf = torch.full(((h + 2) * (w + 2),), math.inf, device=depth.device)
        for idx, m in _footprint(p, h, w, tap_threshold):
            buf.scatter_reduce_(0, idx, torch.where(m, d, math.inf), reduce="amin")
        outs.append(_crop(buf[None], h, w).clone())
    return outs[0], outs[1]


# ----------------------------------------------------------------------------- pass 2

DEPTH_SHIFT = 16  # depth_priority's table buckets: float32 bit patterns >> 16


@functools.lru_cache(maxsize=None)
def depth_priority_table() -> tuple[np.ndarray, np.ndarray, int]:
    """depth_priority's step_table (f = 1023 - rank, exact in float64) and its first
    bucket b0. Buckets from 2**-31 to 2**31: every rank step but the first (depth 0 ->
    1023, any depth above 0 -> at most 1022, handled by the callers) lies inside, and
    from 1.6e8 on the rank is 1 (the last bucket answers for larger depths)."""
    def f(d):
        z = np.power(np.minimum(d, 1e30), 0.33)
        return 1023.0 - np.clip(np.floor(1023.0 / (1.0 + z)), 1.0, 1023.0)

    b0, b1 = (96 << 23) >> DEPTH_SHIFT, (158 << 23) >> DEPTH_SHIFT  # 2**-31, 2**31
    base, thr = step_table(f, 158 << 23, 1022, b0, b1, DEPTH_SHIFT)
    assert base[0] == 1.0 and base[-1] == 1022.0 and np.isnan(thr[-1])
    return base, thr, b0


def depth_priority(depth: torch.Tensor) -> torch.Tensor:
    """FSR 3's 10-bit "near is better" priority: ``z' = z^0.33``,
    ``max(1, floor((1 - z'/(1 + z')) * 1023))`` (= floor(1023 / (1 + z')), exactly, by
    depth_priority_table: no float32 pow); +inf (sky) -> 1, 0 -> 1023. int64, any
    shape."""
    d = sanitize_depth(depth)
    base, thr, b0 = _table_on(depth_priority_table, d.device)
    i = ((d.view(torch.int32) >> DEPTH_SHIFT) - b0).clamp_(0, base.numel() - 1).long()
    step = torch.where(d > 0.0, base[i] + (d >= thr[i]).float(), 0.0)
    return 1023 - step.to(torch.int64)


def game_vector_field(color0: torch.Tensor, color1: torch.Tensor, vec: torch.Tensor,
                      depth: torch.Tensor, alpha: float = 0.5, secondary: bool = True,
                      max_secondary: int = 64, tap_threshold: float = TAP_THRESHOLD,
                      length_bound: float | None = None,
                      luma0: torch.Tensor | None = None) -> torch.Tensor:
    """The GameMotionVectorField pass: vector_field of the game vectors with
    depth_priority(depth) as their priorities (the numba backend makes the priorities
    inside its priority kernel). depth: (1, H, W), frame 1's size."""
    check_same(check_tensor(vec, "vec", 2, allow_batch=False), "vec",
               (check_tensor(depth, "depth", 1, allow_batch=False), "depth"))
    return vector_field(color0, color1, vec, depth_priority(depth), alpha, secondary,
                        max_secondary, tap_threshold, length_bound, luma0=luma0)


def magnitude_priority(vec: torch.Tensor, scale: float = 8.0) -> torch.Tensor:
    """10-bit priority of an optical-flow vector from its magnitude m (px): moving content
    wins over static, ``max(1, floor(1023 m / (m + scale)))``. (2, ...) -> (1, ...) int64."""
    m = _length(sanitize_mv(vec), keepdim=True)
    return (1023.0 * m / (m + scale)).floor().clamp(1.0, 1023.0).to(torch.int64)


def agreement_priority(l0: torch.Tensor, l1: torch.Tensor) -> torch.Tensor:
    """5-bit colour agreement ``round(min/max(L0 + 0.001, L1 + 0.001) * 31)``, int64."""
    a = l0.clamp(min=0.0) + 0.001
    b = l1.clamp(min=0.0) + 0.001
    r = torch.minimum(a, b) / torch.maximum(a, b)
    return torch.round(torch.nan_to_num(r, nan=1.0) * 31.0).clamp(0, 31).to(torch.int64)


def pack_entries(primary: bool, hi: torch.Tensor, lo: torch.Tensor, comp: torch.Tensor):
    """``(primary << 15 | hi << 5 | lo) << 16 | half_bits(comp)`` as int64 (same shape)."""
    prio = (hi.clamp(0, 1023) << 5) | lo.clamp(0, 31)
    if primary:
        prio = prio | (1 << 15)
    bits = comp.clamp(-HALF_MAX, HALF_MAX).to(torch.float16).view(torch.int16)
    return (prio << 16) | (bits.to(torch.int64) & 0xFFFF)


def entries_args(color0, color1, vec, alpha):
    """field_entries' checked inputs: (color0, color1, vec, alpha)."""
    color0 = check_tensor(color0, "color0", 3, allow_batch=False)
    color1 = check_tensor(color1, "color1", 3, allow_batch=False)
    vec = check_tensor(vec, "vec", 2, allow_batch=False)
    check_same(color0, "color0", (color1, "color1"), (vec, "vec"))
    return color0, color1, vec, check_alpha(alpha)


def field_luminance(color: torch.Tensor) -> torch.Tensor:
    """The luminance plane the vector field's agreement priority reads frame 0 in:
    sanitize_values(luminance(sanitize_values(color))) (1, H, W) (the sampling sanitises
    what it reads anyway). A pipeline that builds two fields from the same frame 0 (the
    game field and the optical-flow field) computes it once (vector_field's luma0)."""
    color = check_tensor(color, "color", 3, allow_batch=False)
    return sanitize_values(luminance(sanitize_values(color)))


def field_entries(color0, color1, vec, hi, alpha, luma0=None):
    """The per-source part of vector_field: (vf (2, N) sanitised vectors, pos (2, N) =
    p + (1 - alpha) vf, hi (N,), lo (N,), keys [x, y] (N,) int64 primary entries,
    (h, w, alpha)). luma0: field_luminance(color0) when the caller has it."""
    color0, color1, vec, a = entries_args(color0, color1, vec, alpha)
    h, w = vec.shape[-2:]
    v = sanitize_mv(vec)
    if luma0 is None:
        luma0 = luminance(sanitize_values(color0))
    else:
        luma0 = check_tensor(luma0, "luma0", 1, allow_batch=False)
        check_same(luma0, "luma0", (vec, "vec"))
    s0, inside = backward_warp(luma0, v)
    l1 = luminance(sanitize_values(color1))
    lo = agreement_priority(s0, l1) * inside
    hi = hi.reshape(-1)
    lo = lo.reshape(-1)
    vf = v.reshape(2, -1)
    pos = _positions(h, w, vec.device) + vf * (1.0 - a)
    keys = [pack_entries(True, hi, lo, vf[c]) for c in (0, 1)]
    return vf, pos, hi, lo, keys, (h, w, a)


def vector_field(color0: torch.Tensor, color1: torch.Tensor, vec: torch.Tensor,
                 hi: torch.Tensor, alpha: float = 0.5, secondary: bool = True,
                 max_secondary: int = 64, tap_threshold: float = TAP_THRESHOLD,
                 length_bound: float | None = None, block: int = 1,
                 luma0: torch.Tensor | None = None) -> torch.Tensor:
    """FSR 3 vector field of the interpolated frame (GameMotionVectorField pass; with
    optical-flow vectors and magnitude priority, the OpticalFlowVectorField pass).

    Every pixel p of frame 1 with vector v writes the packed entries (primary flag, hi, lo =
    agreement_priority of frame 0's luminance at p + v and frame 1's at p; lo = 0 when p + v
    is off-screen) with an atomic max into the bilinear footprint of ``p + (1 - alpha) v``.
    Secondary entries (primary flag 0, same hi/lo) step back from there toward p, one
    texel per pixel of distance (at most max_secondary), each into the footprint's base
    texel, stopping after the fourth primary texel hit (FSR 3: "to cover the area the
    object leaves").

    Args:
        color0, color1: (3, H, W). vec: (2, H, W) px (frame 1 -> frame 0).
        hi: (1, H, W) int64 in [1, 1023] (depth_priority of the dilated depth, or
            magnitude_priority). alpha in [0, 1].
        length_bound: an upper bound of |vec| in px known on the host (the GPU path walks
            that many secondary steps instead of reading the longest vector back; None:
            max_secondary steps there). Never changes the result.
        block: vec and hi given per block of block x block pixels ((2, ceil(H / block),
            ceil(W / block)) and (1, ...): the optical flow's), each pixel taking its
            block's (upsample_block_flow).
        luma0: field_luminance(color0), when the caller has it (never changes the result).

    Returns:
        (2, H, W) int64 packed entries (x, y); 0 = not written.
    """
    if block != 1:
        h, w = color1.shape[-2:]
        vec, hi = upsample_block_flow(vec, h, w, block), upsample_block_flow(hi, h, w, block)
    vf, pos, hi, lo, keys, (h, w, a) = field_entries(color0, color1, vec, hi, alpha, luma0)
    dev = vf.device
    buf = torch.zeros(2, (h + 2) * (w + 2), dtype=torch.int64, device=dev)
    for idx, m in _footprint(pos, h, w, tap_threshold):
        for c in (0, 1):
            buf[c].scatter_reduce_(0, idx, keys[c] * m, reduce="amax")
    if secondary and max_secondary > 0:
        dist = _length(vf * (1.0 - a))
        dense = not reads_back(dist)
        if dense:  # GPU: no read-back; steps past the longest vector change nothing
            steps = max_secondary
            if length_bound is not None and math.isfinite(length_bound):
                steps = int(min(steps, math.floor(length_bound * (1.0 - a)) + 1))
        else:
            steps = int(min(max_secondary, math.floor(float(dist.max())) if dist.numel() else 0))
        if steps >= 1 and dist.numel():
            prim = buf[0] >= (1 << 31)  # primary texels (flag = bit 31)
            src = (torch.arange(dist.numel(), device=dev) if dense
                   else (dist >= 1.0).nonzero().view(-1))
            d = vf[:, src] / dist[src].clamp(min=1e-6)
            hits = torch.zeros(src.numel(), dtype=torch.int64, device=dev)
            kx = [pack_entries(False, hi[src], lo[src], vf[c, src]) for c in (0, 1)]
            sec = torch.zeros_like(buf)
            for k in range(1, steps + 1):
                act = (dist[src] >= k) & (hits <= 3)
                if not dense and not bool(act.any()):
                    break
                q = pos[:, src] - d * k
                xi = torch.floor(q[0]).clamp(-1, w).add_(1).to(torch.int64)
                yi = torch.floor(q[1]).clamp(-1, h).add_(1).to(torch.int64)
                idx = yi * (w + 2) + xi
                onscreen = (xi >= 1) & (xi <= w) & (yi >= 1) & (yi <= h)
                act &= onscreen
                hits += (prim[idx] & act).to(torch.int64)
                act &= hits <= 3
                for c in (0, 1):
                    sec[c].scatter_reduce_(0, idx, kx[c] * act, reduce="amax")
            buf = torch.maximum(buf, sec)
    return _crop(buf, h, w).clone()


def unpack_vector_field(field: torch.Tensor):
    """Packed field (2, H, W) int64 (or uint32: the numba backend's vector_field) ->
    (vec (2, H, W) float32, priority (1, H, W) int64 (16 bits: primary | hi | lo), valid
    (1, H, W) bool)."""
    if not isinstance(field, torch.Tensor) or field.dim() != 3 or field.shape[0] != 2:
        raise ValueError("field: expected a (2, H, W) int64 tensor")
    field = field.to(torch.int64)
    bits = (field & 0xFFFF).to(torch.int32)
    bits = torch.where(bits >= 32768, bits - 65536, bits).to(torch.int16)
    vec = bits.view(torch.float16).to(torch.float32)
    vec = torch.nan_to_num(vec, nan=0.0, posinf=HALF_MAX, neginf=-HALF_MAX)
    prio = (field[1:2] >> 16) & 0xFFFF
    valid = prio > 0
    return vec * valid, prio, valid


def fill_vector_field(vec: torch.Tensor, priority: torch.Tensor, valid: torch.Tensor,
                      pool=None, inpaint=None):
    """FSR 3 vector-field inpainting: texels never written take the first coarser level
    of a priority-weighted mip pyramid of the written vectors that has data (bilinear taps
    weighted by priority; pyramid_inpaint mode 'first').

    vec (2, H, W), priority (1, H, W) int, valid (1, H, W) bool -> (vec (2, H, W),
    filled (1, H, W) bool: had no entry and got one). An all-empty field stays 0.
    inpaint: pyramid_inpaint or a function with its signature (the numba backend's)."""
    wgt = priority.to(torch.float32) / 65535.0 * valid
    out, filled = (inpaint or pyramid_inpaint)(vec, wgt, ~valid, mode="first", pool=pool)
    return out, filled


def fill_packed_field(field: torch.Tensor):
    """A packed vector field's vectors with its unwritten texels inpainted: (vec (2, H, W),
    valid (1, H, W) bool: written). unpack_vector_field, then fill_vector_field unless
    every texel was written (on the GPU, which does not read the mask back: always)."""
    vec, prio, valid = unpack_vector_field(field)
    if reads_back(valid) and all_set(valid):
        return vec, valid
    out, _ = fill_vector_field(vec, prio, valid)
    return out, valid


# ----------------------------------------------------------------------------- optical flow

def step_table(f, hi_bits: int, steps: int, b0: int, b1: int, shift: int):
    """A lookup table for a non-decreasing integer function f of a float32 y >= 0 (float64
    arithmetic on the float32 values, vectorised), f(0) = 0, f(float32 with bits hi_bits)
    >= steps: (base (n,) float32, thr (n,) float32).

    T_j (j = 1..steps) is the smallest float32 with f >= j (bisection over the ordered bit
    patterns). Bucket i holds the float32s whose bits >> shift are b0 + i (i < n, the last
    bucket b1): base[i] = the number of T_j at or below its first value, thr[i] = the one
    T_j inside it (NaN when none: y >= NaN is false for every y, +inf too; more than one
    never happens, asserted). So for y in the buckets' range f(y) = base[i] + (y >=
    thr[i]), exactly as the float64 f decides,
    with no float32 pow (which rounds differently near a step, and torch's vectorised
    and scalar pow differ there too). Values below bucket 0 read it (callers check that
    no T_j lies below, except where they handle the values themselves)."""
    want = np.arange(1, steps + 1, dtype=np.float64)
    lo = np.zeros(steps, dtype=np.int64)
    hi = np.full(steps, hi_bits, dtype=np.int64)
    while (hi - lo > 1).any():
        mid = (lo + hi) // 2
        ok = f(mid.astype(np.int32).view(np.float32).astype(np.float64)) >= want
        hi, lo = np.where(ok, mid, hi), np.where(ok, lo, mid)
    n = b1 - b0 + 1
    start = (np.arange(n, dtype=np.int64) + b0) << shift
    assert np.all(np.diff(hi) > 0)
    base = np.searchsorted(hi, start, side="right").astype(np.float32)
    inside = np.clip((hi >> shift) - b0, 0, n - 1)
    own = (hi > start[inside]) & (hi < (b1 + 1) << shift)
    assert np.bincount(inside[own], minlength=n).max() <= 1
    thr = np.full(n, np.nan, dtype=np.float32)
    thr[inside[own]] = hi[own].astype(np.int32).view(np.float32)
    return base, thr


LUMA8_SHIFT = 15  # luma8's table buckets: float32 bit patterns >> 15 (8 mantissa bits)


@functools.lru_cache(maxsize=None)
def luma8_table() -> tuple[np.ndarray, np.ndarray, int]:
    """luma8's step_table and its first bucket b0: the code of a float32 Y in [0, 1] is
    255 sRGB(Y) rounded to nearest (sRGB in float64 as the minimum of its two branches,
    srgb_oetf's form). Buckets from 2**-13 (T_1 ~ 1.5e-4 lies above: below it every code
    is 0) to 1.0."""
    def enc(y):
        e = 255.0 * np.minimum(12.92 * y, 1.055 * np.power(y, 1.0 / 2.4) - 0.055)
        return np.floor(e + 0.5)

    b0, b1 = (114 << 23) >> LUMA8_SHIFT, 0x3F800000 >> LUMA8_SHIFT  # 2**-13, 1.0
    base, thr = step_table(enc, 0x3F800000, 255, b0, b1, LUMA8_SHIFT)
    assert base[0] == 0.0  # no step below bucket 0
    return base, thr, b0


@functools.lru_cache(maxsize=None)
def _table_on(table, device) -> tuple[torch.Tensor, torch.Tensor, int]:
    """A step table's (base, thr) as tensors on ``device`` (made once per device: on the
    GPU not uploaded again every frame), and its first bucket."""
    base, thr, b0 = table()
    return torch.from_numpy(base).to(device), torch.from_numpy(thr).to(device), b0


def luma8(color: torch.Tensor) -> torch.Tensor:
    """8-bit display luminance (FfxOpticalFlow input): 255 sRGB(clip(Y)) rounded to nearest
    (exactly, by luma8_table: a float32 pow rounds differently near k + 1/2, and torch's
    vectorised and scalar pow differ there too), float32 (1, H, W) with integer values
    0..255; NaN reads as 0, +inf as 1."""
    color = check_tensor(color, "color", 3, allow_batch=False)
    return _luma8_code(luminance(sanitize_values(color)))


def _luma8_code(y: torch.Tensor) -> torch.Tensor:
    """luma8's code of a luminance plane y (float32; NaN -> 0, +inf -> 1, clipped)."""
    y = torch.nan_to_num(y, nan=0.0, posinf=1.0, neginf=0.0).clamp_(0.0, 1.0)
    base, thr, b0 = _table_on(luma8_table, y.device)
    i = ((y.view(torch.int32) >> LUMA8_SHIFT) - b0).clamp_(0, base.numel() - 1).long()
    return base[i] + (y >= thr[i]).float()


def luma8_u8(color: torch.Tensor) -> torch.Tensor:
    """luma8 as bytes, (1, H, W) uint8 (its values are whole numbers 0..255): block_flow
    takes it as it is (the numba backend's search reads bytes: no float plane written and
    converted back)."""
    return luma8(color).to(torch.uint8)


def luma8_u8_of(lum: torch.Tensor) -> torch.Tensor:
    """luma8_u8 of a colour from its field_luminance plane (1, H, W): the same bytes (that
    plane is luma8's Y with NaN -> 0 and +-inf -> +-BIG, which the clip to [0, 1] reads as
    luma8 reads NaN and +-inf), from one plane instead of three channels. The
    optical-flow stage takes frame 0's this way from the game field's plane."""
    lum = check_tensor(lum, "lum", 1, allow_batch=False)
    if lum.dtype != torch.float32:
        raise ValueError(f"lum: expected float32, got {lum.dtype}")
    return _luma8_code(lum).to(torch.uint8)


def _vector_median3(f: torch.Tensor) -> torch.Tensor:
    """3x3 vector median (the neighbour minimising the summed L1 distance to the others;
    edge-replicated). (2, h, w) -> (2, h, w)."""
    h, w = f.shape[-2:]
    p = F.pad(f[None], (1, 1, 1, 1), mode="replicate")[0]
    nb = torch.stack([p[:, dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)])
    cost = (nb[:, None] - nb[None]).abs().sum(dim=2).sum(dim=1)  # (9, h, w)
    # ties: prefer the centre (index 4)
    cost[4] -= 1e-3
    best = cost.argmin(dim=0)
    return torch.gather(nb, 0, best[None, None].expand(1, 2, h, w))[0]


def _block_level(cur, prev, pred, block, search, subpixel=False, keep=False):
    """One pyramid level: SAD block search around the prediction. cur, prev (h, w);
    pred (2, nby, nbx) integer px -> (2, nby, nbx). subpixel: add the vertex of the
    parabola through the SAD minimum and its two neighbours, per axis (|offset| <= 0.5 px;
    0 at the window's edge, on a flat cost or on an exact match). keep: the integer vector
    stays the prediction (only the sub-pixel refinement; needs search >= 2)."""
    h, w = cur.shape
    nby, nbx = pred.shape[-2:]
    dev = cur.device
    r = torch.arange(block, device=dev)
    oy = (torch.arange(nby, device=dev) * block)[:, None].expand(nby, nbx).reshape(-1)
    ox = (torch.arange(nbx, device=dev) * block)[None, :].expand(nby, nbx).reshape(-1)
    cy = (oy[:, None] + r).clamp(max=h - 1)
    cx = (ox[:, None] + r).clamp(max=w - 1)
    curb = cur.reshape(-1)[(cy[:, :, None] * w + cx[:, None, :])]  # (N, b, b)
    n_off = 2 * search  # offsets -search .. search-1
    win = block + n_off - 1
    rw = torch.arange(win, device=dev)
    py = pred[1].reshape(-1).to(torch.int64)
    px = pred[0].reshape(-1).to(torch.int64)
    wy = (oy[:, None] + py[:, None] - search + rw).clamp(0, h - 1)
    wx = (ox[:, None] + px[:, None] - search + rw).clamp(0, w - 1)
    wins = prev.reshape(-1)[(wy[:, :, None] * w + wx[:, None, :])]  # (N, win, win)
    # 8-bit values: int16 differences, int32 sums (about 2x float32 on CPU)
    ci = curb.to(torch.int16)
    wi = wins.to(torch.int16)
    cost = torch.empty(ci.shape[0], n_off, n_off, dtype=torch.int32, device=dev)
    ci4 = ci[:, :, None, :]  # (N, b, 1, b)
    for dy in range(n_off):
        # every horizontal offset at once: (N, b, n_off, b) windows of the rows
        rows = wi[:, dy:dy + block, :].unfold(2, block, 1)
        cost[:, dy, :] = (rows - ci4).abs_().sum(dim=(1, 3), dtype=torch.int32)
    off = (torch.arange(n_off, device=dev) - search).abs().to(torch.int32)
    # ties go to the smallest offset (a static block stays static): exact integer keys
    cost = cost * 64 + (off[:, None] + off[None, :])  # (N, dy, dx)
    best = cost.view(cost.shape[0], -1).argmin(dim=1)
    iy = torch.div(best, n_off, rounding_mode="floor")
    ix = best % n_off
    if keep:
        iy = torch.full_like(iy, search)
        ix = torch.full_like(ix, search)
    out = torch.stack([px + ix - search, py + iy - search]).to(torch.float32)
    if subpixel:
        sad = torch.div(cost, 64, rounding_mode="floor").to(torch.float32)
        n = torch.arange(sad.shape[0], device=dev)
        for k, (i, other) in enumerate(((ix, iy), (iy, ix))):
            lo = (i - 1).clamp(min=0)
            hi = (i + 1).clamp(max=n_off - 1)
            if k == 0:
                cm, c0, cp = sad[n, other, lo], sad[n, other, i], sad[n, other, hi]
            else:
                cm, c0, cp = sad[n, lo, other], sad[n, i, other], sad[n, hi, other]
            den = cm - 2.0 * c0 + cp
            ok = (i > 0) & (i < n_off - 1) & (den > 0) & (c0 > 0)  # exact match: stays
            d = torch.where(ok, (cm - cp) / (2.0 * den).clamp(min=1e-6), torch.zeros_like(den))
            out[k] += d.clamp(-0.5, 0.5)
    return out.view(2, nby, nbx)


def block_flow(lum0: torch.Tensor, lum1: torch.Tensor, levels: int = 7, block: int = 8,
               search: int = 8, median: bool = True, subpixel: bool = False) -> torch.Tensor:
    """FfxOpticalFlow-style luminance-pyramid block matching, frame 1 -> frame 0.

    A ``levels``-level pyramid (2x2 box averages) of the 8-bit luminances; from the
    coarsest level to the finest, each block x block block of frame 1 searches integer
    offsets -search .. search-1 around twice the coarser level's vector of its parent
    block for the minimum sum of absolute differences against frame 0 (edge-replicated;
    ties to the smallest offset), then a 3x3 vector-median filter cleans the block field.

    Args:
        lum0, lum1: (1, H, W) luminance (luma8). levels >= 1, block >= 1, search >= 1.

    Returns:
        (2, ceil(H/block), ceil(W/block)) block vectors in px (1/block resolution):
        block b of frame 1 is at ``b + flow`` in frame 0.
    """
    return block_flow_chain(_block_level, lum0, lum1, levels, block, search, median, subpixel)


def block_flow_chain(level, lum0, lum1, levels=7, block=8, search=8, median=True,
                     subpixel=False, pool=None, median3=None):
    """block_flow with the per-level search given: ``level(cur, prev, pred, block, search)``
    (integer vectors, as _block_level; the numba kernel of fgcli.kernels.ops has the same
    signature), the pyramid's level function ``pool`` (default
    fgcli.ops.pyramid.avg_pool2) and the vector median ``median3`` (default
    _vector_median3). The sub-pixel refinement always runs _block_level."""
    from fgcli.ops.pyramid import avg_pool2

    pool = pool or avg_pool2
    median3 = median3 or _vector_median3
    lum0 = check_tensor(lum0, "lum0", 1, allow_batch=False)
    lum1 = check_tensor(lum1, "lum1", 1, allow_batch=False)
    check_same(lum0, "lum0", (lum1, "lum1"))
    p0 = [torch.nan_to_num(lum0, nan=0.0).clamp(0.0, 255.0).round()]
    p1 = [torch.nan_to_num(lum1, nan=0.0).clamp(0.0, 255.0).round()]
    while len(p0) < levels and min(p0[-1].shape[-2:]) >= 2 * block:
        p0.append(torch.round(pool(p0[-1])))
        p1.append(torch.round(pool(p1[-1])))
    flow = None
    for lv in range(len(p0) - 1, -1, -1):
        h, w = p0[lv].shape[-2:]
        nby, nbx = -(-h // block), -(-w // block)
        if flow is None:
            pred = torch.zeros(2, nby, nbx, device=lum0.device)
        else:
            up = flow.repeat_interleave(2, 1).repeat_interleave(2, 2)
            pred = F.pad(up, (0, max(0, nbx - up.shape[2]), 0, max(0, nby - up.shape[1])),
                         mode="replicate")[:, :nby, :nbx] * 2.0
        if lv == 0 and subpixel:
            if median:  # the median runs on the integer field; the refinement comes after
                flow = median3(level(p1[lv][0], p0[lv][0], pred, block, search))
                flow = _block_level(p1[lv][0], p0[lv][0], flow, block, 2, subpixel=True,
                                    keep=True)
            else:
                flow = _block_level(p1[lv][0], p0[lv][0], pred, block, search, subpixel=True)
            break
        flow = level(p1[lv][0], p0[lv][0], pred, block, search)
        if median:
            flow = median3(flow)
    return flow


def dis_flow(lum0: torch.Tensor, lum1: torch.Tensor, preset: str = "medium") -> torch.Tensor:
    """OpenCV DIS optical flow (a stand-in for FfxOpticalFlow, labelled as such), frame 1 ->
    frame 0, full resolution. (1, H, W) 8-bit luminances -> (2, H, W) px. Images smaller
    than 32 px are edge-padded for OpenCV and cropped back."""
    import cv2
    import numpy as np

    lum0 = check_tensor(lum0, "lum0", 1, allow_batch=False)
    lum1 = check_tensor(lum1, "lum1", 1, allow_batch=False)
    check_same(lum0, "lum0", (lum1, "lum1"))
    h, w = lum0.shape[-2:]
    ph, pw = max(0, 32 - h), max(0, 32 - w)

    def u8(x):
        a = torch.nan_to_num(x[0], nan=0.0).clamp(0, 255).to(torch.uint8).cpu().numpy()
        return np.pad(a, ((0, ph), (0, pw)), mode="edge") if (ph or pw) else a

    presets = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
               "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
               "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}
    dis = cv2.DISOpticalFlow_create(presets[preset])
    f = dis.calc(u8(lum1), u8(lum0), None)[:h, :w]
    out = torch.from_numpy(np.ascontiguousarray(f.transpose(2, 0, 1))).to(lum0.device)
    return sanitize_mv(torch.nan_to_num(out, nan=0.0))


# ----------------------------------------------------------------------------- optical-flow field
# FidelityFX SDK, ffx_frameinterpolation_optical_flow_vector_field.h: the optical-flow vector
# field is built at the flow's own resolution (one texel per 8x8 block), not per pixel, and
# the interpolation pass samples it bilinearly (SampleOpticalFlowMotionVectorField).

FLOW_SMOOTH_EPS = 1e-3  # FFX_FRAMEINTERPOLATION_EPSILON


def _flow_neighbours(x: torch.Tensor):
    """The 3x3 neighbourhood of every texel of x (C, H, W), y-major from (-1, -1); texels
    outside the grid read 0 (an out-of-bounds texture load)."""
    h, w = x.shape[-2:]
    xp = F.pad(x, (1, 1, 1, 1))
    return [xp[:, dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)]


def smooth_block_flow(flow: torch.Tensor) -> torch.Tensor:
    """The SDK's 3x3 filter of the block flow before its vector field
    (computeOpticalFlowVectorField): weights ``l = max(0, 512 - |v|) * (|v| > 1)``
    (|v| in px), their weighted mean ``m``, then the mean of the nine vectors weighted by
    ``max(0, dot(m, v))^1.25 * l``; the sum itself (no division) where those weights add
    up to FLOW_SMOOTH_EPS or less, as the SDK does. A vector opposing its neighbours'
    mean gets no weight, so lone outlier blocks are voted down. fgen takes the dot
    product in px (the SDK in UV units, which makes its EPS test depend on the
    resolution: vectors of a few pixels at 1080p would sum below it and vanish).
    (2, H, W) -> (2, H, W) float32."""
    flow = check_tensor(flow, "flow", 2, allow_batch=False)
    f = sanitize_mv(flow)
    ln = _length(f, keepdim=True)
    lf = (512.0 - ln).clamp(min=0.0) * (ln > 1.0)
    vs = _flow_neighbours(f)
    ls = _flow_neighbours(lf)
    acc = torch.zeros_like(f)
    sw = torch.zeros_like(lf)
    for v, l in zip(vs, ls):
        acc = acc + v * l
        sw = sw + l
    m = torch.where(sw > 0.0, acc / sw.clamp(min=1e-30), torch.zeros_like(acc))
    acc = torch.zeros_like(f)
    sw = torch.zeros_like(lf)
    for v, l in zip(vs, ls):
        d = (m * v).sum(dim=0, keepdim=True).clamp(min=0.0)
        wt = d.pow(1.25) * l
        acc = acc + v * wt
        sw = sw + wt
    return torch.where(sw > FLOW_SMOOTH_EPS, acc / sw.clamp(min=1e-30), acc)


def _sample_points(img: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of img (C, H, W) at index positions x, y (N,) (finite), border
    clamp (a clamped texture sampler), the taps sanitised (sanitize_values) before they
    are weighted: (C, N)."""
    h, w = img.shape[-2:]
    x = x.clamp(0.0, w - 1.0)
    y = y.clamp(0.0, h - 1.0)
    x0 = torch.floor(x)
    y0 = torch.floor(y)
    fx = x - x0
    fy = y - y0
    xa = x0.to(torch.int64)
    ya = y0.to(torch.int64)
    xb = (xa + 1).clamp(max=w - 1)
    yb = (ya + 1).clamp(max=h - 1)
    flat = img.reshape(img.shape[0], -1)

    def g(yi, xi):
        return sanitize_values(flat.index_select(1, yi * w + xi))

    top = g(ya, xa) * (1.0 - fx) + g(ya, xb) * fx
    bot = g(yb, xa) * (1.0 - fx) + g(yb, xb) * fx
    return top * (1.0 - fy) + bot * fy


def flow_vector_field(color0: torch.Tensor, color1: torch.Tensor, flow: torch.Tensor,
                      alpha: float = 0.5, block: int = 8, smooth: bool = True,
                      tap_threshold: float = TAP_THRESHOLD) -> torch.Tensor:
    """FSR 3's OpticalFlowVectorField pass at the flow's resolution (the SDK's; one texel
    per block of ``block`` x ``block`` pixels).

    Texel b (grid index) stands for the block centre ``c = block * b + (block - 1) / 2``
    (px). With its vector v (px, frame 1 -> frame 0; smooth_block_flow first when
    ``smooth``) it writes the packed entry (primary, hi, lo) with an atomic max into the
    bilinear footprint (taps of weight > tap_threshold, as the game field) of
    ``b + (1 - alpha) v / block`` on the grid. hi is the SDK's magnitude priority
    ``(|v| > 1) * floor(clamp(|v| / |0.05 (W, H)|, 0, 1) * 1023)`` (vectors of 1 px or
    less write nothing), lo the colour agreement of frame 0's colour at c + v and frame
    1's at c (bilinear, luminance of the samples; 0 when c + v is off-screen). The SDK
    samples the previous frame at c and the current one at c + v, which is backwards for
    a frame-1 -> frame-0 vector; fgen samples as the game field does.

    Args:
        color0, color1: (3, H, W). flow: (2, ceil(H / block), ceil(W / block)) px.

    Returns:
        (2, fh, fw) int64 packed entries (x, y); 0 = not written (unpack_vector_field).
    """
    color0 = check_tensor(color0, "color0", 3, allow_batch=False)
    color1 = check_tensor(color1, "color1", 3, allow_batch=False)
    flow = check_tensor(flow, "flow", 2, allow_batch=False)
    check_same(color0, "color0", (color1, "color1"))
    a = check_alpha(alpha)
    if int(block) < 1:
        raise ValueError(f"block: expected >= 1, got {block}")
    B = int(block)
    h, w = color1.shape[-2:]
    fh, fw = flow.shape[-2:]
    if fh != -(-h // B) or fw != -(-w // B):
        raise ValueError(f"flow: expected (2, {-(-h // B)}, {-(-w // B)}) for {w}x{h} frames "
                         f"and {B}px blocks, got {tuple(flow.shape)}")
    dev = flow.device
    f = smooth_block_flow(flow) if smooth else sanitize_mv(flow)
    vf = f.reshape(2, -1)
    g = _positions(fh, fw, dev)
    c = g * float(B) + (B - 1) / 2.0
    vel = _length(vf)
    diag = 0.05 * math.hypot(w, h)
    hi = ((vel / diag).clamp(0.0, 1.0) * 1023.0).floor() * (vel > 1.0)
    hi = hi.to(torch.int64)
    s0 = _sample_points(color0, c[0] + vf[0], c[1] + vf[1])
    s1 = _sample_points(color1, c[0], c[1])
    q = c + vf
    inside = (q[0] >= -0.5) & (q[0] < w - 0.5) & (q[1] >= -0.5) & (q[1] < h - 0.5)
    lo = agreement_priority(luminance(s0[:, None]), luminance(s1[:, None]))[0, 0] * inside
    pos = g + vf * ((1.0 - a) / B)
    keys = [pack_entries(True, hi, lo, vf[k]) * (hi > 0) for k in (0, 1)]
    buf = torch.zeros(2, (fh + 2) * (fw + 2), dtype=torch.int64, device=dev)
    for idx, m in _footprint(pos, fh, fw, tap_threshold):
        for k in (0, 1):
            buf[k].scatter_reduce_(0, idx, keys[k] * m, reduce="amax")
    return _crop(buf, fh, fw).clone()


def flow_field_coords(n: int, size: int, block: int, device=None):
    """Per pixel index 0..n-1 along one axis, its bilinear taps on a grid of ``size``
    texels of ``block`` px: (i0, i1 int64, w0, w1 float32); a tap off the grid has
    weight 0 (and a clamped index). Position ``(x - (block - 1) / 2) / block``."""
    x = torch.arange(n, dtype=torch.float32, device=device)
    gx = (x - (block - 1) / 2.0) / float(block)
    x0 = torch.floor(gx)
    fx = gx - x0
    i0 = x0.to(torch.int64)
    i1 = i0 + 1
    w0 = (1.0 - fx) * ((i0 >= 0) & (i0 < size))
    w1 = fx * ((i1 >= 0) & (i1 < size))
    return i0.clamp(0, size - 1), i1.clamp(0, size - 1), w0, w1


def sample_flow_field(field: torch.Tensor, h: int, w: int, block: int = 8) -> torch.Tensor:
    """Per-pixel optical-flow vectors from the packed block field (the SDK's
    SampleOpticalFlowMotionVectorField): the bilinear mean of the four texels around the
    pixel's grid position (texels never written count as the zero vector, as the SDK
    unpacks them), the weights of taps off the grid left out and the rest normalised.
    (2, fh, fw) int64 -> (2, h, w) float32 px."""
    vec, _, _ = unpack_vector_field(field)
    fh, fw = vec.shape[-2:]
    dev = vec.device
    ya, yb, wy0, wy1 = flow_field_coords(h, fh, block, dev)
    xa, xb, wx0, wx1 = flow_field_coords(w, fw, block, dev)
    wy0, wy1 = wy0[:, None], wy1[:, None]
    wx0, wx1 = wx0[None, :], wx1[None, :]
    w00, w10, w01, w11 = wy0 * wx0, wy0 * wx1, wy1 * wx0, wy1 * wx1
    sw = ((w00 + w10) + w01) + w11
    t00 = vec[:, ya[:, None], xa[None, :]]
    t10 = vec[:, ya[:, None], xb[None, :]]
    t01 = vec[:, yb[:, None], xa[None, :]]
    t11 = vec[:, yb[:, None], xb[None, :]]
    acc = ((t00 * w00 + t10 * w10) + t01 * w01) + t11 * w11
    return torch.where(sw > 0.0, acc / sw.clamp(min=1e-30), torch.zeros_like(acc))


def upsample_block_flow(flow: torch.Tensor, h: int, w: int, block: int = 8) -> torch.Tensor:
    """Each pixel takes its block's vector: (C, nby, nbx) -> (C, h, w). (One broadcast
    copy: two repeat_interleave calls took 1.6 ms for the flow and its priority at 1080p.)"""
    c, nby, nbx = flow.shape
    up = flow[:, :, None, :, None].expand(c, nby, block, nbx, block)
    return up.reshape(c, nby * block, nbx * block)[:, :h, :w].contiguous()


# ----------------------------------------------------------------------------- masks

def _same_surface(za, zb, thr):
    """Ksep Kfov width min(za, zb) / |za - zb| >= 1 (thr = Ksep Kfov width); equal depths
    (inf == inf, 0 == 0) are the same surface."""
    diff = (za - zb).abs()
    return (za == zb) | (torch.minimum(za, zb) * thr >= diff)


def _tap_mask(depth_src, pos, depth_ref, thr):
    """Sum of the bilinear weights of on-screen taps of depth_src at pos (2, N) that are
    the same surface as depth_ref (N,), or farther (one-sided, as FSR 2's depth clip: only
    a nearer surface at the source hides the target)."""
    h, w = depth_src.shape[-2:]
    d = sanitize_depth(depth_src).reshape(-1)
    x = pos[0].clamp(-2.0, w + 1.0)
    y = pos[1].clamp(-2.0, h + 1.0)
    x0 = torch.floor(x)
    y0 = torch.floor(y)
    fx, fy = x - x0, y - y0
    acc = torch.zeros_like(x)
    for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        wt = (fx if dx else 1.0 - fx) * (fy if dy else 1.0 - fy)
        xi, yi = x0 + dx, y0 + dy
        on = (xi >= 0) & (xi <= w - 1) & (yi >= 0) & (yi <= h - 1)
        # integer index arithmetic (float32 products are exact only below 2**24 pixels)
        idx = yi.clamp(0, h - 1).to(torch.int64).mul_(w).add_(xi.clamp(0, w - 1).to(torch.int64))
        z = d[idx]
        ok = _same_surface(z, depth_ref, thr) | (z > depth_ref)
        acc += wt * (on & ok)
    return acc


def disocclusion_args(depth_t, depth_prev, depth1, vec, alpha, kfov, ksep):
    """disocclusion_masks' checked inputs: (depth_t, depth_prev, depth1, vec, alpha,
    thr = Ksep Kfov width)."""
    depth_t = check_tensor(depth_t, "depth_t", 1, allow_batch=False)
    depth_prev = check_tensor(depth_prev, "depth_prev", 1, allow_batch=False)
    depth1 = check_tensor(depth1, "depth1", 1, allow_batch=False)
    vec = check_tensor(vec, "vec", 2, allow_batch=False)
    check_same(depth_t, "depth_t", (depth_prev, "depth_prev"), (depth1, "depth1"), (vec, "vec"))
    a = check_alpha(alpha)
    return depth_t, depth_prev, depth1, vec, a, float(ksep) * float(kfov) * depth_t.shape[-1]


def disocclusion_masks(depth_t: torch.Tensor, depth_prev: torch.Tensor, depth1: torch.Tensor,
                       vec: torch.Tensor, alpha: float = 0.5, kfov: float = 1.4,
                       ksep: float = KSEP, threshold: float = 0.5):
    """FSR 3's two disocclusion masks of the interpolated frame.

    For the pixel q with vector v (the filled game field) and interpolated depth z_t(q):
    toward the previous frame the bilinear taps of the reconstructed previous depth at
    ``q + alpha v``, toward the current frame the taps of frame 1's (dilated) depth at
    ``q - (1 - alpha) v``. A tap agrees when it is the same surface,
    ``Ksep Kfov W min(z_a, z_b) / |z_a - z_b| >= 1`` (W = image width), or farther (FSR 2's
    one-sided depth clip); the mask is 1 where the agreeing taps' bilinear weight reaches
    ``threshold`` (FSR 3 stores binary masks), else 0 (disoccluded toward that frame).

    Args:
        depth_t, depth_prev, depth1: (1, H, W). vec: (2, H, W) px. alpha in [0, 1].
        kfov: camera_kfov(...). ksep: 1.37e-5.

    Returns:
        (mask_prev, mask_cur): (1, H, W) float32 in {0, 1}.
    """
    depth_t, depth_prev, depth1, vec, a, thr = disocclusion_args(depth_t, depth_prev, depth1,
                                                                  vec, alpha, kfov, ksep)
    h, w = depth_t.shape[-2:]
    v = sanitize_mv(vec).reshape(2, -1)
    p = _positions(h, w, vec.device)
    zt = sanitize_depth(depth_t).reshape(-1)
    mp = _tap_mask(depth_prev, p + v * a, zt, thr) >= threshold
    mc = _tap_mask(depth1, p - v * (1.0 - a), zt, thr) >= threshold
    return mp.view(1, h, w).float(), mc.view(1, h, w).float()


# ----------------------------------------------------------------------------- interpolation

def color_similarity(a: torch.Tensor, b: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """FSR 3's colour similarity ``dot(a/m, b/m)``, m = max(|a|, |b|) (RGB lengths):
    1 for equal colours (both black included, m <= eps), smaller as they differ.
    (3, H, W) x2 -> (1, H, W).

    Computed as ``dot(a, b) / max(|a|^2, |b|^2)`` (the denominator clamped to eps): no
    square root, which torch's CPU kernels (MKL) do not round correctly, so a compiled
    kernel could not repeat it bit for bit."""
    sa = (a * a).sum(dim=0, keepdim=True)
    sb = (b * b).sum(dim=0, keepdim=True)
    m2 = torch.maximum(sa, sb)
    s = (a * b).sum(dim=0, keepdim=True) / m2.clamp(min=eps)
    return torch.where(m2 <= eps * eps, torch.ones_like(s), s)


def encode_display(x: torch.Tensor) -> torch.Tensor:
    """Linear -> display-encoded "back buffer" values: the sRGB OETF extended above 1
    (``1.055 x^(1/2.4) - 0.055`` without clipping, so HDR values survive the round trip);
    negatives -> 0."""
    x = x.clamp(min=0.0)
    hi = 1.055 * x.clamp(min=0.0031308).pow(1 / 2.4) - 0.055
    return torch.where(x <= 0.0031308, x * 12.92, hi)


def decode_display(v: torch.Tensor) -> torch.Tensor:
    """Inverse of encode_display."""
    v = v.clamp(min=0.0)
    return torch.where(v <= 0.04045, v / 12.92, ((v.clamp(min=0.04045) + 0.055) / 1.055).pow(2.4))


def interpolate_args(color0, color1, vec, alpha, of_vec, space):
    """interpolate_fsr3's checked inputs: (color0, color1, vec, of_vec, alpha)."""
    color0 = check_tensor(color0, "color0", 3, allow_batch=False)
    color1 = check_tensor(color1, "color1", 3, allow_batch=False)
    vec = check_tensor(vec, "vec", 2, allow_batch=False)
    if of_vec is not None:
        of_vec = check_tensor(of_vec, "of_vec", 2, allow_batch=False)
    check_same(color0, "color0", (color1, "color1"), (vec, "vec"), (of_vec, "of_vec"))
    if space not in ("linear", "display"):
        raise ValueError(f"space: expected 'linear' or 'display', got {space!r}")
    return color0, color1, vec, of_vec, check_alpha(alpha)


def interpolate_fsr3(color0: torch.Tensor, color1: torch.Tensor, vec: torch.Tensor,
                     mask_prev: torch.Tensor, mask_cur: torch.Tensor, alpha: float = 0.5,
                     of_vec: torch.Tensor | None = None, space: str = "linear"):
    """FSR 3 interpolation pass.

    Game path: ``P = color0(q + alpha v)``, ``C = color1(q - (1 - alpha) v)`` (bilinear),
    masks x = mask_prev and y = mask_cur (0 also where the sample is off-screen),
    ``t = alpha + (1 - alpha)(1 - x) - alpha (1 - y)`` clamped to [0, 1] (FSR 3's
    ``0.5 + 0.5(1-x) - 0.5(1-y)`` at alpha = 0.5), ``C_game = lerp(P, C, t)``. With optical
    flow the same with its vectors gives C_of (same t), and with the similarities
    S = color_similarity of each path's two samples, ``bias = clamp(S_game / S_of, 0, 1)``
    and the output is ``lerp(C_of, C_game, bias)`` (the better-matching pair wins). Where
    exactly one mask is 0 the game path resolved a disocclusion by depth, its two samples
    differ by construction, and bias is 1 (fgen's reading: the similarity rule is meant for
    pixels both frames see). Pixels with both masks 0 are holes (for inpainting).

    Args:
        color0, color1: (3, H, W). vec, of_vec: (2, H, W) px (frame 1 -> frame 0).
        mask_prev, mask_cur: (1, H, W) in [0, 1]. alpha in [0, 1].

    Returns:
        (color (3, H, W), holes (1, H, W) bool, bias (1, H, W) float: 1 = game vectors).
    """
    color0, color1, vec, of_vec, a = interpolate_args(color0, color1, vec, alpha, of_vec, space)
    if space == "display":
        color0 = encode_display(sanitize_values(color0))
        color1 = encode_display(sanitize_values(color1))
    v = sanitize_mv(vec)
    P, in0 = backward_warp(color0, v * a)
    C, in1 = backward_warp(color1, v * -(1.0 - a))
    x = mask_prev * in0
    y = mask_cur * in1
    t = (a + (1.0 - a) * (1.0 - x) - a * (1.0 - y)).clamp(0.0, 1.0)
    out = torch.lerp(P, C, t)
    holes = (x <= 0) & (y <= 0)
    bias = torch.ones_like(t)
    if of_vec is not None:
        o = sanitize_mv(of_vec)
        Po, _ = backward_warp(color0, o * a)
        Co, _ = backward_warp(color1, o * -(1.0 - a))
        c_of = torch.lerp(Po, Co, t)
        s_game = color_similarity(P, C)
        s_of = color_similarity(Po, Co)
        bias = torch.where(s_of > 0, s_game / s_of.clamp(min=1e-6), torch.ones_like(s_of))
        bias = torch.nan_to_num(bias, nan=1.0).clamp(0.0, 1.0)
        bias = torch.where((x > 0) != (y > 0), torch.ones_like(bias), bias)
        out = torch.lerp(c_of, out, bias)
    if space == "display":
        out = decode_display(out)
    return sanitize_values(out), holes, bias


def output_vectors(vec: torch.Tensor, scale: float) -> torch.Tensor:
    """The generated frame's motion vectors: sanitize_mv(vec) * scale, a new tensor (the
    interpolation stage's game vectors scaled to the previous output time)."""
    vec = check_tensor(vec, "vec", 2, allow_batch=False)
    return sanitize_mv(vec) * float(scale)


def interpolated_depth(depth_t: torch.Tensor, vec: torch.Tensor, alpha: float = 0.5,
                       depth0: torch.Tensor | None = None,
                       depth1: torch.Tensor | None = None) -> torch.Tensor:
    """The generated frame's depth: the reconstructed interpolated depth, and where nothing
    was splatted (+inf: holes and sky) the nearer of frame 0's depth at ``q + alpha v`` and
    frame 1's at ``q - (1 - alpha) v`` (nearest pixel), when both frames' depths are given.
    (1, H, W), vec (2, H, W) px -> (1, H, W)."""
    from fgcli.ops.warp import sample_nearest

    a = check_alpha(alpha)
    vec = sanitize_mv(vec)
    depth = sanitize_depth(depth_t)
    if depth0 is not None and depth1 is not None and (not reads_back(depth)
                                                      or bool(torch.isinf(depth).any())):
        d0, _ = sample_nearest(sanitize_depth(depth0), vec * a)
        d1, _ = sample_nearest(sanitize_depth(depth1), vec * -(1.0 - a))
        depth = torch.where(torch.isinf(depth), torch.minimum(d0, d1), depth)
    return depth


def inpaint_color(color: torch.Tensor, holes: torch.Tensor, decay: float = 10.0, pool=None,
                  inpaint=None, in_place: bool = False):
    """FSR 3 colour inpainting: hole pixels take pyramid_inpaint mode 'blend' of the valid
    interpolated colour (level weights (1 - i/10)^3). (3, H, W), (1, H, W) bool -> (3, H, W).
    inpaint: pyramid_inpaint or a function with its signature (the numba backend's).
    in_place: the caller gives color up (the numba backend may fill the holes in it; a new
    tensor here always)."""
    out, _ = (inpaint or pyramid_inpaint)(color, (~holes).to(torch.float32), holes,
                                          mode="blend", decay=decay, pool=pool)
    return out
