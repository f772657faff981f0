"""Mob-FGSR refinement of splatted motion ("gap fill") and extrapolation hole filling."""
from __future__ import annotations

import torch
import torch.nn.functional as F

from fgcli.ops._util import (ALPHA_MAX, INF_BITS, aux, check_alpha, check_choice,
                             check_same, check_tensor, reads_back, sanitize_depth,
                             sanitize_mv)
from fgcli.ops.splat import SplatResult

# 3x3 neighbours in row-major order, centre excluded: indices 0..7 = shader 0,1,2,3,5,6,7,8
_NEIGH = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]
# the four 2x2 blocks that contain the centre, as neighbour indices (plus the centre)
_BLOCKS = [(0, 1, 3), (1, 2, 4), (3, 5, 6), (4, 6, 7)]


def _check_result(result):
    if not isinstance(result, SplatResult):
        raise TypeError(f"result: expected a SplatResult, got {type(result).__name__}")


def _minpool3(d):
    """3x3 minimum of (H, W) with out-of-image neighbours ignored (separable)."""
    h, w = d.shape
    inf = float("inf")
    dp = F.pad(d[None, None], (1, 1, 0, 0), value=inf)[0, 0]
    row = torch.minimum(dp[:, 0:w], dp[:, 1:w + 1])
    torch.minimum(row, dp[:, 2:w + 2], out=row)
    rp = F.pad(row[None, None], (0, 0, 1, 1), value=inf)[0, 0]
    out = torch.minimum(rp[0:h], rp[1:h + 1])
    return torch.minimum(out, rp[2:h + 2], out=out)


def _shifted(x: torch.Tensor, pad_value) -> torch.Tensor:
    """(C, H, W) -> (8, C, H, W): the 8 neighbours of every pixel in _NEIGH order, pixels
    outside the image reading pad_value."""
    c, h, w = x.shape
    p = torch.full((c, h + 2, w + 2), pad_value, dtype=x.dtype, device=x.device)
    p[:, 1:h + 1, 1:w + 1] = x
    return torch.stack([p[:, 1 + dy:1 + dy + h, 1 + dx:1 + dx + w] for dy, dx in _NEIGH])


def _gap_inputs(res: SplatResult):
    """(h, w, valid (H, W), hole (H, W), d (H, W): the sanitised splat depth, +inf at
    holes) of one frame's splat."""
    h, w = res.depth.shape[-2:]
    valid = res.valid[0]
    hole = ~valid
    d = sanitize_depth(res.depth)[0]
    if not reads_back(hole) or bool(hole.any()):
        d = d.masked_fill(hole, float("inf"))
    return h, w, valid, hole, d


def _gap_fill_dense(res: SplatResult, thr, fill, fallback_mv, fallback_depth):
    """_gap_fill_frame for every pixel at once, with no value read back to the host (the
    CUDA path; see reads_back). Same rule and arithmetic; pixels the rule leaves alone keep
    their values through exact selects."""
    h, w, valid, hole, d = _gap_inputs(res)
    n = h * w
    dev = res.depth.device
    susp = (_minpool3(d) < d * (1.0 - thr)).logical_or_(hole)
    dn = _shifted(d.contiguous().view(torch.int32)[None], INF_BITS)[:, 0]  # (8, H, W)
    vn = _shifted(valid[None], False)[:, 0]
    limit = d * (1.0 - thr)
    cand = vn & ((dn.view(torch.float32) < limit[None]) | hole[None])
    nc = ~cand
    keep = torch.zeros_like(hole)
    for i, j, k in _BLOCKS:
        keep |= nc[i] & nc[j] & nc[k]
    sel = susp & ~keep
    key = dn.masked_fill(nc, 0x7FFFFFFF)
    k = key.argmin(dim=0)  # nearest candidate; ties -> first in row-major order
    # neighbour k of _NEIGH sits at j = k + (k >= 4) of the 3x3 window (no host list: a
    # tensor made from one would be a blocking copy to the GPU)
    j = k.view(-1) + (k.view(-1) >= 4).to(k.dtype)
    off = torch.div(j, 3, rounding_mode="floor").sub_(1).mul_(w).add_(j.remainder(3).sub_(1))
    srcpix = (aux(h, w, dev)["ar64"] + off).clamp_(0, n - 1)
    has0 = res.to0 is not None
    t1 = res.to1.reshape(2, -1)
    t0 = res.to0.reshape(2, -1) if has0 else None
    selv = sel.view(1, h, w)
    if fill == "nearest":
        n1 = t1[:, srcpix].view(2, h, w)
        n0 = t0[:, srcpix].view(2, h, w) if has0 else None
    else:  # mean of the candidates' vectors
        wgt = cand.to(torch.float32)[:, None]  # (8, 1, H, W)
        cnt = wgt.sum(0)
        n1 = (_shifted(res.to1, 0.0) * wgt).sum(0) / cnt
        n0 = (_shifted(res.to0, 0.0) * wgt).sum(0) / cnt if has0 else None
    to1 = torch.where(selv, n1, res.to1)
    to0 = torch.where(selv, n0, res.to0) if has0 else None
    depth = torch.where(selv, d.view(-1)[srcpix].view(1, h, w), d[None])
    source = torch.where(selv, res.source.reshape(-1)[srcpix].view(1, h, w), res.source)
    filled = selv
    new_valid = valid[None] | filled
    holes = ~new_valid
    if fallback_mv is not None:
        m = sanitize_mv(fallback_mv)
        a = res.alpha
        c1, c0 = (-(1.0 - a), a) if res.mode == "interp" else (a, 1.0 + a)
        to1 = torch.where(holes, m * c1, to1)
        if has0:
            to0 = torch.where(holes, m * c0, to0)
        if fallback_depth is not None:
            depth = torch.where(holes, sanitize_depth(fallback_depth), depth)
    return res.replace(to1=to1, to0=to0, depth=depth, valid=new_valid, source=source,
                       filled=filled, holes=holes)


def _gap_fill_frame(res: SplatResult, thr, fill, fallback_mv, fallback_depth):
    if not reads_back(res.depth):
        return _gap_fill_dense(res, thr, fill, fallback_mv, fallback_depth)
    h, w, valid, hole, d = _gap_inputs(res)
    n = h * w
    dev = res.depth.device
    has0 = res.to0 is not None
    to1 = res.to1.clone()
    to0 = res.to0.clone() if has0 else None
    depth = d.clone()[None]
    source = res.source.clone()
    filled = torch.zeros((1, h, w), dtype=torch.bool, device=dev)
    # empty pixels, and pixels with a valid neighbour nearer by more than the threshold
    susp = (_minpool3(d) < d * (1.0 - thr)).logical_or_(hole)
    idx = susp.view(-1).nonzero().squeeze(1)
    if idx.numel():
        dbits = d.contiguous().view(torch.int32).view(-1)
        vflat = valid.reshape(-1)
        offu = torch.tensor([dy * w + dx for dy, dx in _NEIGH], device=dev)
        ody = torch.tensor([dy for dy, _ in _NEIGH], device=dev)
        odx = torch.tensor([dx for _, dx in _NEIGH], device=dev)
        y = torch.div(idx, w, rounding_mode="floor")
        x = idx - y * w
        ny = y[:, None] + ody[None, :]  # (M, 8)
        nx = x[:, None] + odx[None, :]
        inb = (ny >= 0) & (ny < h) & (nx >= 0) & (nx < w)
        nb = (ny.clamp_(0, h - 1) * w).add_(nx.clamp_(0, w - 1))
        # out-of-image neighbours: depth +inf and invalid, never candidates
        dn = dbits[nb].masked_fill_(~inb, INF_BITS)  # (M, 8) int32 depth bits
        vn = vflat[nb] & inb
        dc = d.view(-1)[idx]
        hc = hole.view(-1)[idx]
        limit = dc * (1.0 - thr)
        cand = vn & ((dn.view(torch.float32) < limit[:, None]) | hc[:, None])
        nc = ~cand
        keep = torch.zeros_like(hc)
        for i, j, k in _BLOCKS:
            keep |= nc[:, i] & nc[:, j] & nc[:, k]
        sel = ~keep
        if bool(sel.any()):
            tgt = idx[sel]
            c_sel = cand[sel]
            # non-candidates get a key above +inf so argmin never picks them
            key = dn[sel].masked_fill(~c_sel, 0x7FFFFFFF)
            k = key.argmin(dim=1)  # nearest candidate; ties -> first in row-major order
            srcpix = tgt + offu[k]
            pairs = [(to1, res.to1.reshape(2, -1))]
            if has0:
                pairs.append((to0, res.to0.reshape(2, -1)))
            if fill == "nearest":
                for dst, srcf in pairs:
                    dst.view(2, -1)[:, tgt] = srcf[:, srcpix]
            else:  # mean of the candidates' vectors (the paper's "mean filter")
                nbu = (tgt[:, None] + offu[None, :]).clamp_(0, n - 1)  # OOB: not candidates
                wgt = c_sel.to(torch.float32)
                cnt = wgt.sum(1)
                for dst, srcf in pairs:
                    vals = srcf[:, nbu]  # (2, S, 8)
                    dst.view(2, -1)[:, tgt] = (vals * wgt[None]).sum(2) / cnt[None]
            depth.view(-1)[tgt] = d.view(-1)[srcpix]
            source.view(-1)[tgt] = res.source.reshape(-1)[srcpix]
            filled.view(-1)[tgt] = True
    new_valid = valid[None] | filled
    holes = ~new_valid
    if fallback_mv is not None:
        hidx = holes.view(-1).nonzero().squeeze(1)
        if hidx.numel():
            m = sanitize_mv(fallback_mv).reshape(2, -1)[:, hidx]
            a = res.alpha
            c1, c0 = (-(1.0 - a), a) if res.mode == "interp" else (a, 1.0 + a)
            to1.view(2, -1)[:, hidx] = m * c1
            if has0:
                to0.view(2, -1)[:, hidx] = m * c0
            if fallback_depth is not None:
                depth.view(-1)[hidx] = sanitize_depth(fallback_depth).reshape(-1)[hidx]
    return res.replace(to1=to1, to0=to0, depth=depth, valid=new_valid, source=source,
                       filled=filled, holes=holes)


def gap_fill_args(result, depth_threshold_rel, fallback_mv, fallback_depth):
    """Validated threshold and fallbacks of gap_fill (shared by the numba kernel's
    wrapper): (depth_threshold_rel, fallback_mv, fallback_depth)."""
    thr = check_alpha(depth_threshold_rel, "depth_threshold_rel", 0.0, 1.0)
    if fallback_mv is not None:
        fallback_mv = check_tensor(fallback_mv, "fallback_mv", 2)
        check_same(result.depth, "result.depth", (fallback_mv, "fallback_mv"))
    if fallback_depth is not None:
        fallback_depth = check_tensor(fallback_depth, "fallback_depth", 1)
        check_same(result.depth, "result.depth", (fallback_depth, "fallback_depth"))
    return thr, fallback_mv, fallback_depth


def gap_fill(result: SplatResult, depth_threshold_rel: float = 0.01, fill: str = "nearest",
             fallback_mv: torch.Tensor | None = None,
             fallback_depth: torch.Tensor | None = None, in_place: bool = False) -> SplatResult:
    """Mob-FGSR refinement of splatted motion: fill grid-like cracks, keep disocclusions.

    For each empty or suspicious target pixel q, its 3x3 neighbours that are valid and
    nearer than q by more than ``depth_threshold_rel`` (``d_n < d_q (1 - rel)``; for an
    empty q every valid neighbour) are *candidates*; the others (including out-of-image
    neighbours and q itself) are "similar". If the similar pixels contain a 2x2 block that
    includes q, q is kept (an edge, a slope, or a genuine hole); otherwise q is a crack in
    a nearer surface and takes the vectors (to1, to0), depth and source of the nearest
    candidate (``fill='nearest'``, as the public Mob-FGSR code) or the mean of the
    candidates' vectors with the nearest candidate's depth (``fill='mean'``, the paper's
    wording). One pass, reading only pre-fill values (like the GPU version).

    Pixels still empty afterwards are ``holes``. If ``fallback_mv`` (2, H, W) is given
    they take linear motion along that field *at q* (the public code uses frame 0's
    vectors, "the previous vector", for interpolation):
      * interp: ``to0 = alpha * m(q)``, ``to1 = -(1 - alpha) * m(q)``;
      * extrap: ``to1 = alpha * m(q)``, ``to0 = (1 + alpha) * m(q)``;
    and ``depth = fallback_depth(q)`` when given (else +inf). Holes stay ``valid=False``.
    Without fallback_mv holes keep zero vectors (use extrap_hole_fill for extrapolation).

    Args:
        result: SplatResult from splat_motion (per-frame or batched).
        depth_threshold_rel: relative depth margin (default 0.01 = 1 %; the public code
            uses 0.0005 on [0, 1] device depth).
        fill: 'nearest' | 'mean'.
        fallback_mv, fallback_depth: (2, H, W), (1, H, W) [batched like result] or None.
        in_place: the caller gives up ``result``: where it is scratch (SplatResult.scratch)
            an implementation may write the refinement into its planes (the numba kernel
            does; this reference always returns new ones).

    Returns:
        A new SplatResult with to1, to0, depth, valid, source updated, ``filled`` (1, H, W)
        bool = pixels changed by the refinement, ``holes`` (1, H, W) bool = pixels with no
        splatted or refined vector.
    """
    _check_result(result)
    check_choice(fill, "fill", ("nearest", "mean"))
    thr, fallback_mv, fallback_depth = gap_fill_args(result, depth_threshold_rel, fallback_mv,
                                                     fallback_depth)
    if result.depth.dim() == 4:
        return SplatResult.stack([
            _gap_fill_frame(result.frame(i), thr, fill,
                            None if fallback_mv is None else fallback_mv[i],
                            None if fallback_depth is None else fallback_depth[i])
            for i in range(result.depth.shape[0])])
    return _gap_fill_frame(result, thr, fill, fallback_mv, fallback_depth)


def _pixel_xy(h: int, w: int, device):
    """(x, y) float32 index coordinates of every pixel, (H, W) each."""
    x = torch.arange(w, device=device, dtype=torch.float32)[None].expand(h, w)
    y = torch.arange(h, device=device, dtype=torch.float32)[:, None].expand(h, w)
    return x, y


def _extrap_fill_dense(mv1, depth1, to1, valid, depth_target, alpha, thr):
    """_extrap_fill_frame for every pixel at once, no read-back (the CUDA path)."""
    h, w = depth1.shape[-2:]
    hole = ~valid.reshape(1, h, w)
    d1 = sanitize_depth(depth1).reshape(-1)
    m = sanitize_mv(mv1).reshape(2, h, w) * alpha
    x, y = _pixel_xy(h, w, depth1.device)
    sx = x + m[0]
    sy = y + m[1]
    inside = (sx >= -0.5) & (sx < w - 0.5) & (sy >= -0.5) & (sy < h - 0.5)
    ix = torch.floor(sx + 0.5).clamp_(0, w - 1).to(torch.int64)
    iy = torch.floor(sy + 0.5).clamp_(0, h - 1).to(torch.int64)
    ds = d1[iy * w + ix]
    do = d1.view(h, w)
    bg = inside & ~(ds < do * (1.0 - thr))
    new1 = torch.where(bg[None], m, torch.zeros_like(m))
    to1 = torch.where(hole, new1, to1)
    depth = torch.where(hole, torch.where(bg, ds, do)[None], sanitize_depth(depth_target))
    return to1, depth, hole.clone()


def _extrap_fill_frame(mv1, depth1, to1, valid, depth_target, alpha, thr):
    if not reads_back(depth1):
        return _extrap_fill_dense(mv1, depth1, to1, valid, depth_target, alpha, thr)
    h, w = depth1.shape[-2:]
    to1 = to1.clone()
    depth = sanitize_depth(depth_target).clone()
    hole = ~valid.reshape(-1)
    idx = hole.nonzero().squeeze(1)
    filled = hole.view(1, h, w).clone()
    if idx.numel() == 0:
        return to1, depth, filled
    d1 = sanitize_depth(depth1).reshape(-1)
    m = sanitize_mv(mv1).reshape(2, -1)[:, idx] * alpha  # (2, M)
    y = torch.div(idx, w, rounding_mode="floor")
    x = idx - y * w
    sx = x.to(torch.float32) + m[0]
    sy = y.to(torch.float32) + m[1]
    inside = (sx >= -0.5) & (sx < w - 0.5) & (sy >= -0.5) & (sy < h - 0.5)
    ix = torch.floor(sx + 0.5).clamp_(0, w - 1).to(torch.int64)
    iy = torch.floor(sy + 0.5).clamp_(0, h - 1).to(torch.int64)
    ds = d1[iy * w + ix]
    do = d1[idx]
    # background = the sample is not nearer than the origin pixel (frame 1 at q)
    bg = inside & ~(ds < do * (1.0 - thr))
    to1.view(2, -1)[:, idx] = torch.where(bg[None], m, torch.zeros_like(m))
    depth.view(-1)[idx] = torch.where(bg, ds, do)
    return to1, depth, filled


def extrap_hole_fill(mv1: torch.Tensor, depth1: torch.Tensor, to1: torch.Tensor,
                     valid: torch.Tensor, depth_target: torch.Tensor, alpha: float,
                     depth_threshold_rel: float = 1e-3):
    """Mob-FGSR extrapolation hole rule ("disocclusion filling" with frame 1's vectors).

    For each hole q (``valid`` False) of the extrapolated frame at time 1 + alpha: take
    frame 1's vector at the same pixel, m = mv1(q), and read frame 1's depth at the pixel
    nearest ``q + alpha * m`` (a point behind q along that motion). If that depth is
    background, i.e. not nearer than the origin depth1(q) (``d_s >= d_o (1 - rel)``), the
    hole takes that motion, ``to1 = alpha * m`` (sample frame 1 at q + alpha m, the
    background the moving object uncovers); otherwise (nearer, or off-screen) zero motion,
    ``to1 = 0``. Matches the public Mob-FGSR Warp_E pass.

    Args:
        mv1: (2, H, W) frame-1 vectors. depth1: (1, H, W) frame-1 depth (the one the splat
            used, usually dilated). to1: (2, H, W) splatted/refined offsets to frame 1.
        valid: (1, H, W) bool, False at holes. depth_target: (1, H, W) splatted depth.
        alpha: extrapolation distance (0 ... 1e6). depth_threshold_rel: relative margin.
        (All may carry a leading batch dim.)

    Returns:
        (to1, depth, filled): new (2, H, W) offsets, (1, H, W) depth (holes: the sampled
        background depth, or depth1(q) for zero motion), (1, H, W) bool mask of the holes
        that were filled (all of them).
    """
    mv1 = check_tensor(mv1, "mv1", 2)
    depth1 = check_tensor(depth1, "depth1", 1)
    to1 = check_tensor(to1, "to1", 2)
    valid = check_tensor(valid, "valid", 1, dtype_kind="bool")
    depth_target = check_tensor(depth_target, "depth_target", 1)
    check_same(mv1, "mv1", (depth1, "depth1"), (to1, "to1"), (valid, "valid"),
               (depth_target, "depth_target"))
    a = check_alpha(alpha, hi=ALPHA_MAX)
    thr = check_alpha(depth_threshold_rel, "depth_threshold_rel", 0.0, 1.0)
    if mv1.dim() == 4:
        outs = [_extrap_fill_frame(mv1[i], depth1[i], to1[i], valid[i], depth_target[i], a, thr)
                for i in range(mv1.shape[0])]
        return tuple(torch.stack([o[k] for o in outs]) for k in range(3))
    return _extrap_fill_frame(mv1, depth1, to1, valid, depth_target, a, thr)


def fill_extrap_holes(result: SplatResult, mv1: torch.Tensor, depth1: torch.Tensor,
                      depth_threshold_rel: float = 1e-3, in_place: bool = False) -> SplatResult:
    """extrap_hole_fill applied to a SplatResult (mode 'extrap'); returns a new result.

    Hole pixels (``result.valid`` False) get to1 and depth from extrap_hole_fill and
    ``to0 = to1 + mv1(q + to1)`` (nearest fetch; a result without to0 keeps None);
    ``valid`` is unchanged, ``holes`` is set to the filled pixels. in_place: as gap_fill's
    (this reference always returns new planes).
    """
    _check_result(result)
    if result.mode != "extrap":
        raise ValueError(f"fill_extrap_holes: needs an 'extrap' SplatResult, got {result.mode!r}")
    to1, depth, filled = extrap_hole_fill(mv1, depth1, result.to1, result.valid, result.depth,
                                          result.alpha, depth_threshold_rel)
    if result.to0 is None:  # (splat_motion(toward0=False): frame 1's offsets only)
        return result.replace(to1=to1, depth=depth, holes=filled)
    mv1 = sanitize_mv(check_tensor(mv1, "mv1", 2))
    to0 = result.to0.clone()
    frames = [(to0, to1, mv1, filled)] if to1.dim() == 3 else \
        [(to0[i], to1[i], mv1[i], filled[i]) for i in range(to1.shape[0])]
    for t0, t1, m, f in frames:  # to0 = to1 + mv1(q + to1) at the filled holes only
        h, w = t1.shape[-2:]
        if not reads_back(t1):  # every pixel, then an exact select (no read-back)
            x, y = _pixel_xy(h, w, t1.device)
            ix = (x + t1[0] + 0.5).floor_().clamp_(0, w - 1).long()
            iy = (y + t1[1] + 0.5).floor_().clamp_(0, h - 1).long()
            v = t1 + m.reshape(2, -1)[:, (iy * w + ix).view(-1)].view(2, h, w)
            t0.copy_(torch.where(f.view(1, h, w), v, t0))
            continue
        hidx = f.view(-1).nonzero().squeeze(1)
        if hidx.numel() == 0:
            continue
        y = torch.div(hidx, w, rounding_mode="floor")
        x = hidx - y * w
        v = t1.reshape(2, -1)[:, hidx]
        ix = (x.to(torch.float32) + v[0] + 0.5).floor_().clamp_(0, w - 1).long()
        iy = (y.to(torch.float32) + v[1] + 0.5).floor_().clamp_(0, h - 1).long()
        t0.view(2, -1)[:, hidx] = v + m.reshape(2, -1)[:, iy * w + ix]
    return result.replace(to1=to1, to0=to0, depth=depth, holes=filled)
