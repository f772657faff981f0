"""Pyramid (mip-chain) hole filling: the inpainting op shared by fsr3-interp and gffe-extrap.

Shared op: FSR 3 fills the holes of its game-vector field and of its interpolated colour
with it (fgcli/stages/fsr3.py), and gffe-extrap's remaining holes use it too. Keep its
behaviour stable; add modes rather than change one.

A weighted mip chain of an image: level 0 is ``(w * v, w)`` (premultiplied by a per-pixel
weight, 0 = hole), each coarser level the 2x2 box average of the finer one (odd sizes: the
last row/column averages what exists). The ratio ``sum(w v) / sum(w)`` of a coarse texel is
the weighted mean of its valid children, so holes never leak into the average. A hole pixel
then reads the coarser levels bilinearly at its own position (pixel centres at
integer + 0.5, levels scaled by exactly 2**i):

* mode ``"first"`` (FSR 3's vector-field inpainting): the first coarser level whose
  bilinear taps hold any weight; the taps are weighted by bilinear weight x pixel weight
  (FSR 3: the vector's priority).
* mode ``"blend"`` (FSR 3's colour inpainting): ``sum_i m_i (w v)_i / sum_i m_i w_i`` over
  levels i >= 1 with ``m_i = max(0, 1 - i/decay)**3`` (FSR 3: decay = 10); where those
  levels hold no weight at all (a hole wider than 2**decay px) the "first" rule applies.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F

from fgcli.ops._util import (check_choice, check_same, check_tensor, reads_back,
                             sanitize_values)

PYRAMID_MODES = ("first", "blend")


def avg_pool2(x: torch.Tensor) -> torch.Tensor:
    """One coarser level: 2x2 box averages, (C, H, W) -> (C, ceil(H/2), ceil(W/2)) (the
    last row / column of an odd size averages what exists)."""
    return F.avg_pool2d(x[None], 2, ceil_mode=True)[0]


def weighted_pyramid(values: torch.Tensor, weight: torch.Tensor,
                     levels: int | None = None, pool=None) -> list[torch.Tensor]:
    """Premultiplied mip chain.

    Args:
        values: (C, H, W) float (NaN/inf sanitised: NaN -> 0, inf -> 1e30).
        weight: (1, H, W) float >= 0 (negative/NaN read as 0).
        levels: number of levels including level 0 (default: down to 1x1).
        pool: the level function (default avg_pool2; the numba backend passes its kernel,
            fgcli.kernels.ops.avg_pool2, which gives the same values).

    Returns:
        list of (C + 1, h_i, w_i) tensors, h_i = ceil(H / 2**i): channels ``w * v`` then
        ``w`` (box averages).
    """
    values = check_tensor(values, "values", allow_batch=False)
    weight = check_tensor(weight, "weight", 1, allow_batch=False)
    check_same(values, "values", (weight, "weight"))
    w = torch.nan_to_num(weight, nan=0.0, posinf=0.0).clamp_(min=0.0)
    v = sanitize_values(values)
    lev = [torch.cat([v * w, w], 0)]
    h, wd = values.shape[-2:]
    while (h > 1 or wd > 1) and (levels is None or len(lev) < levels):
        lev.append((pool or avg_pool2)(lev[-1]))
        h, wd = lev[-1].shape[-2:]
    return lev


def _sample_level(level: torch.Tensor, i: int, xs: torch.Tensor, ys: torch.Tensor):
    """Bilinear sample of level i at full-resolution index coords (xs, ys) (N,) -> (C+1, N)."""
    h, w = level.shape[-2:]
    s = float(2 ** i)
    gx = (xs + 0.5) / s / w * 2.0 - 1.0
    gy = (ys + 0.5) / s / h * 2.0 - 1.0
    g = torch.stack([gx, gy], -1).view(1, 1, -1, 2)
    return F.grid_sample(level[None], g, mode="bilinear", padding_mode="border",
                         align_corners=False)[0, :, 0]


def pyramid_inpaint(values: torch.Tensor, weight: torch.Tensor,
                    holes: torch.Tensor | None = None, mode: str = "blend",
                    decay: float = 10.0, eps: float = 1e-12, pool=None):
    """Fill holes of an image from a weighted mip pyramid (see the module docstring).

    Args:
        values: (C, H, W) image; values at holes are ignored.
        weight: (1, H, W) >= 0 per-pixel weight; 0 marks a pixel without data.
        holes: (1, H, W) bool, the pixels to fill (default: weight == 0).
        mode: 'blend' (FSR 3 colour inpainting, level weights (1 - i/decay)^3) or 'first'
            (FSR 3 vector-field inpainting: first coarser level with data).
        decay: > 0, the level-weight falloff of 'blend'.
        pool: the pyramid's level function (see weighted_pyramid).

    Returns:
        (out (C, H, W), filled (1, H, W) bool): out equals the (sanitised) input outside
        holes; a hole takes the pyramid value; holes without any data in the whole image
        are 0 with filled False. Always finite. Cost: the pyramid (4/3 of one pass over the
        image) plus a gather per level at the hole pixels only.
    """
    values, weight, holes = checked_inpaint_args(values, weight, holes, mode, decay)
    c, h, w = values.shape
    wclean = torch.nan_to_num(weight, nan=0.0, posinf=0.0).clamp_(min=0.0)
    if holes is None:
        holes = wclean <= 0
    out = sanitize_values(values).clone()
    dense = not reads_back(holes)  # GPU: every pixel, every level, then a select
    idx = (torch.arange(h * w, device=values.device) if dense
           else holes.view(-1).nonzero().view(-1))
    if idx.numel() == 0:
        return out, torch.zeros(1, h, w, dtype=torch.bool, device=values.device)
    w_ = wclean.masked_fill(holes, 0.0)
    lev = weighted_pyramid(values, w_, pool=pool)
    return fill_from_levels(out, holes, idx, lev, mode, decay, eps, dense)


def checked_inpaint_args(values, weight, holes, mode, decay):
    """pyramid_inpaint's argument checks: (values, weight, holes or None)."""
    values = check_tensor(values, "values", allow_batch=False)
    weight = check_tensor(weight, "weight", 1, allow_batch=False)
    check_same(values, "values", (weight, "weight"))
    check_choice(mode, "mode", PYRAMID_MODES)
    if not (decay > 0):
        raise ValueError(f"decay: expected > 0, got {decay!r}")
    if holes is not None:
        holes = check_tensor(holes, "holes", 1, allow_batch=False, dtype_kind="bool")
        check_same(values, "values", (holes, "holes"))
    return values, weight, holes


def fill_from_levels(out, holes, idx, lev, mode="blend", decay=10.0, eps=1e-12,
                     dense=False, sample=None):
    """pyramid_inpaint's second half: the hole pixels (flat indices idx, or every pixel
    when dense) read the levels 1.. of lev (level 0 is not read: it may be None) into out
    (C, H, W, written in place unless dense). sample: _sample_level or a function with its
    signature and values (the numba backend's). Returns (out, filled)."""
    sample = sample or _sample_level
    c, h, w = out.shape
    filled = torch.zeros(1, h, w, dtype=torch.bool, device=out.device)
    ys = torch.div(idx, w, rounding_mode="floor").to(torch.float32)
    xs = (idx % w).to(torch.float32)
    n = idx.numel()
    res = torch.zeros(c, n, dtype=torch.float32, device=out.device)
    done = torch.zeros(n, dtype=torch.bool, device=out.device)
    if mode == "blend":
        acc = torch.zeros(c + 1, n, dtype=torch.float32, device=out.device)
        for i in range(1, len(lev)):
            m = max(0.0, 1.0 - i / decay) ** 3
            if m <= 0.0:
                break
            acc.add_(sample(lev[i], i, xs, ys), alpha=m)
        ok = acc[c] > eps
        res = torch.where(ok[None], acc[:c] / acc[c:].clamp(min=eps), res)
        done = ok
    for i in range(1, len(lev)):
        if not dense and bool(done.all()):
            break
        s = sample(lev[i], i, xs, ys)
        ok = (s[c] > eps) & ~done
        res = torch.where(ok[None], s[:c] / s[c:].clamp(min=eps), res)
        done = done | ok
    res = sanitize_values(res)
    if dense:
        hv = holes.view(1, h, w)
        return (torch.where(hv, res.view(c, h, w), out),
                hv & done.view(1, h, w))
    flat = out.view(c, -1)
    flat[:, idx] = res
    filled.view(-1)[idx] = done
    return out, filled
