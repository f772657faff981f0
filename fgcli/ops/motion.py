"""Motion-vector utilities: composing vectors over several frames and finding the pixels
of a frame that have no source in another (disocclusions)."""
from __future__ import annotations

import torch

from fgcli.ops._util import check_alpha, check_same, check_tensor, sanitize_depth, sanitize_mv
from fgcli.ops.warp import backward_warp, sample_nearest


def chain_mv(mv_list) -> torch.Tensor:
    """Compose backward motion vectors over several frames.

    Args:
        mv_list: sequence [mv_k, mv_{k-1}, ..., mv_{j+1}] newest first; each (2, H, W) or
            (B, 2, H, W), pointing from its frame to the previous one (fgen convention).

    Returns:
        (2, H, W) vectors from frame k directly to frame j:
        ``b(p) = mv_k(p) + mv_{k-1}(p + mv_k(p)) + ...``, each later vector fetched
        bilinearly at the position reached so far. Off-screen positions are clamped to the
        image (edge-replicated fetch) and chaining continues; the result is then an
        extrapolation and callers that care should test ``p + b`` against the image
        rectangle. A one-element list returns a copy of its vectors.
    """
    if isinstance(mv_list, torch.Tensor) or len(mv_list) == 0:
        raise ValueError("mv_list: expected a non-empty list of (2, H, W) tensors")
    mvs = [check_tensor(m, f"mv_list[{i}]", 2) for i, m in enumerate(mv_list)]
    for i, m in enumerate(mvs[1:], 1):
        check_same(mvs[0], "mv_list[0]", (m, f"mv_list[{i}]"))
    total = sanitize_mv(mvs[0]).clone()
    for m in mvs[1:]:
        fetched, _ = backward_warp(sanitize_mv(m), total, mode="bilinear", border="clamp")
        total = sanitize_mv(total + fetched)
    return total



def disocclusion_mask(depth_t: torch.Tensor, mv_t: torch.Tensor, depth_src: torch.Tensor,
                      rel_tol: float = 0.05) -> torch.Tensor:
    """Pixels of frame t with no source in frame s (for disocclusion-restricted metrics).

    Frame t's pixel q is reprojected to ``q + mv_t(q)`` in frame s (mv_t: vectors from t
    to s, e.g. chained with chain_mv). It is *disoccluded* when that position is off-screen
    or frame s shows a nearer surface there: ``depth_src(nearest pixel) < depth_t(q) *
    (1 - rel_tol)`` (something covered it in frame s). A farther depth in s is not flagged
    (surfaces moving away from the camera). Sky (+inf) in t is disoccluded where s has
    geometry; sky in both is not. The nearest-pixel fetch makes silhouette pixels lean
    towards "disoccluded" (conservative for hole-filling metrics).

    Args:
        depth_t: (1, H, W) depth of frame t. mv_t: (2, H, W) vectors t -> s.
        depth_src: (1, H, W) depth of frame s. rel_tol: relative tolerance (default 5 %).
        (Leading batch dim allowed on all.)

    Returns:
        (1, H, W) bool, True = disoccluded (no source in frame s).
    """
    depth_t = check_tensor(depth_t, "depth_t", 1)
    mv_t = check_tensor(mv_t, "mv_t", 2)
    depth_src = check_tensor(depth_src, "depth_src", 1)
    check_same(depth_t, "depth_t", (mv_t, "mv_t"), (depth_src, "depth_src"))
    tol = check_alpha(rel_tol, "rel_tol", 0.0, 1.0)
    ds, inside = sample_nearest(sanitize_depth(depth_src), sanitize_mv(mv_t))
    dt = sanitize_depth(depth_t)
    return ~inside | (ds < dt * (1.0 - tol))
