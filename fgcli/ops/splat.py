"""Mob-FGSR motion splatting: nearest-depth dilation and depth-aware forward splatting of
motion to a generated time (interpolation at alpha, extrapolation at 1 + alpha).

Frames: "1" is the newer rendered frame (time 1), "0" the older (time 0). mv1 = frame 1's
vectors (toward frame 0), mv0 = frame 0's vectors (toward frame -1); fgen convention,
``prev_xy = xy + mv``. All positions below are index coordinates (pixel centre of column x
is x); displacements are the same in pixel coordinates.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields, replace

import torch

from fgcli.ops._util import (ALPHA_MAX, EXACT_F32, aux, check_alpha, check_choice,
                             check_same, check_tensor, gather_pixels, inside_mask,
                             nearest_index, sanitize_depth, sanitize_mv)

I64_MAX = (1 << 63) - 1


# ----------------------------------------------------------------------------- dilation

def _dilate_frame(depth, mv, radius):
    h, w = depth.shape[-2:]
    d = sanitize_depth(depth)[0].contiguous()
    mv = sanitize_mv(mv)
    if radius == 0:
        return d[None].clone(), mv.clone()
    r = radius
    a = aux(h, w, d.device)
    # key = float32 bits of the (non-negative) depth << 32 | flat index: the minimum over
    # a window is the nearest pixel, ties going to the lowest index; separable min.
    key = _pack_key(d, a).view(h, w)
    # (F.pad would round an int64 fill value through float)
    kp = torch.full((h, w + 2 * r), I64_MAX, dtype=torch.int64, device=d.device)
    kp[:, r:r + w] = key
    rowmin = kp[:, 0:w].clone()
    for k in range(1, 2 * r + 1):
        torch.minimum(rowmin, kp[:, k:k + w], out=rowmin)
    kp = torch.full((h + 2 * r, w), I64_MAX, dtype=torch.int64, device=d.device)
    kp[r:r + h] = rowmin
    best = kp[0:h].clone()
    for k in range(1, 2 * r + 1):
        torch.minimum(best, kp[k:k + h], out=best)
    halves = best.view(torch.int32).view(h, w, 2)  # little-endian: [low, high]
    nearest_bits = halves[..., 1]
    idx = halves[..., 0].contiguous()
    # ties with the centre pixel keep the centre (FSR 2 / Mob-FGSR iterate from the centre)
    centre = nearest_bits == d.view(torch.int32)
    idx = torch.where(centre, a["ar32"].view(h, w), idx)
    depth_d = nearest_bits.contiguous().view(torch.float32)[None]
    mv_d = gather_pixels(mv, idx.view(-1)).view(2, h, w)
    return depth_d, mv_d


def dilate_nearest_depth(depth: torch.Tensor, mv: torch.Tensor, radius: int = 1):
    """Nearest-depth dilation (FSR 2 / Mob-FGSR pre-pass).

    Each pixel takes the depth and the motion vector of the nearest (smallest depth) pixel
    of its (2r+1) x (2r+1) window, so the vectors of thin or edge foreground pixels cover
    their silhouette. Ties go to the centre pixel, then to the lowest flat index (first in
    row-major order; deterministic). Out-of-image neighbours are ignored. Sky (+inf) never
    wins over geometry; an all-sky window keeps the centre. NaN vectors read as 0.

    Args:
        depth: (1, H, W) or (B, 1, H, W) linear depth (> 0, +inf sky). NaN is read as +inf
            and negative values as 0 (see sanitize_depth).
        mv: (2, H, W) or (B, 2, H, W) motion vectors, pixels.
        radius: window radius r >= 0 (1 = 3x3; 0 returns copies).

    Returns:
        (depth_d (1, H, W), mv_d (2, H, W)) [batched alike], new tensors.
    """
    depth = check_tensor(depth, "depth", 1)
    mv = check_tensor(mv, "mv", 2)
    check_same(depth, "depth", (mv, "mv"))
    if not isinstance(radius, int) or isinstance(radius, bool) or radius < 0:
        raise ValueError(f"radius: expected an int >= 0, got {radius!r}")
    if depth.dim() == 4:
        outs = [_dilate_frame(depth[i], mv[i], radius) for i in range(depth.shape[0])]
        return torch.stack([o[0] for o in outs]), torch.stack([o[1] for o in outs])
    return _dilate_frame(depth, mv, radius)


# ----------------------------------------------------------------------------- splat

@dataclass
class SplatResult:
    """Motion of a generated frame, as produced by splat_motion (and refined by gap_fill,
    extrap_hole_fill). Per-frame shapes; batched results carry a leading B.

    to1: (2, H, W) offset from target pixel q to the matching position in frame 1:
        sample frame 1 at ``q + to1``. For a splatted pixel it is ``p1 - p_t`` of the
        winning source pixel p1 (p_t = its position at the target time), i.e. the
        surface's exact sub-pixel motion, not ``p1 - q``. 0 where not valid.
    to0: (2, H, W) offset from q to the position in frame 0: ``to1 + a`` with
        a = mv1(p1) (interpolation and extrapolation alike). 0 where not valid. None when
        the splat was asked for frame 1's offsets only (``splat_motion(toward0=False)``:
        extrapolation, where no stage samples frame 0); gap_fill and fill_extrap_holes
        keep it None.
    depth: (1, H, W) frame-1 depth of the winning surface (not interpolated in time);
        +inf where nothing splatted.
    valid: (1, H, W) bool: the target received a splat (after gap_fill: or was filled
        from a neighbour).
    source: (1, H, W) int32 flat index (y * W + x) in frame 1 of the source pixel; -1 none.
    alpha: the generated time is alpha (mode 'interp') or 1 + alpha ('extrap').
    mode: 'interp' or 'extrap'.
    filled: (1, H, W) bool or None: pixels changed by gap filling (refinement).
    holes: (1, H, W) bool or None: pixels that had no vector after refinement (and took the
        fallback rule, if any).
    scratch: True when no one else holds the planes (the numba kernels' fresh outputs): a
        refinement called with ``in_place=True`` (gap_fill, fill_extrap_holes) may then
        write into them instead of copying them, and the result it was given is spent
        (scratch False, planes overwritten). ``replace`` clears it unless told otherwise: a
        replaced result shares planes with the one it came from.
    """

    to1: torch.Tensor
    to0: torch.Tensor | None
    depth: torch.Tensor
    valid: torch.Tensor
    source: torch.Tensor
    alpha: float
    mode: str
    filled: torch.Tensor | None = None
    holes: torch.Tensor | None = None
    scratch: bool = field(default=False, compare=False)  # (ownership, not a value)

    def replace(self, **kw) -> "SplatResult":
        kw.setdefault("scratch", False)
        return replace(self, **kw)

    def frame(self, i: int) -> "SplatResult":
        """The i-th frame of a batched result."""
        kw = {f.name: (getattr(self, f.name)[i] if isinstance(getattr(self, f.name), torch.Tensor)
                       else getattr(self, f.name)) for f in fields(self)}
        return SplatResult(**dict(kw, scratch=False))  # (views of the batch)

    @staticmethod
    def stack(results) -> "SplatResult":
        kw = {}
        for f in fields(SplatResult):
            vals = [getattr(r, f.name) for r in results]
            if isinstance(vals[0], torch.Tensor):
                kw[f.name] = torch.stack(vals)
            else:
                kw[f.name] = vals[0]
        return SplatResult(**dict(kw, scratch=False))


def motion_coefficients(alpha: float, model: str, mode: str) -> tuple[float, float]:
    """(cA, cB) with ``p_t - p1 = cA * a + cB * b`` (a = mv1(p1), b = mv0(p1 + a)).

    interp, time alpha:   quadratic cA = (1-alpha)(2+alpha)/2, cB = -alpha(1-alpha)/2;
                          linear    cA = 1 - alpha,              cB = 0.
    extrap, time 1+alpha: quadratic cA = -alpha(3+alpha)/2,      cB = alpha(1+alpha)/2;
                          linear    cA = -alpha,                 cB = 0.
    """
    a = float(alpha)
    if mode == "interp":
        if model == "quadratic":
            return (1.0 - a) * (2.0 + a) / 2.0, -a * (1.0 - a) / 2.0
        return 1.0 - a, 0.0
    if model == "quadratic":
        return -a * (3.0 + a) / 2.0, a * (1.0 + a) / 2.0
    return -a, 0.0


def _pack_key(d, ax):
    """int64 keys ``float32_bits(d) << 32 | flat_index`` for a non-negative (1, H, W) depth
    without NaN, written through an int32 view (two strided copies)."""
    n = d.numel()
    key = torch.empty(n, dtype=torch.int64, device=d.device)
    k32 = key.view(torch.int32).view(n, 2)  # little-endian: [low, high]
    k32[:, 0] = ax["ar32"]
    k32[:, 1] = d.reshape(-1).view(torch.int32)
    return key


def _splat_frame(depth1, mv1, mv0, alpha, model, mode, depth0=None, depth0_tol=0.05,
                 toward0=True):
    h, w = depth1.shape[-2:]
    n = h * w
    dev = depth1.device
    ax = aux(h, w, dev)
    d = sanitize_depth(depth1).contiguous()
    a = sanitize_mv(mv1)
    ca, cb = motion_coefficients(alpha, model if mv0 is not None else "linear", mode)
    if cb != 0.0:
        # b = frame 0's vector where the surface was in frame 0 (nearest pixel, as the
        # public code's splat pass); linear where that is off-screen or another surface
        idx0 = nearest_index(a, h, w)
        use = inside_mask(a, h, w)
        b = gather_pixels(sanitize_mv(mv0), idx0).view(2, h, w)
        if depth0 is not None:
            d0s = gather_pixels(sanitize_depth(depth0), idx0).view(h, w)
            d1s = d[0]
            same = (d0s == d1s).logical_or_(
                (d0s - d1s).abs_() <= torch.minimum(d0s, d1s).mul_(depth0_tol))
            use.logical_and_(same)
        b = torch.lerp(a, b, use.to(torch.float32))  # exact 0/1 select, values finite
        disp = b.mul_(cb).add_(a, alpha=ca)
    else:
        disp = a * ca
    # target pixel (nearest to p1 + disp, ties round up), clamped into a one-pixel ring
    # around the image that collects everything off-screen and is discarded
    w2, h2 = w + 2, h + 2
    qx = torch.add(disp[0], ax["xh"]).floor_().clamp_(-1, w).add_(1)
    qy = torch.add(disp[1], ax["yh"]).floor_().clamp_(-1, h).add_(1)
    if h2 * w2 < EXACT_F32:
        q = qy.mul_(w2).add_(qx).view(-1).to(torch.int64)
    else:
        q = qy.to(torch.int64).mul_(w2).add_(qx.to(torch.int64)).view(-1)
    # key: float32 bits of the (non-negative) depth are monotonic in the depth, +inf
    # included; the low 32 bits carry the source index (nearest surface wins, ties go to
    # the lowest index, deterministically)
    key = _pack_key(d, ax)
    buf = torch.full((h2 * w2,), I64_MAX, dtype=torch.int64, device=dev)
    buf.scatter_reduce_(0, q, key, reduce="amin", include_self=True)
    win = buf.view(h2, w2)[1:h + 1, 1:w + 1]
    halves = win.view(torch.int32).view(h, w, 2)  # little-endian: [low, high]
    src = halves[..., 0].contiguous()  # -1 (low word of I64_MAX) where nothing landed
    valid = src >= 0
    # high word: depth bits; NaN (0x7FFFFFFF) exactly where nothing landed -> +inf
    inf = float("inf")
    depth_t = torch.nan_to_num(halves[..., 1].contiguous().view(torch.float32),
                               nan=inf, posinf=inf)[None]
    # per-source offsets to frame 1 and frame 0, with one trailing zero entry that the
    # empty targets (src = -1 -> n) read
    s1 = torch.empty((2, n + 1), dtype=torch.float32, device=dev)
    s1[:, n] = 0.0
    torch.neg(disp.view(2, n), out=s1[:, :n])  # p1 - p_t
    gi = src.view(-1).remainder(n + 1)
    to1 = gather_pixels(s1, gi).view(2, h, w)
    to0 = None
    if toward0:
        s0 = torch.empty((2, n + 1), dtype=torch.float32, device=dev)
        s0[:, n] = 0.0
        torch.sub(a.reshape(2, n), disp.view(2, n), out=s0[:, :n])  # p1 + a - p_t
        to0 = gather_pixels(s0, gi).view(2, h, w)
    return SplatResult(to1=to1, to0=to0, depth=depth_t, valid=valid[None], source=src[None],
                       alpha=float(alpha), mode=mode)


def splat_args(depth1, mv1, mv0, alpha, model, mode, depth0, depth0_tol_rel):
    """Validated arguments of splat_motion (shared by the numba kernel's wrapper):
    (depth1, mv1, mv0, depth0, depth0_tol_rel, alpha)."""
    depth1 = check_tensor(depth1, "depth1", 1)
    mv1 = check_tensor(mv1, "mv1", 2)
    if mv0 is not None:
        mv0 = check_tensor(mv0, "mv0", 2)
    if depth0 is not None:
        depth0 = check_tensor(depth0, "depth0", 1)
    check_same(depth1, "depth1", (mv1, "mv1"), (mv0, "mv0"), (depth0, "depth0"))
    tol = check_alpha(depth0_tol_rel, "depth0_tol_rel", 0.0, None)
    check_choice(model, "model", ("linear", "quadratic"))
    check_choice(mode, "mode", ("interp", "extrap"))
    a = check_alpha(alpha, hi=1.0 if mode == "interp" else ALPHA_MAX)
    return depth1, mv1, mv0, depth0, tol, a


def splat_motion(depth1: torch.Tensor, mv1: torch.Tensor, mv0: torch.Tensor | None,
                 alpha: float, model: str = "quadratic", mode: str = "interp",
                 depth0: torch.Tensor | None = None,
                 depth0_tol_rel: float = 0.05, toward0: bool = True) -> SplatResult:
    """Forward-splat frame 1's motion to the generated time (Mob-FGSR section 3.3).

    For every source pixel p1 of frame 1, with a = mv1(p1) and b = mv0(p1 + a) (frame 0's
    vector where the surface was in frame 0, nearest pixel as the public code's splat
    pass; off-screen -> b = a, i.e. linear):
      * interp, time alpha in [0, 1]:
        quadratic ``p_alpha = p1 + ((1-alpha)(2+alpha)/2) a - (alpha(1-alpha)/2) b``,
        linear ``p_alpha = p1 + (1-alpha) a``;
      * extrap, time 1 + alpha (0 <= alpha <= 1e6):
        quadratic ``p = p1 - (alpha(3+alpha)/2) a + (alpha(1+alpha)/2) b``,
        linear ``p = p1 - alpha a``.
    With mv0 None the linear model is used. b read from frame 0 may belong to another
    surface (the one that covered p1's surface in frame 0); pass ``depth0`` (frame 0's
    depth, an fgen extension, off by default as in the paper) to use b only where frame
    0's depth at p1 + a agrees with depth1(p1) within ``depth0_tol_rel`` (else linear).
    The source writes into the target pixel whose
    centre is nearest to p_t; conflicts resolve by an atomic min (scatter_reduce 'amin') of
    the int64 key ``float32_bits(depth) << 32 | source_index``: the nearest surface wins,
    ties go to the lowest source index. Sources landing off-screen are dropped.

    Args:
        depth1: (1, H, W) frame-1 depth (usually nearest-depth dilated).
        mv1: (2, H, W) frame-1 vectors (usually dilated with the depth).
        mv0: (2, H, W) frame-0 vectors, or None.
        depth0: (1, H, W) frame-0 depth or None (see above).
        alpha: see above. model: 'quadratic' | 'linear'. mode: 'interp' | 'extrap'.
        toward0: False leaves ``to0`` out (None): an extrapolation samples frame 1 only,
            and the field costs ~80 MB of memory traffic per 1080p frame through the
            splat and the fills.
        (All tensors may carry a leading batch dim B, all or none.)

    Returns:
        SplatResult (see its docstring for the exact meaning of to1, to0, depth, valid).
        ``generated_mv(result)`` gives the generated frame's own motion vectors.

    Endpoints: interp alpha = 1 puts every pixel on itself (to1 = 0, to0 = mv1);
    interp alpha = 0 puts frame-1 surfaces at their frame-0 positions with to0 = 0.
    """
    depth1, mv1, mv0, depth0, tol, a = splat_args(depth1, mv1, mv0, alpha, model, mode,
                                                  depth0, depth0_tol_rel)
    if (depth1.shape[-2] + 2) * (depth1.shape[-1] + 2) >= 2 ** 31:
        raise ValueError("splat_motion: image too large for 32-bit source indices")
    if depth1.dim() == 4:
        return SplatResult.stack([
            _splat_frame(depth1[i], mv1[i], None if mv0 is None else mv0[i], a, model, mode,
                         None if depth0 is None else depth0[i], tol, bool(toward0))
            for i in range(depth1.shape[0])])
    return _splat_frame(depth1, mv1, mv0, a, model, mode, depth0, tol, bool(toward0))


def generated_mv(result: SplatResult, copy: bool = True) -> torch.Tensor:
    """Motion vectors of the generated frame, in fgen's convention (toward the past).

    * interp (time alpha): vectors toward time 0 (the older rendered frame), ``to0``:
      ``q + mv(q)`` is where the surface at q was in frame 0. In a merged x2 sequence
      frame 0 is the previous output frame. (Vectors toward an arbitrary earlier time t
      in [0, alpha] are approximately ``to0 * (alpha - t) / alpha`` under linear motion.)
    * extrap (time 1 + alpha): vectors toward frame 1 (the previous output frame), ``to1``.

    Returns a (2, H, W) [or (B, 2, H, W)] tensor: a copy, or with ``copy=False`` the
    result's own field (for callers that never modify it in place).
    """
    if not isinstance(result, SplatResult):
        raise TypeError(f"result: expected a SplatResult, got {type(result).__name__}")
    mv = result.to0 if result.mode == "interp" else result.to1
    if mv is None:
        raise ValueError("generated_mv: an interpolation result without to0 "
                         "(splat_motion(toward0=False) is for extrapolation)")
    return mv.clone() if copy else mv
