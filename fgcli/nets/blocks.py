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
    flow (B, 2, H, W) in pixels of img. While exporting to ONNX: the same warp as four
    gathers (warp_gather), which onnxruntime runs ~5x faster than its GridSample."""
    if torch.onnx.is_in_onnx_export():
        return warp_gather(img, flow)
    B, _, H, W = img.shape
    ys = torch.arange(H, dtype=img.dtype, device=img.device).view(1, H, 1)
    xs = torch.arange(W, dtype=img.dtype, device=img.device).view(1, 1, W)
    # align_corners=True maps -1 / +1 to the centres of the outer pixels
    gx = (xs + flow[:, 0]) * (2.0 / max(W - 1, 1)) - 1.0
    gy = (ys + flow[:, 1]) * (2.0 / max(H - 1, 1)) - 1.0
    grid = torch.stack([gx, gy], dim=-1)
    return F.grid_sample(img, grid, mode="bilinear", padding_mode="border", align_corners=True)


def warp_gather(img: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
    """warp() written as clamped coordinates, four row gathers of the channels-last image
    and the bilinear weights (the ONNX form; equal to grid_sample's align_corners=True,
    border result within float32 rounding of the coordinates, ~1e-5). One image per call
    (B = 1: the exported graph runs one frame)."""
    B, C, H, W = img.shape
    if not torch.onnx.is_in_onnx_export() and B != 1:
        return torch.cat([warp_gather(img[i:i + 1], flow[i:i + 1]) for i in range(B)])
    ys = torch.arange(H, dtype=img.dtype, device=img.device).view(1, H, 1)
    xs = torch.arange(W, dtype=img.dtype, device=img.device).view(1, 1, W)
    x = (xs + flow[:, 0]).clamp(0, W - 1)
    y = (ys + flow[:, 1]).clamp(0, H - 1)
    x0, y0 = x.floor(), y.floor()
    wx, wy = x - x0, y - y0
    x0i, y0i = x0.long(), y0.long()
    x1i, y1i = (x0i + 1).clamp(max=W - 1), (y0i + 1).clamp(max=H - 1)
    rows = img.permute(0, 2, 3, 1).reshape(H * W, C)  # one row of C channels per pixel
    wx, wy = wx.reshape(H * W, 1), wy.reshape(H * W, 1)

    def tap(yi, xi):
        return rows.index_select(0, (yi * W + xi).reshape(-1))

    top = tap(y0i, x0i) * (1 - wx) + tap(y0i, x1i) * wx
    bottom = tap(y1i, x0i) * (1 - wx) + tap(y1i, x1i) * wx
    out = top * (1 - wy) + bottom * wy  # (H * W, C), back to channels-first once
    return out.reshape(1, H, W, C).permute(0, 3, 1, 2)


# ConvTranspose2d(k=4, s=2, p=1) output phase (0 or 1 per axis) -> {tap of a 3x3 conv over
# the input: the transposed kernel's index}
_PHASE_TAPS = {0: {1: 1, 0: 3}, 1: {2: 0, 1: 2}}


def conv_transpose_as_conv(ct: nn.ConvTranspose2d, x: torch.Tensor) -> torch.Tensor:
    """ct(x) for a ConvTranspose2d(cin, cout, 4, stride 2, padding 1) computed as a 3x3
    convolution to 4 * cout channels (one per output phase) and a pixel shuffle: the same
    sums (to float32 rounding), but onnxruntime runs Conv + DepthToSpace ~3x faster than
    its ConvTranspose at full resolution (the ONNX form)."""
    w = ct.weight  # (cin, cout, 4, 4)
    cin, cout = w.shape[:2]
    rows = []
    for py in (0, 1):
        for px in (0, 1):
            k = torch.zeros(cout, cin, 3, 3, dtype=w.dtype, device=w.device)
            for a, ky in _PHASE_TAPS[py].items():
                for b, kx in _PHASE_TAPS[px].items():
                    k[:, :, a, b] = w[:, :, ky, kx].t()
            rows.append(k)
    # channel order o * 4 + py * 2 + px, as pixel_shuffle (DepthToSpace CRD) reads it
    k3 = torch.stack(rows, 1).reshape(cout * 4, cin, 3, 3)
    bias = ct.bias.repeat_interleave(4) if ct.bias is not None else None
    return F.pixel_shuffle(F.conv2d(x, k3, bias, padding=1), 2)


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
