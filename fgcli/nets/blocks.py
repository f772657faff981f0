"""Building blocks shared by fgen's networks (IFRNet-style, ALGORITHMS.md): conv + PReLU,
the residual block with a side path, backward warping with grid_sample (exports to ONNX
GridSample, opset 16+), the Charbonnier and census losses."""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def conv(cin: int, cout: int, k: int = 3, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, k, stride, k // 2), nn.PReLU(cout))


class ResBlock(nn.Module):
    """IFRNet's residual block: 5 convolutions, the last `side` channels take a side path."""

    def __init__(self, c: int, side: int):
        super().__init__()
        self.side = side
        self.c1 = conv(c, c)
        self.c2 = conv(side, side)
        self.c3 = conv(c, c)
        self.c4 = conv(side, side)
        self.c5 = nn.Conv2d(c, c, 3, 1, 1)
        self.act = nn.PReLU(c)

    def forward(self, x):
        s = self.side
        out = self.c1(x)
        out = torch.cat([out[:, :-s], self.c2(out[:, -s:])], 1)
        out = self.c3(out)
        out = torch.cat([out[:, :-s], self.c4(out[:, -s:])], 1)
        return self.act(x + self.c5(out))


def warp(img: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
    """Backward warp: out(q) = img(q + flow(q)), bilinear, border clamped. img (B, C, H, W),
    flow (B, 2, H, W) in pixels of img."""
    B, _, H, W = img.shape
    ys = torch.arange(H, dtype=img.dtype, device=img.device).view(1, H, 1)
    xs = torch.arange(W, dtype=img.dtype, device=img.device).view(1, 1, W)
    # align_corners=True maps -1 / +1 to the centres of the outer pixels
    gx = (xs + flow[:, 0]) * (2.0 / max(W - 1, 1)) - 1.0
    gy = (ys + flow[:, 1]) * (2.0 / max(H - 1, 1)) - 1.0
    grid = torch.stack([gx, gy], dim=-1)
    return F.grid_sample(img, grid, mode="bilinear", padding_mode="border", align_corners=True)


def resize_flow(flow: torch.Tensor, scale: float) -> torch.Tensor:
    """Resize a flow field by `scale` (2 = up), values scaled with it."""
    return F.interpolate(flow, scale_factor=scale, mode="bilinear", align_corners=False) * scale


def charbonnier(x: torch.Tensor, y: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    return torch.sqrt((x - y) ** 2 + eps).mean()


def _census_transform(img: torch.Tensor, patch: int = 7) -> torch.Tensor:
    g = img.mean(1, keepdim=True)
    k = torch.eye(patch * patch, dtype=img.dtype, device=img.device).view(
        patch * patch, 1, patch, patch)
    neigh = F.conv2d(g, k, padding=patch // 2)
    d = neigh - g
    return d / torch.sqrt(0.81 + d * d)


def census(x: torch.Tensor, y: torch.Tensor, patch: int = 7) -> torch.Tensor:
    """Soft Hamming distance of census transforms on 7x7 patches of the channel mean
    (IFRNet's ternary loss): t = d / sqrt(0.81 + d^2), distance dt^2 / (0.1 + dt^2)."""
    tx, ty = _census_transform(x, patch), _census_transform(y, patch)
    dt = (tx - ty) ** 2
    dist = (dt / (0.1 + dt)).mean(1, keepdim=True)
    r = patch // 2
    valid = torch.zeros_like(dist)
    valid[..., r:-r or None, r:-r or None] = 1.0
    return (dist * valid).sum() / valid.sum().clamp_min(1.0)
