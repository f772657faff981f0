"""Guiding flows of the motion-vector-guided interpolation network (mv-interp, seed 000
section 3.1), the cue channels fgen adds to its motion encoder, and the network's tone
mapping.

The paper splats frame 1's vectors to time t "following [YZZ*24]" (Mob-FGSR) with the
linear model and fills disocclusions with frame 1's own vector at the pixel. fgen runs the
whole Mob-FGSR motion chain instead (fgen choice, stated in docs/training.md): nearest-depth
dilation, the quadratic splat (frame 0's vector where frame 0's depth agrees), gap fill,
and holes from frame 0's vectors: a hole is a surface frame 1 does not see, so frame 1's
vector there belongs to the occluder, while frame 0's is the surface's own. Without frame
0's vectors (the first frame of a sequence, forward-only files) it falls back to the
paper's rule (linear, holes from frame 1's vector).

Holes the dilation made (fgen extension, ``undilated=True``): the 3x3 nearest-depth
dilation gives a background pixel beside a nearer surface that surface's vector, so the
pixel splats away with it and its own place at time t can be left empty although frame 1
sees a surface that lands exactly there (a static floor beside a moving object). Such a
hole is not a disocclusion. Before the hole fallback, holes therefore take the vectors of
the undilated splat (frame 1's own vectors and depths, the same splat and depth test)
where it reached them; only the rest take frame 0's vectors.

Cue channels (fgen extension): the network also sees, per pixel, the log ratio of the two
frames' depths at the guided sample positions (Eq. 1 of Mob-FGSR decides by exactly this:
same surface or not, which is farther) and the hole mask; depth is in every G-buffer the
pipeline reads, and without it the network has to guess occlusion order from colour alone.
"""
from __future__ import annotations

import math

import torch

from fgcli.ops._util import (check_alpha, check_tensor, reads_back, sanitize_depth,
                              sanitize_mv)
from fgcli.ops.fill import gap_fill
from fgcli.ops.splat import dilate_nearest_depth, splat_motion
from fgcli.ops.warp import sample_nearest

MU = 8.0          # mu-law of the network's colour space (GFFE's research code: mu = 8)
CLIP = 100.0      # after clipping to [0, 100]
_LOG1MU = math.log1p(MU)
_TM_CLIP = math.log1p(MU * CLIP) / _LOG1MU
CUE_LOG_RANGE = 2.0  # depth log ratios are clamped to +-2 (a factor of e^2 = 7.4)


def guiding_flows(depth1: torch.Tensor, mv1: torch.Tensor, alpha: float,
                  mv0: torch.Tensor | None = None, depth0: torch.Tensor | None = None,
                  undilated: bool = True):
    """Bilateral guiding flows (to0, to1) at interpolation time alpha and the hole mask.

    Args:
        depth1: (1, H, W) frame-1 depth (+inf sky); mv1: (2, H, W) frame-1 vectors toward
            frame 0 (pixels). mv0, depth0: frame 0's vectors (toward frame -1) and depth,
            or None. alpha: time in [0, 1] (0 = frame 0).
        undilated: holes of the dilated splat take the undilated splat's vectors where it
            reached them (module docstring), before the hole fallback.
    Returns:
        to0, to1: (2, H, W): sample frame 0 at ``q + to0`` and frame 1 at ``q + to1``.
        holes: (1, H, W) bool, pixels no splat or gap fill reached (nor, with undilated,
            the undilated splat).
    """
    return guiding_chain(dilate_nearest_depth, splat_motion, gap_fill, depth1, mv1, alpha,
                         mv0, depth0, undilated)


def guiding_chain(dilate, splat, fill, depth1, mv1, alpha, mv0=None, depth0=None,
                  undilated: bool = True):
    """guiding_flows with the three motion ops given (these torch ops, or the numba
    kernels of fgcli.kernels.ops: the same chain either way)."""
    a = check_alpha(alpha)
    check_tensor(depth1, "depth1", 1, allow_batch=False)
    check_tensor(mv1, "mv1", 2, allow_batch=False)

    def splat1(d, m):
        if mv0 is not None:
            return splat(d, m, mv0, a, model="quadratic", mode="interp", depth0=depth0)
        return splat(d, m, None, a, model="linear", mode="interp")

    d1, m1 = dilate(depth1, mv1, 1)
    r = splat1(d1, m1)
    if mv0 is not None:
        r = fill(r, 0.01, "nearest", mv0, depth0 if depth0 is not None else depth1)
    else:
        r = fill(r, 0.01, "nearest", sanitize_mv(mv1), depth1)
    if undilated and (not reads_back(r.holes) or bool(r.holes.any())):
        # holes the dilation made: frame 1's own (undilated) splat reaches them
        u = splat1(sanitize_depth(depth1), sanitize_mv(mv1))
        take = r.holes & u.valid
        return (torch.where(take, u.to0, r.to0), torch.where(take, u.to1, r.to1),
                r.holes & ~take)
    return r.to0, r.to1, r.holes.clone()


def guide_cues(depth0: torch.Tensor, depth1: torch.Tensor, to0: torch.Tensor,
               to1: torch.Tensor, holes: torch.Tensor) -> torch.Tensor:
    """(2, H, W) float32: clamp(log(d0(q + to0) / d1(q + to1)), +-2) / 2 (nearest samples;
    0 = same depth, > 0 = frame 1's sample is nearer) and the hole mask as 0/1."""
    z0, _ = sample_nearest(sanitize_depth(depth0), to0)
    z1, _ = sample_nearest(sanitize_depth(depth1), to1)
    # sky (+inf) counts as 1e6: sky against sky is "same depth", anything against sky nearer
    r = torch.log(z0.clamp(1e-6, 1e6)) - torch.log(z1.clamp(1e-6, 1e6))
    r = r.clamp(-CUE_LOG_RANGE, CUE_LOG_RANGE) * (1.0 / CUE_LOG_RANGE)
    return torch.cat([r, holes.to(torch.float32)], 0)


def tonemap(x: torch.Tensor) -> torch.Tensor:
    """mu-law after clipping to [0, CLIP]: the network's colour space (0..~3 for HDR)."""
    # log/exp rather than log1p/expm1: ONNX has no expm1 (the difference is < 1e-7 here)
    return torch.log(1.0 + MU * x.clamp(0.0, CLIP)) * (1.0 / _LOG1MU)


def untonemap(y: torch.Tensor) -> torch.Tensor:
    """Inverse of tonemap on [0, tonemap(CLIP)]."""
    return (torch.exp(y.clamp(0.0, _TM_CLIP) * _LOG1MU) - 1.0) * (1.0 / MU)




def guide_warp(c0: torch.Tensor, c1: torch.Tensor, to0: torch.Tensor, to1: torch.Tensor,
               alpha: float) -> torch.Tensor:
    """The network-off ablation: both frames backward-warped by their guiding flows and
    blended by time, ``(1 - alpha)·W(c0, to0) + alpha·W(c1, to1)`` (bilinear, clamped)."""
    from fgcli.ops.warp import backward_warp

    a = check_alpha(alpha)
    s0, _ = backward_warp(c0, to0)
    s1, _ = backward_warp(c1, to1)
    return (1.0 - a) * s0 + a * s1


__all__ = ["guide_warp", "guiding_flows", "tonemap", "untonemap"]
