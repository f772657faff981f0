"""Derive backward motion vectors from the previous frame's forward vectors (numpy only).

Used by the reader for layouts whose files carry only forward vectors (Nuke renders often
do). Frame t-1's forward vectors f (pixels, y down, toward t) say where each of its pixels
lands in frame t. Splatting every pixel p of t-1 to the nearest pixel q of t, with a depth
test (the nearest surface wins), gives frame t's backward vector mv(q) = -f(p). Pixels of t
that nothing lands on (disocclusions, stretching) take the vector of the nearest pixel that
was hit and are flagged invalid.
"""
from __future__ import annotations

import numpy as np


def nearest_fill(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Fill `values` (C, H, W) where `valid` (H, W) is False with the nearest valid pixel's
    value (Euclidean). Returns a new array; all zeros when nothing is valid."""
    values = np.asarray(values)
    valid = np.asarray(valid, bool)
    out = values.copy()
    if valid.all():
        return out
    if not valid.any():
        return np.zeros_like(values)
    c, h, w = values.shape
    try:
        import cv2

        src = (~valid).astype(np.uint8)  # distance to the nearest zero = nearest valid pixel
        _, labels = cv2.distanceTransformWithLabels(src, cv2.DIST_L2, 5,
                                                    labelType=cv2.DIST_LABEL_PIXEL)
        lut = np.zeros(int(labels.max()) + 1, np.int64)
        lut[labels[valid]] = np.flatnonzero(valid)
        idx = lut[labels].ravel()
    except ImportError:  # pragma: no cover - opencv is a dependency; slow fallback
        idx = _nearest_index_numpy(valid)
    flat = values.reshape(c, -1)
    return flat[:, idx].reshape(c, h, w)


def _nearest_index_numpy(valid: np.ndarray) -> np.ndarray:  # pragma: no cover
    h, w = valid.shape
    idx = np.where(valid.ravel(), np.arange(h * w), -1).reshape(h, w)
    while (idx < 0).any():
        grown = idx.copy()
        for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
            sh = np.full_like(idx, -1)
            ys = slice(max(dy, 0), h + min(dy, 0))
            yd = slice(max(-dy, 0), h + min(-dy, 0))
            xs = slice(max(dx, 0), w + min(dx, 0))
            xd = slice(max(-dx, 0), w + min(-dx, 0))
            sh[yd, xd] = idx[ys, xs]
            grown = np.where((grown < 0) & (sh >= 0), sh, grown)
        idx = grown
    return idx.ravel()


def backward_from_forward(fwd_prev: np.ndarray, depth_prev: np.ndarray | None = None,
                          valid_prev: np.ndarray | None = None
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Backward vectors of frame t from the forward vectors of frame t-1.

    fwd_prev: (2, H, W) float, frame t-1's vectors toward t (pixels, y down).
    depth_prev: (1, H, W) or (H, W) view depth of t-1 (smaller wins; inf = sky), or None.
    valid_prev: (H, W) or (1, H, W) bool, pixels of t-1 whose vectors may be splatted.
    Returns (mv, valid): mv (2, H, W) float32 toward t-1 (prev_xy = xy + mv), valid (1, H, W)
    bool, False where no pixel of t-1 landed (filled from the nearest valid pixel).
    """
    fwd = np.asarray(fwd_prev, dtype=np.float32)
    if fwd.ndim != 3 or fwd.shape[0] != 2:
        raise ValueError(f"fwd_prev must be (2, H, W), got {fwd.shape}")
    _, h, w = fwd.shape
    fx, fy = fwd[0].ravel(), fwd[1].ravel()
    ys, xs = np.divmod(np.arange(h * w), w)
    ok = np.isfinite(fx) & np.isfinite(fy)
    if valid_prev is not None:
        ok &= np.asarray(valid_prev, bool).reshape(-1)
    fxs = np.where(ok, fx, 0.0)
    fys = np.where(ok, fy, 0.0)
    # landing position of p's centre is p + 0.5 + f; the pixel containing it is its floor
    tx = np.floor(xs + 0.5 + fxs).astype(np.int64)
    ty = np.floor(ys + 0.5 + fys).astype(np.int64)
    ok &= (tx >= 0) & (tx < w) & (ty >= 0) & (ty < h)
    src = np.flatnonzero(ok)
    tgt = ty[src] * w + tx[src]
    # z-buffer: per target pixel the nearest depth, then the lowest source index among
    # equally near sources (deterministic ties)
    if depth_prev is not None:
        d = np.asarray(depth_prev, dtype=np.float32).reshape(-1)[src]
        d = np.where(np.isnan(d), np.inf, d)
        zbuf = np.full(h * w, np.inf, np.float32)
        np.minimum.at(zbuf, tgt, d)
        near = d <= zbuf[tgt]
        src, tgt = src[near], tgt[near]
    first = np.full(h * w, h * w, np.int64)
    np.minimum.at(first, tgt, src)
    win = first[tgt] == src
    win_src, win_tgt = src[win], tgt[win]
    mv = np.zeros((2, h * w), np.float32)
    mv[0, win_tgt] = -fxs[win_src]
    mv[1, win_tgt] = -fys[win_src]
    valid = np.zeros(h * w, bool)
    valid[win_tgt] = True
    mv = mv.reshape(2, h, w)
    valid = valid.reshape(h, w)
    mv = nearest_fill(mv, valid)
    return mv.astype(np.float32), valid[None]
