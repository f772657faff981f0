"""Mob-FGSR motion splatting: nearest-depth dilation and depth-aware forward splatting of
motion to a generated time (interpolation at alpha, extrapolation at 1 + alpha).

Frames: "1" is the newer rendered frame (time 1), "0" the older (time 0). mv1 = frame 1's
vectors (toward frame 0), mv0 = frame 0's vectors (toward frame -1); fgen convention,
``prev_xy = xy + mv``. All positions below are index coordinates (pixel centre of column x
is x); displacements are the same in pixel coordinates.
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace

import torch
import torch.nn.functional as F

from fgcli.ops._util import (INF_BITS, check_alpha, check_choice, check_same, check_tensor,
                             grid, sanitize_depth, sanitize_mv)

I64_MAX = (1 << 63) - 1
_LOW32 = 0xFFFFFFFF


# ----------------------------------------------------------------------------- dilation

def _dilate_frame(depth, mv, radius):
    h, w = depth.shape[-2:]
    d = sanitize_depth(depth)[0]
    if radius == 0:
        return d[None].clone(), mv.clone()
    r = radius
    dp = F.pad(d[None, None], (r, r, r, r), value=float("inf"))[0, 0]
    best = d.clone()
    choice = torch.zeros((h, w), dtype=torch.uint8, device=d.device)
    offs = [(dy, dx) for dy in range(-r, r + 1) for dx in range(-r, r + 1) if (dy, dx) != (0, 0)]
    table = [0]
    for k, (dy, dx) in enumerate(offs, 1):
        cand = dp[r + dy:r + dy + h, r + dx:r + dx + w]
        better = cand < best  # strict: the centre, then the earlier offset, wins ties
        torch.minimum(best, cand, out=best)
        choice.masked_fill_(better, k)
        table.append(dy * w + dx)
    if not bool(choice.any()):
        return best[None], mv.clone()
    tab = torch.tensor(table, dtype=torch.int64, device=d.device)
    idx = tab[choice.view(-1).long()]
    idx += torch.arange(h * w, device=d.device)
    mv_d = torch.gather(mv.reshape(2, -1), 1, idx.view(1, -1).expand(2, -1)).view(2, h, w)
    return best[None], mv_d


def dilate_nearest_depth(depth: torch.Tensor, mv: torch.Tensor, radius: int = 1):
    """Nearest-depth dilation (FSR 2 / Mob-FGSR pre-pass).

    Each pixel takes the depth and the motion vector of the nearest (smallest depth) pixel
    of its (2r+1) x (2r+1) window, so the vectors of thin or edge foreground pixels cover
    their silhouette. Ties go to the centre pixel, then to the first offset in row-major
    order (deterministic). Out-of-image neighbours are ignored. Sky (+inf) never wins over
    geometry; an all-sky window keeps the centre.

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
        a = mv1(p1) (interpolation and extrapolation alike). 0 where not valid.
    depth: (1, H, W) frame-1 depth of the winning surface (not interpolated in time);
        +inf where nothing splatted.
    valid: (1, H, W) bool: the target received a splat (after gap_fill: or was filled
        from a neighbour).
    source: (1, H, W) int64 flat index (y * W + x) in frame 1 of the source pixel; -1 none.
    alpha: the generated time is alpha (mode 'interp') or 1 + alpha ('extrap').
    mode: 'interp' or 'extrap'.
    filled: (1, H, W) bool or None: pixels changed by gap filling (refinement).
    holes: (1, H, W) bool or None: pixels that had no vector after refinement (and took the
        fallback rule, if any).
    """

    to1: torch.Tensor
    to0: torch.Tensor
    depth: torch.Tensor
    valid: torch.Tensor
    source: torch.Tensor
    alpha: float
    mode: str
    filled: torch.Tensor | None = None
    holes: torch.Tensor | None = None

    def replace(self, **kw) -> "SplatResult":
        return replace(self, **kw)

    def frame(self, i: int) -> "SplatResult":
        """The i-th frame of a batched result."""
        kw = {f.name: (getattr(self, f.name)[i] if isinstance(getattr(self, f.name), torch.Tensor)
                       else getattr(self, f.name)) for f in fields(self)}
        return SplatResult(**kw)

    @staticmethod
    def stack(results) -> "SplatResult":
        kw = {}
        for f in fields(SplatResult):
            vals = [getattr(r, f.name) for r in results]
            if isinstance(vals[0], torch.Tensor):
                kw[f.name] = torch.stack(vals)
            else:
                kw[f.name] = vals[0]
        return SplatResult(**kw)


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


def _fetch_nearest(field, px, py):
    """field (C,H,W) at index positions (px, py) (H,W), nearest pixel; + inside mask."""
    c, h, w = field.shape
    inside = (px >= -0.5) & (px < w - 0.5) & (py >= -0.5) & (py < h - 0.5)
    ix = torch.floor(px + 0.5).clamp_(0, w - 1).to(torch.int64)
    iy = torch.floor(py + 0.5).clamp_(0, h - 1).to(torch.int64)
    idx = iy.mul_(w).add_(ix).view(1, -1)
    out = torch.gather(field.reshape(c, -1), 1, idx.expand(c, -1)).view(c, h, w)
    return out, inside


def _splat_frame(depth1, mv1, mv0, alpha, model, mode, mv0_fetch, depth0=None,
                 depth0_tol=0.05):
    h, w = depth1.shape[-2:]
    n = h * w
    dev = depth1.device
    d = sanitize_depth(depth1)
    a = sanitize_mv(mv1)
    gx, gy = grid(h, w, dev)
    ca, cb = motion_coefficients(alpha, model if mv0 is not None else "linear", mode)
    if cb != 0.0:
        px = gx + a[0]
        py = gy + a[1]
        m0 = sanitize_mv(mv0)
        if mv0_fetch == "nearest":
            b, inside = _fetch_nearest(m0, px, py)
        else:
            from fgcli.ops.warp import backward_warp
            b, inside = backward_warp(m0, a, mode="bilinear", border="clamp")
            inside = inside[0]
        use_b = inside
        if depth0 is not None:  # b must belong to the same surface: depths agree
            d0s, _ = _fetch_nearest(sanitize_depth(depth0), px, py)
            d1s = d[0]
            d0s = d0s[0]
            use_b = use_b & ((d0s == d1s) | ((d0s - d1s).abs_() <= torch.minimum(d0s, d1s)
                                                                  .mul_(depth0_tol)))
        b = torch.where(use_b[None], b, a)  # frame-0 position off-screen: linear motion
        disp = a * ca
        disp.add_(b, alpha=cb)
    else:
        disp = a * ca
    # offsets from the target position to frame 1 and frame 0, per source pixel
    to1_src = -disp
    to0_src = a - disp
    tx = disp[0] + gx
    ty = disp[1] + gy
    # nearest target pixel; positions are finite (|mv| <= 1e6) so the casts are safe
    qx = torch.floor(tx.add_(0.5))
    qy = torch.floor(ty.add_(0.5))
    inb = (qx >= 0) & (qx < w) & (qy >= 0) & (qy < h)
    q = qy.to(torch.int64).mul_(w).add_(qx.to(torch.int64))
    q.masked_fill_(~inb, n)  # off-screen sources go to a dummy slot
    # key: float32 bits of the (non-negative) depth are monotonic in the depth, +inf
    # included; the low 32 bits carry the source index (nearest surface wins, ties go to
    # the lowest index, deterministically)
    key = d.view(torch.int32).to(torch.int64).clamp_(0, INF_BITS).bitwise_left_shift_(32)
    key.view(-1).add_(torch.arange(n, device=dev))
    buf = torch.full((n + 1,), I64_MAX, dtype=torch.int64, device=dev)
    buf.scatter_reduce_(0, q.view(-1), key.view(-1), reduce="amin", include_self=True)
    win = buf[:n]
    valid = win != I64_MAX
    src = win.bitwise_and(_LOW32)
    src.masked_fill_(~valid, 0)
    depth_t = win.bitwise_right_shift(32).to(torch.int32).view(torch.float32)
    depth_t = depth_t.masked_fill(~valid, float("inf")).view(1, h, w)
    gi = src.view(1, -1).expand(2, -1)
    inv = ~valid.view(1, h, w)
    to1 = torch.gather(to1_src.view(2, -1), 1, gi).view(2, h, w).masked_fill_(inv, 0.0)
    to0 = torch.gather(to0_src.view(2, -1), 1, gi).view(2, h, w).masked_fill_(inv, 0.0)
    source = src.masked_fill_(~valid, -1).view(1, h, w)
    return SplatResult(to1=to1, to0=to0, depth=depth_t, valid=valid.view(1, h, w),
                       source=source, alpha=float(alpha), mode=mode)


def splat_motion(depth1: torch.Tensor, mv1: torch.Tensor, mv0: torch.Tensor | None,
                 alpha: float, model: str = "quadratic", mode: str = "interp",
                 mv0_fetch: str = "nearest", depth0: torch.Tensor | None = None,
                 depth0_tol_rel: float = 0.05) -> SplatResult:
    """Forward-splat frame 1's motion to the generated time (Mob-FGSR section 3.3).

    For every source pixel p1 of frame 1, with a = mv1(p1) and b = mv0(p1 + a) (frame 0's
    vector where the surface was in frame 0; fetched 'nearest' (default, as the public
    code's splat pass) or 'bilinear'; off-screen -> b = a, i.e. linear):
      * interp, time alpha in [0, 1]:
        quadratic ``p_alpha = p1 + ((1-alpha)(2+alpha)/2) a - (alpha(1-alpha)/2) b``,
        linear ``p_alpha = p1 + (1-alpha) a``;
      * extrap, time 1 + alpha (alpha >= 0):
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
        (All tensors may carry a leading batch dim B, all or none.)

    Returns:
        SplatResult (see its docstring for the exact meaning of to1, to0, depth, valid).
        ``generated_mv(result)`` gives the generated frame's own motion vectors.

    Endpoints: interp alpha = 1 puts every pixel on itself (to1 = 0, to0 = mv1);
    interp alpha = 0 puts frame-1 surfaces at their frame-0 positions with to0 = 0.
    """
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
    check_choice(mv0_fetch, "mv0_fetch", ("nearest", "bilinear"))
    a = check_alpha(alpha, hi=1.0 if mode == "interp" else None)
    if depth1.shape[-2] * depth1.shape[-1] >= 2 ** 31:
        raise ValueError("splat_motion: image too large for 32-bit source indices")
    if depth1.dim() == 4:
        return SplatResult.stack([
            _splat_frame(depth1[i], mv1[i], None if mv0 is None else mv0[i], a, model, mode,
                         mv0_fetch, None if depth0 is None else depth0[i], tol)
            for i in range(depth1.shape[0])])
    return _splat_frame(depth1, mv1, mv0, a, model, mode, mv0_fetch, depth0, tol)


def generated_mv(result: SplatResult) -> torch.Tensor:
    """Motion vectors of the generated frame, in fgen's convention (toward the past).

    * interp (time alpha): vectors toward time 0 (the older rendered frame), ``to0``:
      ``q + mv(q)`` is where the surface at q was in frame 0. In a merged x2 sequence
      frame 0 is the previous output frame. (Vectors toward an arbitrary earlier time t
      in [0, alpha] are approximately ``to0 * (alpha - t) / alpha`` under linear motion.)
    * extrap (time 1 + alpha): vectors toward frame 1 (the previous output frame), ``to1``.

    Returns a (2, H, W) [or (B, 2, H, W)] tensor (a copy).
    """
    if not isinstance(result, SplatResult):
        raise TypeError(f"result: expected a SplatResult, got {type(result).__name__}")
    return (result.to0 if result.mode == "interp" else result.to1).clone()
