"""Reference composition of the Mob-FGSR frame-generation ops (one function per mode).

The stages wrap the individual ops; these two functions are the same chain in one call,
for tests, benchmarks and as the executable description of the wiring.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from fgcli.ops.blend import T_B, T_D_REL, blend_interp, blend_interp_depth
from fgcli.ops.fill import fill_extrap_holes, gap_fill
from fgcli.ops.splat import SplatResult, dilate_nearest_depth, generated_mv, splat_motion
from fgcli.ops.warp import backward_warp, sample_nearest


@dataclass
class Generated:
    """A generated frame: color (3, H, W), depth (1, H, W), mv (2, H, W) (toward time 0 for
    interpolation, toward frame 1 for extrapolation; see generated_mv) and the motion."""

    color: torch.Tensor
    depth: torch.Tensor
    mv: torch.Tensor
    motion: SplatResult


def interpolate(color0, depth0, mv0, color1, depth1, mv1, alpha: float, *,
                model: str = "quadratic", dilate: int = 1, check_depth0: bool = True,
                fill: str = "nearest", gap_threshold_rel: float = 0.01,
                warp_mode: str = "bilinear", t_d_rel: float = T_D_REL, t_b: float = T_B,
                use_target_depth: bool = False) -> Generated:
    """Mob-FGSR interpolation at time alpha between frame 0 (older) and frame 1 (newer).

    dilate (radius; 0 = off) -> splat_motion (check_depth0: pass depth0 so the quadratic
    term is only used on the same surface) -> gap_fill (holes fall back to linear motion
    along mv0) -> backward_warp of both colours (and nearest fetch of both depths) ->
    blend_interp (Eq. 1). Per-frame (C, H, W) tensors.
    """
    d1, m1 = dilate_nearest_depth(depth1, mv1, dilate) if dilate else (depth1, mv1)
    r = splat_motion(d1, m1, mv0, alpha, model=model, mode="interp",
                     depth0=depth0 if check_depth0 else None)
    r = gap_fill(r, gap_threshold_rel, fill, fallback_mv=mv0, fallback_depth=depth0)
    c0s, v0 = backward_warp(color0, r.to0, warp_mode)
    c1s, v1 = backward_warp(color1, r.to1, warp_mode)
    d0s, _ = sample_nearest(depth0, r.to0)
    d1s, _ = sample_nearest(depth1, r.to1)
    dt = r.depth if use_target_depth else None
    color = blend_interp(c0s, c1s, d0s, d1s, v0, v1, dt, alpha, t_d_rel, t_b)
    depth = blend_interp_depth(d0s, d1s, v0, v1, dt, alpha, t_d_rel)
    return Generated(color=color, depth=depth, mv=generated_mv(r), motion=r)


def extrapolate(color1, depth1, mv1, mv0, alpha: float, *, model: str = "linear",
                dilate: int = 1, gap_threshold_rel: float = 0.01, fill: str = "nearest",
                warp_mode: str = "bilinear") -> Generated:
    """Mob-FGSR extrapolation to time 1 + alpha from frame 1 (and frame 0's vectors for the
    quadratic model; the public code splats linearly, the default here).

    dilate -> splat_motion(mode='extrap') -> gap_fill -> fill_extrap_holes -> warp frame 1.
    """
    d1, m1 = dilate_nearest_depth(depth1, mv1, dilate) if dilate else (depth1, mv1)
    r = splat_motion(d1, m1, mv0, alpha, model=model, mode="extrap")
    r = gap_fill(r, gap_threshold_rel, fill)
    r = fill_extrap_holes(r, m1, d1)
    color, _ = backward_warp(color1, r.to1, warp_mode)
    depth, _ = sample_nearest(depth1, r.to1)
    return Generated(color=color, depth=depth, mv=generated_mv(r), motion=r)
