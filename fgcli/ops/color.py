"""Colour transforms used for blending decisions and metrics. Work on torch tensors and
numpy arrays alike (same type out as in), channel-first (3, H, W) where channels matter.
Inputs are never modified; NaN reads as 0 and +inf as the clip maximum."""
from __future__ import annotations

import math

import numpy as np
import torch

REC709_LUMA = (0.2126, 0.7152, 0.0722)


def _is_torch(x) -> bool:
    return isinstance(x, torch.Tensor)


def _clip01(x):
    if _is_torch(x):
        return torch.nan_to_num(x.float(), nan=0.0, posinf=1.0, neginf=0.0).clamp_(0.0, 1.0)
    return np.clip(np.nan_to_num(np.asarray(x, dtype=np.float32), nan=0.0, posinf=1.0,
                                 neginf=0.0), 0.0, 1.0)


def srgb_oetf(x):
    """sRGB encoding (IEC 61966-2-1) of clip(x, 0, 1): linear light -> display value.

    ``12.92 x`` for x <= 0.0031308, else ``1.055 x^(1/2.4) - 0.055``. Any shape.
    (Computed as the minimum of the two branches, which equals the piecewise definition
    because the power branch is concave and below the line above the threshold.)
    """
    c = _clip01(x)
    t = 0.0031308
    if _is_torch(c):
        p = c.clamp(min=t).pow_(1.0 / 2.4)
        hi = (p - 1.0).mul_(0.055).add_(p)  # == 1.055 p - 0.055, exactly 1 at p = 1
        return torch.minimum(hi, c.mul_(12.92), out=hi).clamp_(0.0, 1.0)
    p = np.power(np.maximum(c, t), 1.0 / 2.4)
    hi = p + 0.055 * (p - 1.0)
    return np.clip(np.minimum(hi, c * 12.92), 0.0, 1.0).astype(np.float32)


def srgb_eotf(v):
    """Inverse of srgb_oetf on [0, 1]: display value -> linear light. Any shape."""
    c = _clip01(v)
    if _is_torch(c):
        hi = ((c + 0.055) / 1.055).pow_(2.4)
        return torch.where(c <= 0.04045, c / 12.92, hi)
    hi = np.power((c + 0.055) / 1.055, 2.4)
    return np.where(c <= 0.04045, c / 12.92, hi).astype(np.float32)


def mulaw(x, mu: float = 5000.0, peak: float = 1.0):
    """mu-law tone curve for HDR comparisons: ``log(1 + mu y) / log(1 + mu)`` with
    ``y = clip(x / peak, 0, 1)``. peak = the linear value mapped to 1 (default 1.0; set it
    to the scene's white, e.g. 100, to keep highlights). Any shape; output in [0, 1]."""
    if not (mu > 0 and math.isfinite(mu)):
        raise ValueError(f"mu: must be positive and finite, got {mu!r}")
    if not (peak > 0 and math.isfinite(peak)):
        raise ValueError(f"peak: must be positive and finite, got {peak!r}")
    y = _clip01(x / peak if peak != 1.0 else x)
    if _is_torch(y):
        return torch.log1p(y * mu) / math.log1p(mu)
    return (np.log1p(y * mu) / math.log1p(mu)).astype(np.float32)


def luminance(x):
    """Rec. 709 luminance of a (3, H, W) or (B, 3, H, W) colour -> (1, H, W) / (B, 1, H, W).
    (numpy: (3, H, W) -> (1, H, W).) No clipping."""
    if x.shape[-3] != 3:
        raise ValueError(f"luminance: expected 3 channels in dim -3, got shape {tuple(x.shape)}")
    r, g, b = REC709_LUMA
    return x[..., 0:1, :, :] * r + x[..., 1:2, :, :] * g + x[..., 2:3, :, :] * b


DISPLAY_TRANSFORMS = ("srgb", "mulaw", "none")


def to_display(x, transform: str = "srgb", mu: float = 5000.0, peak: float = 1.0):
    """Display-referred colour for metrics: 'srgb' (sRGB OETF of clip(x, 0, 1), the
    default of docs/design.md section 4), 'mulaw' (see mulaw) or 'none' (x as is, assumed
    already display-referred in [0, 1]; only NaN/inf are cleaned)."""
    if transform == "srgb":
        return srgb_oetf(x)
    if transform == "mulaw":
        return mulaw(x, mu, peak)
    if transform in ("none", None):
        if _is_torch(x):
            return torch.nan_to_num(x.float(), nan=0.0, posinf=1.0, neginf=0.0)
        return np.nan_to_num(np.asarray(x, dtype=np.float32), nan=0.0, posinf=1.0, neginf=0.0)
    raise ValueError(f"transform: expected one of {DISPLAY_TRANSFORMS}, got {transform!r}")
