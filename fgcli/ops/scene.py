"""Scene-change (camera cut) detection: FSR 3's histogram rule, confirmed by motion.

3x3 regional luminance histograms of the two frames, symmetric KL divergence per region;
a candidate cut when the mean divergence exceeds a threshold (FSR 3: 0.45). A histogram
difference alone cannot tell a cut from big motion (a large object crossing the frame, a
fast pan) or a global exposure change, so a candidate is confirmed only when no motion
explains the new frame (`motion_explains`): frame 0 warped by frame 1's own vectors, or by
a cheap optical flow (OpenCV DIS at low resolution), must not match frame 1 in structure.
Interpolating across a cut would smear two shots together, so the runner then repeats the
nearest frame.
"""
from __future__ import annotations

import torch

from fgcli.ops._util import check_tensor, check_same, sanitize_values

CUT_THRESHOLD = 0.45


def _linear_luma(color: torch.Tensor) -> torch.Tensor:
    """(B, 3, h, w) colour -> (B, h, w) luma of the sanitised colour clipped to [0, 1]."""
    c = sanitize_values(color).clamp(0.0, 1.0)
    return 0.2126 * c[:, 0] + 0.7152 * c[:, 1] + 0.0722 * c[:, 2]


def _luma(color: torch.Tensor) -> torch.Tensor:
    """(B, 3, h, w) colour -> (B, h, w) display-referred luma: sRGB-ish gamma of
    _linear_luma."""
    return _linear_luma(color).pow(1.0 / 2.2)


def _region_counts(luma: torch.Tensor, bins: int, regions: int) -> torch.Tensor:
    """(B, h, w) luma -> (B, regions**2, bins) float pixel counts of the luma quantised to
    `bins` levels, per region of a regions x regions grid."""
    n, h, w = luma.shape
    q = (luma * (bins - 1)).round().long()
    ry = (torch.arange(h, device=luma.device) * regions // max(h, 1)).clamp(max=regions - 1)
    rx = (torch.arange(w, device=luma.device) * regions // max(w, 1)).clamp(max=regions - 1)
    region = ry[:, None] * regions + rx[None, :]
    frame = torch.arange(n, device=luma.device)[:, None, None] * (regions * regions * bins)
    idx = (frame + region * bins + q).reshape(-1)
    hist = torch.zeros(n * regions * regions * bins, device=luma.device)
    hist.index_add_(0, idx, torch.ones_like(idx, dtype=hist.dtype))
    return hist.view(n, regions * regions, bins)


def _histograms(color: torch.Tensor, bins: int, regions: int) -> torch.Tensor:
    """(B, 3, h, w) colour -> (B, regions**2, bins) normalised luma histograms."""
    hist = _region_counts(_luma(color), bins, regions)
    return hist / hist.sum(dim=2, keepdim=True).clamp(min=1.0)


def score_stride(h: int, w: int, regions: int = 3, stride: int | None = None) -> int:
    """The pixel subsampling of scene_change_score_tensor: about 4000 samples per region
    unless given."""
    if stride is None:
        stride = int((h * w / (regions * regions) / 4000) ** 0.5)
    return max(1, int(stride))


def kl_score(h0: torch.Tensor, h1: torch.Tensor) -> torch.Tensor:
    """Mean over regions of the symmetric KL divergence of two (regions**2, bins)
    normalised histograms (0-dim tensor)."""
    eps = 1e-4
    p, q = h0 + eps, h1 + eps
    p, q = p / p.sum(1, keepdim=True), q / q.sum(1, keepdim=True)
    kl = ((p - q) * (p.log() - q.log())).sum(dim=1)  # KL(p||q) + KL(q||p)
    return kl.mean()


def scene_change_score(c0: torch.Tensor, c1: torch.Tensor, bins: int = 32,
                       regions: int = 3, stride: int | None = None) -> float:
    """Mean symmetric KL divergence between regional luminance histograms (a float; see
    scene_change_score_tensor)."""
    return float(scene_change_score_tensor(c0, c1, bins, regions, stride))


def scene_change_score_tensor(c0: torch.Tensor, c1: torch.Tensor, bins: int = 32,
                              regions: int = 3, stride: int | None = None) -> torch.Tensor:
    """Mean symmetric KL divergence between regional luminance histograms.

    c0, c1: (3, H, W) linear colour. stride subsamples pixels (default: keep about 4000
    samples per region, so 1080p costs little and small frames keep every pixel). Returns a
    0-dim tensor on the frames' device, >= 0: ~0 for consecutive frames of one shot, large
    across a cut (a tensor, so a caller on the GPU can read it back with other values in
    one transfer).
    """
    c0 = check_tensor(c0, "c0", 3, allow_batch=False)
    c1 = check_tensor(c1, "c1", 3, allow_batch=False)
    check_same(c0, "c0", (c1, "c1"))
    s = score_stride(*c0.shape[-2:], regions, stride)
    # both frames in one batch: the subsampled frames are small, so per-op overhead
    # dominates (one pass over the pair: 1.4x faster than two)
    h0, h1 = _histograms(torch.stack((c0[:, ::s, ::s], c1[:, ::s, ::s])), bins, regions)
    return kl_score(h0, h1)


def is_scene_change(c0: torch.Tensor, c1: torch.Tensor, threshold: float = CUT_THRESHOLD,
                    mv1: torch.Tensor | None = None) -> bool:
    """True when c0 and c1 are two different shots: the histogram score exceeds
    `threshold` and no motion explains c1 from c0 (confirm_cut)."""
    return confirm_cut(c0, c1, mv1, threshold)["cut"]


# Structure match at or above which motion explains the new frame (not a cut): a zero-mean,
# high-pass normalised cross-correlation, insensitive to exposure (gain and offset) and to
# the large-scale layout two unrelated shots often share (sky above, ground below).
# Measured on the bundled scenes (every consecutive pair, also with the second frame's
# exposure x0.4 / x1.5 / x2.5): 0.62-0.99; a box crossing 1/3.5 of the frame per frame
# (tests/test_scene_cut.py), exposure x1 / x2: 0.40-0.62; spliced pairs of unrelated shots
# (all 12 orderings of the bundled scenes): -0.00-0.20, including the optical-flow warp.
EXPLAINED_MIN = 0.3
FLOW_BELOW = 0.5  # try the optical flow when neither a repeat nor the vectors reach this


def _structure(color: torch.Tensor, size: int) -> torch.Tensor:
    """(h, w) high-pass display luma at about `size` pixels on the long side."""
    import torch.nn.functional as F

    c = sanitize_values(color).clamp(0.0, 1.0)
    luma = (0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]).pow(1.0 / 2.2)[None, None]
    h, w = luma.shape[-2:]
    s = max(1, max(h, w) // size)
    if s > 1:
        luma = F.avg_pool2d(luma, s, s, ceil_mode=True)
    return _highpass(luma[0, 0])


def _highpass(x: torch.Tensor) -> torch.Tensor:
    """(h, w) map minus its 7x7 box blur (edge-replicated)."""
    import torch.nn.functional as F

    x = x[None, None]
    return (x - F.avg_pool2d(F.pad(x, (3, 3, 3, 3), mode="replicate"), 7, 1))[0, 0]


def structure_match(a: torch.Tensor, b: torch.Tensor, valid: torch.Tensor | None = None) -> float:
    """Normalised cross-correlation of two (h, w) maps (over `valid`); 0 when either is flat."""
    if valid is not None:
        a, b = a[valid], b[valid]
    a, b = a.reshape(-1).double(), b.reshape(-1).double()
    if a.numel() < 16:
        return 0.0
    a, b = a - a.mean(), b - b.mean()
    den = float((a.square().sum() * b.square().sum()).sqrt())
    return float((a * b).sum()) / den if den > 1e-12 else 0.0


def motion_explains(c0: torch.Tensor, c1: torch.Tensor, mv1: torch.Tensor | None = None,
                    size: int = 256, flow: bool = True) -> dict:
    """How well motion explains frame 1 from frame 0 (a cut candidate's confirmation).

    c0, c1: (3, H, W) linear colour; mv1: (2, H, W) frame 1's vectors toward frame 0 (or
    None). Works at about `size` px on the long side. Returns {"repeat": match of c0 and c1
    as they are, "vectors": match of c0 warped by mv1 with c1 (None without vectors),
    "flow": match of c0 warped by a DIS optical flow (None when flow=False or OpenCV is
    missing), "explained": the best of them}; matches are structure_match values in [-1, 1].
    """
    import torch.nn.functional as F

    from fgcli.ops.warp import backward_warp

    c0 = check_tensor(c0, "c0", 3, allow_batch=False)
    c1 = check_tensor(c1, "c1", 3, allow_batch=False)
    check_same(c0, "c0", (c1, "c1"))
    s1 = _structure(c1, size)
    out = {"repeat": structure_match(_structure(c0, size), s1), "vectors": None, "flow": None}
    h, w = c0.shape[-2:]
    if mv1 is not None and torch.count_nonzero(mv1).item() > 0:
        warped, inside = backward_warp(c0, mv1)
        inside = inside.float()[None]
        sw = _structure(warped, size)
        if inside.shape[-2:] != sw.shape:
            inside = F.adaptive_avg_pool2d(inside, sw.shape)
        # a pixel is scored where the warp found a source; most of the frame must have one
        valid = inside[0, 0] > 0.99
        if valid.float().mean() > 0.25:
            out["vectors"] = structure_match(sw, s1, valid)
    if flow and max(out["repeat"], out["vectors"] or -1.0) < FLOW_BELOW:
        out["flow"] = _flow_match(c0, c1, size)
    out["explained"] = max(v for v in (out["repeat"], out["vectors"], out["flow"]) if v is not None)
    return out


def _flow_match(c0: torch.Tensor, c1: torch.Tensor, size: int) -> float | None:
    """structure_match after warping c0 onto c1 by OpenCV DIS flow (8-bit display luma at
    about `size` px)."""
    try:
        import cv2
    except ImportError:  # pragma: no cover - opencv is a dependency
        return None
    import numpy as np

    def lum8(c):
        c = sanitize_values(c).clamp(0.0, 1.0)
        l = (0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]).pow(1.0 / 2.2)
        h, w = l.shape
        s = max(1, max(h, w) // size)
        a = (l.cpu().numpy() * 255.0 + 0.5).astype(np.uint8)
        if s > 1:
            a = cv2.resize(a, (max(1, w // s), max(1, h // s)), interpolation=cv2.INTER_AREA)
        return a

    a, b = lum8(c0), lum8(c1)
    if min(a.shape) < 8:
        return None
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_FAST)
    f = dis.calc(b, a, None)  # for each pixel of b, where it is in a
    h, w = a.shape
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    wa = cv2.remap(a, gx + f[..., 0], gy + f[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    ta = torch.from_numpy(wa.astype(np.float32) / 255.0)
    tb = torch.from_numpy(b.astype(np.float32) / 255.0)
    return structure_match(_highpass(ta), _highpass(tb))


def confirm_cut(c0: torch.Tensor, c1: torch.Tensor, mv1: torch.Tensor | None = None,
                threshold: float = CUT_THRESHOLD, score: float | None = None) -> dict:
    """The whole rule: {"score": histogram score, "candidate": score > threshold, "cut":
    a candidate that no motion explains, "explain": motion_explains(...) for candidates}.
    score: scene_change_score(c0, c1) when the caller already has it."""
    if score is None:
        score = scene_change_score(c0, c1)
    out = {"score": score, "candidate": score > threshold, "cut": False, "explain": None}
    if out["candidate"]:
        out["explain"] = motion_explains(c0, c1, mv1)
        out["cut"] = out["explain"]["explained"] < EXPLAINED_MIN
    return out
