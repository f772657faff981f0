"""Tiny analytic scenes for the ops tests (not used at run time)."""
from __future__ import annotations

import torch


def moving_square(t: float, h: int = 24, w: int = 40, size: int = 6, x1: int = 20,
                  y1: int = 8, v: int = 4, bg_depth: float = 10.0, fg_depth: float = 2.0,
                  seed: int = 0):
    """Frame at time t of a textured static background and a bright HDR square moving
    right by v px per frame; at t = 1 its left column is x1. Returns (color (3, H, W),
    depth (1, H, W), mv (2, H, W)); mv is the exact backward motion (-v, 0) on the square,
    0 elsewhere. v * (1 - t) must be an integer (no partial coverage)."""
    g = torch.Generator().manual_seed(seed)
    bg = torch.rand(3, h, w, generator=g)
    fg = torch.tensor([5.0, 0.2, 0.1])[:, None, None] * (1 + 0.3 * torch.rand(1, size, size,
                                                                            generator=g))
    xs = x1 - v * (1 - t)
    if abs(xs - round(xs)) > 1e-9:
        raise ValueError("v * (1 - t) must be an integer")
    xs = int(round(xs))
    c = bg.clone()
    d = torch.full((1, h, w), float(bg_depth))
    mv = torch.zeros(2, h, w)
    a, b = max(xs, 0), min(xs + size, w)
    if b > a:
        c[:, y1:y1 + size, a:b] = fg[:, :, a - xs:b - xs]
        d[:, y1:y1 + size, a:b] = fg_depth
        mv[0, y1:y1 + size, a:b] = -v
    return c, d, mv
