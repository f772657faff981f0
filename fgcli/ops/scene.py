"""Scene-change (camera cut) detection, as FSR 3's optical-flow pass does it.

3x3 regional luminance histograms of the two frames, symmetric KL divergence per region;
a cut when the mean divergence exceeds a threshold (FSR 3: 0.45). Interpolating across a
cut would smear two shots together, so the runner then repeats the nearest frame.
"""
from __future__ import annotations

import torch

from fgcli.ops._util import check_tensor, check_same, sanitize_values

CUT_THRESHOLD = 0.45


def _histograms(color: torch.Tensor, bins: int, regions: int) -> torch.Tensor:
    # display-referred luma (sRGB-ish gamma of clip(x,0,1)) quantised to `bins` levels
    c = sanitize_values(color).clamp(0.0, 1.0)
    luma = (0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]).pow(1.0 / 2.2)
    h, w = luma.shape
    q = (luma * (bins - 1)).round().long()
    ry = (torch.arange(h, device=luma.device) * regions // max(h, 1)).clamp(max=regions - 1)
    rx = (torch.arange(w, device=luma.device) * regions // max(w, 1)).clamp(max=regions - 1)
    region = ry[:, None] * regions + rx[None, :]
    idx = (region * bins + q).reshape(-1)
    hist = torch.zeros(regions * regions * bins, device=luma.device)
    hist.index_add_(0, idx, torch.ones_like(idx, dtype=hist.dtype))
    hist = hist.view(regions * regions, bins)
    return hist / hist.sum(dim=1, keepdim=True).clamp(min=1.0)


def scene_change_score(c0: torch.Tensor, c1: torch.Tensor, bins: int = 32,
                       regions: int = 3, stride: int | None = None) -> float:
    """Mean symmetric KL divergence between regional luminance histograms.

    c0, c1: (3, H, W) linear colour. stride subsamples pixels (default: keep about 4000
    samples per region, so 1080p costs little and small frames keep every pixel). Returns a
    float >= 0: ~0 for consecutive frames of one shot, large across a cut.
    """
    c0 = check_tensor(c0, "c0", 3, allow_batch=False)
    c1 = check_tensor(c1, "c1", 3, allow_batch=False)
    check_same(c0, "c0", (c1, "c1"))
    h, w = c0.shape[-2:]
    if stride is None:
        stride = int((h * w / (regions * regions) / 4000) ** 0.5)
    s = max(1, int(stride))
    h0 = _histograms(c0[:, ::s, ::s], bins, regions)
    h1 = _histograms(c1[:, ::s, ::s], bins, regions)
    eps = 1e-4
    p, q = h0 + eps, h1 + eps
    p, q = p / p.sum(1, keepdim=True), q / q.sum(1, keepdim=True)
    kl = ((p - q) * (p.log() - q.log())).sum(dim=1)  # KL(p||q) + KL(q||p)
    return float(kl.mean())


def is_scene_change(c0: torch.Tensor, c1: torch.Tensor, threshold: float = CUT_THRESHOLD) -> bool:
    """True when c0 and c1 look like two different shots (see scene_change_score)."""
    return scene_change_score(c0, c1) > threshold
