"""Super resolution from jittered low-resolution renders: resampling, geometry upsampling,
TAA upsampling and Mob-FGSR's SR (paper Sec. 3.5).

Coordinates. A low-resolution (LR) frame (C, h, w) was rendered with a sub-pixel jitter
(jx, jy) in LR pixels: its sample (col, row) lies at (col + 0.5 + jx, row + 0.5 + jy) of
the unjittered LR grid. The high-resolution (HR) output is (C, s*h, s*w) for an integer
scale s; HR pixel (X, Y) has its centre at ((X + 0.5) / s, (Y + 0.5) / s) in LR pixel
units, i.e. at LR *sample-index* position ``u = (X + 0.5) / s - 0.5 - jx`` (and v alike),
where sample i sits at index i. Motion vectors exclude the jitter (as engines write them):
an LR vector scaled by s is the HR vector.

Every function takes torch float32 (C, H, W) tensors and returns finite values for finite
or non-finite input (NaN colour reads as 0, inf as a large finite value).
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from fgcli.ops._util import BIG, check_tensor, sanitize_depth, sanitize_mv, sanitize_values

# Mob-FGSR Eq. 2 blend constants (paper Sec. 4)
SR_A = 0.34
SR_B = 0.81
# sub-pixel phases of the Catmull-Rom look-up table (the public code's 32 x 32 x 16 LUT)
LUT_PHASES = 32


def check_scale(scale) -> int:
    s = int(scale)
    if s != scale or s < 1:
        raise ValueError(f"scale must be a positive integer, got {scale!r}")
    return s


def clean_jitter(jitter) -> tuple[float, float]:
    """(jx, jy) as finite floats in [-1, 1] LR pixels (None, NaN or inf read as 0)."""
    if jitter is None:
        return 0.0, 0.0
    out = []
    for v in jitter:
        v = float(v)
        out.append(min(1.0, max(-1.0, v)) if math.isfinite(v) else 0.0)
    return out[0], out[1]


def cr_weights(t: torch.Tensor):
    """Catmull-Rom (a = -0.5) weights of the taps at offsets -1, 0, 1, 2 for fraction t."""
    t2 = t * t
    return (t * (t * (1.0 - 0.5 * t) - 0.5), t2 * (1.5 * t - 2.5) + 1.0,
            t * (t * (2.0 - 1.5 * t) + 0.5), t2 * (0.5 * t - 0.5))


def catmull_rom_lut(phases: int = LUT_PHASES) -> torch.Tensor:
    """(phases, 4) separable Catmull-Rom tap weights at the phase centres (k + 0.5) / phases;
    the 2D table of the public code is the outer product (phases x phases x 16)."""
    t = (torch.arange(phases, dtype=torch.float64) + 0.5) / phases
    return torch.stack(cr_weights(t), dim=1).float()


def _axis_weights(frac: torch.Tensor, phases: int | None):
    if phases is None:
        return cr_weights(frac)
    lut = catmull_rom_lut(phases).to(frac.device)
    k = (frac * phases).floor_().clamp_(0, phases - 1).long()
    w = lut[k]  # (..., 4)
    return tuple(w[..., i] for i in range(4))


def resample_cubic(img: torch.Tensor, x: torch.Tensor, y: torch.Tensor,
                   phases: int | None = None, dering: bool = True) -> torch.Tensor:
    """Sample img (C, h, w) at sample-index positions x, y (each (H, W)) with 4x4
    Catmull-Rom taps, edges clamped. phases: quantise the sub-pixel fraction to that many
    phases (a look-up table, as Mob-FGSR's LUT); None = exact weights. dering: clamp each
    result to the range of its 2x2 nearest taps (no overshoot past HDR edges, no negative
    colour). Returns (C, H, W)."""
    c, h, w = img.shape
    src = sanitize_values(img)
    x = torch.nan_to_num(x, nan=0.0).clamp(-2.0, w + 1.0)
    y = torch.nan_to_num(y, nan=0.0).clamp(-2.0, h + 1.0)
    x0, y0 = x.floor(), y.floor()
    wx, wy = _axis_weights(x - x0, phases), _axis_weights(y - y0, phases)
    x0, y0 = x0.long(), y0.long()
    flat = src.reshape(c, h * w)
    out = torch.zeros((c,) + tuple(x.shape), dtype=torch.float32, device=img.device)
    lo = hi = None
    for j in range(4):
        yy = (y0 + (j - 1)).clamp_(0, h - 1) * w
        for i in range(4):
            idx = (yy + (x0 + (i - 1)).clamp_(0, w - 1)).reshape(-1)
            tap = flat[:, idx].reshape(out.shape)
            out += tap * (wx[i] * wy[j])
            if dering and i in (1, 2) and j in (1, 2):
                lo = tap.clone() if lo is None else torch.minimum(lo, tap)
                hi = tap.clone() if hi is None else torch.maximum(hi, tap)
    if dering:
        out = torch.maximum(torch.minimum(out, hi), lo)
    return sanitize_values(out)


def hr_positions(h: int, w: int, scale: int, jitter=(0.0, 0.0), device="cpu"):
    """LR sample-index positions (u, v), each (s*h, s*w), of the HR pixel centres."""
    s = check_scale(scale)
    jx, jy = clean_jitter(jitter)
    xs = (torch.arange(w * s, dtype=torch.float32, device=device) + 0.5) / s - 0.5 - jx
    ys = (torch.arange(h * s, dtype=torch.float32, device=device) + 0.5) / s - 0.5 - jy
    return xs[None, :].expand(h * s, w * s), ys[:, None].expand(h * s, w * s)


# The HR grid over an LR image is periodic: HR pixel X = s*c + p (phase p in 0..s-1) sits at
# LR sample-index position u = c + off(p), off(p) = (p + 0.5) / s - 0.5 - jx. So every
# filter whose taps and weights depend only on the fractional position is, per phase, a
# fixed set of shifted LR images with scalar weights: s^2 small passes over the LR image
# instead of per-pixel gathers at HR. (resample_cubic at hr_positions is the same filter
# evaluated per pixel.)
_PAD = 4  # covers every tap offset for |jitter| <= 1 LR pixel and 4x4 / 3x3 footprints


def _offsets(s: int, j: float) -> list[float]:
    return [(p + 0.5) / s - 0.5 - j for p in range(s)]


class _Shifted:
    """img (C, h, w) padded by _PAD (replicate: edge samples repeat, as clamped indices;
    zeros: outside reads 0); at(dy, dx) is the image shifted so that pixel (r, c) reads
    sample (r + dy, c + dx)."""

    def __init__(self, img: torch.Tensor, mode: str = "replicate"):
        self.h, self.w = img.shape[-2:]
        if mode == "replicate":
            self.p = F.pad(img[None], (_PAD,) * 4, mode="replicate")[0]
        else:
            self.p = F.pad(img, (_PAD,) * 4)

    def at(self, dy: int, dx: int) -> torch.Tensor:
        y, x = _PAD + dy, _PAD + dx
        return self.p[:, y:y + self.h, x:x + self.w]

    def rows(self, dy: int) -> torch.Tensor:
        """Shifted by dy rows, every (padded) column."""
        return self.p[:, _PAD + dy:_PAD + dy + self.h, :]


def _interleave(planes: list, s: int) -> torch.Tensor:
    """planes[py][px] (C, h, w) -> (C, s*h, s*w) with HR pixel (s*r + py, s*c + px) =
    planes[py][px][:, r, c]."""
    c, h, w = planes[0][0].shape
    out = torch.empty((c, h, s, w, s), dtype=planes[0][0].dtype, device=planes[0][0].device)
    for py in range(s):
        for px in range(s):
            out[:, :, py, :, px] = planes[py][px]
    return out.reshape(c, h * s, w * s)


def _scalar_weights(frac: float, phases: int | None) -> list[float]:
    return [float(v) for v in _axis_weights(torch.tensor(frac, dtype=torch.float32), phases)]


def upscale(color: torch.Tensor, scale: int, jitter=(0.0, 0.0),
            phases: int | None = None, dering: bool = True) -> torch.Tensor:
    """Bicubic (Catmull-Rom), jitter-aware upscale of an LR image (C, h, w) to
    (C, s*h, s*w): each HR pixel reads the 4x4 LR samples around its centre at their true
    (jittered) places, edges clamped; phases: quantised weights (Mob-FGSR's LUT); dering:
    each result clamped to the range of its 2x2 nearest samples. The same values as
    resample_cubic at hr_positions, per phase instead of per pixel."""
    color = check_tensor(color, "color", allow_batch=False)
    s = check_scale(scale)
    jx, jy = clean_jitter(jitter)
    if s == 1 and (jx, jy) == (0.0, 0.0):
        return sanitize_values(color)
    src = _Shifted(sanitize_values(color))
    planes = []
    for oy in _offsets(s, jy):
        fy = math.floor(oy)
        wy = _scalar_weights(oy - fy, phases)
        vert = sum(wy[k] * src.rows(fy + k - 1) for k in range(4))
        row = []
        for ox in _offsets(s, jx):
            fx = math.floor(ox)
            wx = _scalar_weights(ox - fx, phases)
            x0 = _PAD + fx - 1
            out = sum(wx[i] * vert[:, :, x0 + i:x0 + i + src.w] for i in range(4))
            if dering:
                taps = [src.at(fy + j, fx + i) for j in (0, 1) for i in (0, 1)]
                lo = torch.minimum(torch.minimum(taps[0], taps[1]), torch.minimum(taps[2], taps[3]))
                hi = torch.maximum(torch.maximum(taps[0], taps[1]), torch.maximum(taps[2], taps[3]))
                out = torch.maximum(torch.minimum(out, hi), lo)
            row.append(out)
        planes.append(row)
    return sanitize_values(_interleave(planes, s))


def upsample_geometry(depth: torch.Tensor, mv: torch.Tensor | None, scale: int,
                      jitter=(0.0, 0.0), extra: dict | None = None):
    """Depth and vectors at HR: each HR pixel takes the nearest surface (smallest depth) of
    the 2x2 LR samples around its centre (edges clamped), with that sample's vector scaled
    by s (never an average across an edge); a tie keeps the first of (top-left, top-right,
    bottom-left, bottom-right). extra: other per-pixel fields (normals, albedo...) taken
    from the same sample. Returns (depth (1, sH, sW), mv (2, sH, sW) or None, extra)."""
    depth = sanitize_depth(check_tensor(depth, "depth", 1, allow_batch=False))
    s = check_scale(scale)
    jx, jy = clean_jitter(jitter)
    fields = {"depth": depth}
    if mv is not None:
        fields["mv"] = sanitize_mv(mv) * float(s)
    for k, t in (extra or {}).items():
        if t is not None:
            fields[k] = t
    shifted = {k: _Shifted(t) for k, t in fields.items()}
    planes = {k: [] for k in fields}
    for oy in _offsets(s, jy):
        fy = math.floor(oy)
        rows = {k: [] for k in fields}
        for ox in _offsets(s, jx):
            fx = math.floor(ox)
            best = {k: sh.at(fy, fx) for k, sh in shifted.items()}
            for dy, dx in ((0, 1), (1, 0), (1, 1)):
                d = shifted["depth"].at(fy + dy, fx + dx)
                take = d < best["depth"]
                for k, sh in shifted.items():
                    best[k] = torch.where(take, sh.at(fy + dy, fx + dx), best[k])
            for k in fields:
                rows[k].append(best[k])
        for k in fields:
            planes[k].append(rows[k])
    out = {k: _interleave(v, s) for k, v in planes.items()}
    out_extra = {k: (out[k] if t is not None else None) for k, t in (extra or {}).items()}
    return out["depth"], out.get("mv"), out_extra


def _neighbourhood_box(color: torch.Tensor, gamma: float | None = None):
    """Per-LR-pixel min and max of its 3x3 neighbourhood (edges replicate): (C, h, w) x2.
    gamma: variance clipping, the box narrowed to mean +- gamma * standard deviation."""
    p = F.pad(color[None], (1, 1, 1, 1), mode="replicate")
    hi = F.max_pool2d(p, 3, stride=1)[0]
    lo = -F.max_pool2d(-p, 3, stride=1)[0]
    if gamma is not None:
        mu = F.avg_pool2d(p, 3, stride=1)[0]
        sd = (F.avg_pool2d(p * p, 3, stride=1)[0] - mu * mu).clamp_min(0.0).sqrt()
        lo = torch.maximum(lo, mu - gamma * sd)
        hi = torch.minimum(hi, mu + gamma * sd)
    return lo, hi


def _box_at_nearest(color_lr: torch.Tensor, s: int, jitter, gamma: float | None = None):
    """The colour box (min, max) of the 3x3 LR samples around the LR sample nearest to each
    HR pixel centre (nearest: floor(u + 0.5), edges clamped): (3, sH, sW) x2."""
    jx, jy = clean_jitter(jitter)
    lo, hi = _neighbourhood_box(color_lr, gamma)
    slo, shi = _Shifted(lo), _Shifted(hi)
    plo, phi = [], []
    for oy in _offsets(s, jy):
        ny = math.floor(oy + 0.5)
        plo.append([slo.at(ny, math.floor(ox + 0.5)) for ox in _offsets(s, jx)])
        phi.append([shi.at(ny, math.floor(ox + 0.5)) for ox in _offsets(s, jx)])
    return _interleave(plo, s), _interleave(phi, s)


def _weighted_samples(color_lr: torch.Tensor, s: int, jitter, weight):
    """sum_k w_k c_k over the 3x3 LR samples around the nearest one to each HR pixel
    centre, with w_k = weight(d_k) (d_k: distance from the sample's jittered place to the
    pixel centre, in LR pixels; samples outside the image count 0). Returns (the sum
    (3, sH, sW), the sum of the weights (1, sH, sW), the number of samples with w > 0
    (1, sH, sW))."""
    jx, jy = clean_jitter(jitter)
    h, w = color_lr.shape[-2:]
    src = _Shifted(color_lr, "zeros")
    inside = _Shifted(torch.ones((1, h, w), dtype=torch.float32, device=color_lr.device),
                      "zeros")
    acc, wsum, cnt = [], [], []
    for oy in _offsets(s, jy):
        ny = math.floor(oy + 0.5)
        ra, rw, rc = [], [], []
        for ox in _offsets(s, jx):
            nx = math.floor(ox + 0.5)
            a = torch.zeros((3, h, w), dtype=torch.float32, device=color_lr.device)
            ws = torch.zeros((1, h, w), dtype=torch.float32, device=color_lr.device)
            n = torch.zeros((1, h, w), dtype=torch.float32, device=color_lr.device)
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    d = math.hypot(ox - (nx + dx), oy - (ny + dy))
                    wt = float(weight(d))
                    if wt <= 0.0:
                        continue
                    m = inside.at(ny + dy, nx + dx)
                    a += wt * src.at(ny + dy, nx + dx)
                    ws += wt * m
                    n += m
            ra.append(a)
            rw.append(ws)
            rc.append(n)
        acc.append(ra)
        wsum.append(rw)
        cnt.append(rc)
    return _interleave(acc, s), _interleave(wsum, s), _interleave(cnt, s)


def _history(hist_color, hist_depth, depth_hr, mv_hr, t_d, filter_phases, cubic=True):
    """Warp the HR history to the current frame by the HR vectors: (colour (3,H,W), valid
    (H,W) bool, flat index (H*W,) of the history pixel nearest to each reprojected place).
    Invalid: off-screen, no history, or the history's depth at the reprojected place is a
    nearer surface (disocclusion: relative difference above t_d)."""
    _, H, W = depth_hr.shape
    dev = depth_hr.device
    gx = torch.arange(W, dtype=torch.float32, device=dev)[None, :].expand(H, W)
    gy = torch.arange(H, dtype=torch.float32, device=dev)[:, None].expand(H, W)
    px, py = gx + mv_hr[0], gy + mv_hr[1]
    inside = (px > -0.5) & (px < W - 0.5) & (py > -0.5) & (py < H - 0.5)
    if cubic:
        hc = resample_cubic(hist_color, px, py, filter_phases)
    else:
        g = torch.stack(((px + 0.5) * (2.0 / W) - 1.0, (py + 0.5) * (2.0 / H) - 1.0), -1)
        hc = F.grid_sample(sanitize_values(hist_color)[None], g[None].clamp(-2, 2),
                           mode="bilinear", padding_mode="border", align_corners=False)[0]
    ix = px.round().clamp(0, W - 1).long()
    iy = py.round().clamp(0, H - 1).long()
    # the farthest history depth of the 3x3 pixels around the reprojected place: a slanted
    # surface (a floor at a grazing angle) changes depth faster than t_d from pixel to
    # pixel, and only a surface nearer than all of them covered this one
    far = F.max_pool2d(torch.nan_to_num(hist_depth, nan=float("inf"))[None], 3, stride=1,
                       padding=1)[0]
    idx = (iy * W + ix).reshape(-1)
    hd = far.reshape(-1)[idx].reshape(H, W)
    cd = depth_hr[0]
    # disoccluded: the previous frame shows a nearer surface there (something covered this
    # one); a farther one is the same surface seen from a camera that moved toward it
    covered = hd < cd * (1.0 - t_d)
    return hc, inside & ~covered, idx


def _gaussian_samples(color_lr: torch.Tensor, scale: int, jitter, sigma: float):
    """The 3x3 LR samples around each HR pixel weighted exp(-sigma d^2) (d from the
    sample's jittered place to the pixel centre, in HR pixels): (weighted mean (3, H, W),
    sum of the weights (H, W))."""
    s = float(scale)
    acc, wsum, _ = _weighted_samples(color_lr, scale, jitter,
                                     lambda d: math.exp(-sigma * (d * s) ** 2))
    return acc / wsum.clamp_min(1e-12), wsum[0]


def taau(color_lr: torch.Tensor, depth_hr: torch.Tensor, mv_hr: torch.Tensor, scale: int,
         jitter=(0.0, 0.0), hist_color: torch.Tensor | None = None,
         hist_depth: torch.Tensor | None = None, hist_weight: torch.Tensor | None = None,
         blend: float = 0.3, t_d: float = 0.02, history_filter: str = "catmull-rom",
         sigma: float = 2.29, gamma: float | None = None, reactive: float | None = 0.25,
         current: str = "catmull-rom"):
    """One frame of TAA upsampling (UE4-style TAAU with an accumulated sample weight, as
    FSR 2 keeps one). color_lr (3, h, w) jittered LR colour; depth_hr, mv_hr: the frame's
    geometry at HR (upsample_geometry); hist_*: the previous output, its depth and its
    accumulated weight (H, W) at HR (None: no history).

    The current estimate is the jitter-aware Catmull-Rom upscale with weight 1
    (current="catmull-rom"), or the 3x3 LR samples around each HR pixel weighted
    exp(-sigma d^2) with the sum of the weights as its weight (current="gaussian"; d from
    the sample's jittered place to the pixel centre, HR pixels; 2.29: UE's Blackman-Harris
    fit). The history is reprojected by the vectors
    (history_filter: catmull-rom or bilinear), rejected off-screen or where the previous
    frame shows a nearer surface (disocclusion, relative t_d), clamped to the colour range
    of the 3x3 LR samples around the pixel, and blended by weight:
    out = (h W_h + c W_c) / (W_h + W_c), W_h capped at 1/blend - 1 (the usual exponential
    blend once converged; a plain average while the history is young). reactive: the
    history's weight falls to 0 as its brightness difference to the current estimate
    exceeds `reactive` x the spread of the 3x3 samples by 0.1 (a change of shading the
    vectors do not explain: animated textures, reflections, moving shadows; aliasing stays
    within the spread); None: off. gamma: variance clipping of the clamp box (None: min/max).
    Without valid history: the bicubic upscale. Returns (colour (3, s*h, s*w), weight
    (s*h, s*w))."""
    color_lr = sanitize_values(check_tensor(color_lr, "color", 3, allow_batch=False))
    s = check_scale(scale)
    h, w = color_lr.shape[-2:]
    if history_filter not in ("catmull-rom", "bilinear"):
        raise ValueError(f"history_filter must be catmull-rom or bilinear, got {history_filter!r}")
    if current not in ("catmull-rom", "gaussian"):
        raise ValueError(f"current must be catmull-rom or gaussian, got {current!r}")
    spatial = upscale(color_lr, s, jitter)
    H, W = h * s, w * s
    if hist_color is None or hist_depth is None or hist_weight is None:
        return spatial, torch.ones((H, W), dtype=torch.float32, device=color_lr.device)
    if current == "gaussian":
        cur, wcur = _gaussian_samples(color_lr, s, jitter, sigma)
    else:
        cur, wcur = spatial, torch.ones((H, W), dtype=torch.float32, device=color_lr.device)
    mv = sanitize_mv(mv_hr)
    hc, ok, near = _history(hist_color, hist_depth, depth_hr, mv, t_d, None,
                            cubic=history_filter == "catmull-rom")
    hw = hist_weight.reshape(-1)[near].reshape(H, W)
    hw = torch.where(ok, torch.nan_to_num(hw, nan=0.0).clamp_min(0.0), torch.zeros_like(hw))
    lo, hi = _box_at_nearest(color_lr, s, jitter, gamma)
    hcc = torch.maximum(torch.minimum(hc, hi), lo)
    if reactive is not None:
        from fgcli.ops.blend import brightness_difference

        # the history's distance to the current estimate, against the spread of the
        # samples around the pixel: aliasing moves the estimate within the spread, a
        # change of shading (animated texture, reflection) moves it out of it
        diff = brightness_difference(hc.clamp(0, BIG), cur.clamp(0, BIG))[0]
        spread = brightness_difference(hi.clamp(0, BIG), lo.clamp(0, BIG))[0]
        hw = hw * (1.0 - (diff - spread * reactive).clamp_min(0.0) / 0.1).clamp(0.0, 1.0)
    hc = hcc
    out = (hc * hw + cur * wcur) / (hw + wcur).clamp_min(1e-12)
    has = hw > 0
    out = torch.where(has[None], out, spatial)
    weight = torch.where(has, (hw + wcur).clamp(max=1.0 / blend - 1.0), torch.ones_like(hw))
    return sanitize_values(out), weight


def mobfgsr_sr(color_lr: torch.Tensor, depth_hr: torch.Tensor, mv_hr: torch.Tensor,
               scale: int, jitter=(0.0, 0.0), hist_color: torch.Tensor | None = None,
               hist_depth: torch.Tensor | None = None, a: float = SR_A, b: float = SR_B,
               t_d: float = 0.02, t_b: float = 0.13, phases: int = LUT_PHASES,
               normalize: bool = True, reactive: float | None = 0.25,
               samples: str = "lut", clamp: str = "always"):
    """Mob-FGSR super resolution of one rendered frame (paper Sec. 3.5, Eq. 2).

    The HR history is warped by the vectors with the Catmull-Rom LUT (``phases``
    sub-pixel phases, 4x4 taps) and rejected where the previous frame shows a nearer
    surface (disocclusion, relative t_d) or off-screen. It is clamped to the colour AABB of
    the 3x3 LR samples around the pixel: everywhere (clamp="always", as TAA clamps) or only
    where its brightness differs from the current frame's by more than t_b (clamp="changed",
    the paper's T_B). Then Eq. 2: q = a * c + (1 - a) q_w, with the current frame's
    estimate c either the paper's samples="eq2": sum_s (1 - b d_s) s / n over the LR samples
    s within one LR pixel of q (d_s in LR pixels; normalize: divide by the sum of the
    weights instead of the sample count n, which darkens the image by the mean weight), or
    samples="lut": the Catmull-Rom LUT resampling of the jittered input. reactive (an fgen
    addition, None: off): the history's share falls to 0 as its brightness difference to c
    exceeds `reactive` x the spread of the 3x3 samples by 0.1 (shading the vectors do not
    explain: animated textures, reflections, translucency). Where the history is rejected,
    and on the first frame: the Catmull-Rom LUT resampling. Returns (3, s*h, s*w)."""
    from fgcli.ops.blend import brightness_difference

    color_lr = sanitize_values(check_tensor(color_lr, "color", 3, allow_batch=False))
    s = check_scale(scale)
    if samples not in ("lut", "eq2"):
        raise ValueError(f"samples must be lut or eq2, got {samples!r}")
    if clamp not in ("always", "changed"):
        raise ValueError(f"clamp must be always or changed, got {clamp!r}")
    spatial = upscale(color_lr, s, jitter, phases=phases)
    if hist_color is None or hist_depth is None:
        return spatial
    if samples == "eq2":
        acc, wsum, n = _weighted_samples(color_lr, s, jitter,
                                         lambda d: 1.0 - b * d if d <= 1.0 else 0.0)
        cur = acc / (wsum if normalize else n).clamp_min(1e-6)
        cur = torch.where(n > 0, cur, spatial)
    else:
        cur = spatial
    hc, ok, _ = _history(hist_color, hist_depth, depth_hr, sanitize_mv(mv_hr), t_d, phases)
    lo, hi = _box_at_nearest(color_lr, s, jitter)
    keep = 1.0 - a
    if reactive is not None:
        diff = brightness_difference(hc.clamp(0, BIG), cur.clamp(0, BIG))[0]
        spread = brightness_difference(hi.clamp(0, BIG), lo.clamp(0, BIG))[0]
        keep = keep * (1.0 - (diff - spread * reactive).clamp_min(0.0) / 0.1).clamp(0.0, 1.0)
    hcc = torch.maximum(torch.minimum(hc, hi), lo)
    if clamp == "always":
        hc = hcc
    else:
        changed = brightness_difference(hc.clamp(0, BIG), spatial.clamp(0, BIG))[0] > t_b
        hc = torch.where(changed[None], hcc, hc)
    # a = 0 with the history dropped leaves no weight: the current estimate
    den = torch.as_tensor(a + keep, dtype=torch.float32)
    out = torch.where(den > 0, (a * cur + keep * hc) / den.clamp_min(1e-12), cur)
    return sanitize_values(torch.where(ok[None], out, spatial))
