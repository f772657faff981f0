"""Pure tensor functions shared by the stages (docs/design.md section 3).

Every function takes and returns torch float32 channel-first tensors, (C, H, W) per
frame and (B, C, H, W) batched, documents its shapes, never modifies its inputs, and
returns finite values for the hard cases of docs/design.md section 5. Conventions: pixel
centres at integer + 0.5, x right, y down; depth linear (> 0, +inf sky); mv from frame t
to frame t-1 in pixels (``prev_xy = xy + mv``).

Mob-FGSR interpolation, frame 0 (older) and 1 (newer), time alpha (what the stages of
pipelines/mob-fgsr.toml run, one op per stage)::

    d1, m1 = dilate_nearest_depth(depth1, mv1)
    r = splat_motion(d1, m1, mv0, alpha, model="quadratic", mode="interp", depth0=depth0)
    r = gap_fill(r, fallback_mv=mv0, fallback_depth=depth0)
    c0s, v0 = backward_warp(color0, r.to0); c1s, v1 = backward_warp(color1, r.to1)
    d0s, _ = sample_nearest(depth0, r.to0); d1s, _ = sample_nearest(depth1, r.to1)
    out = blend_interp(c0s, c1s, d0s, d1s, v0, v1, alpha=alpha)
    out_depth = blend_interp_depth(d0s, d1s, v0, v1, alpha=alpha)
    out_mv = generated_mv(r)              # toward time 0

Extrapolation to 1 + alpha: splat with mode="extrap" (the public
code: model="linear"), gap_fill(r), fill_extrap_holes(r, m1, d1), then
backward_warp(color1, r.to1); generated_mv(r) points toward frame 1.

Performance: ``python benchmarks/ops.py`` times every op at 1080p. Call
``tune_allocator()`` once per process (see its docstring): frame-sized temporaries
otherwise pay for fresh page faults on every op.
"""
from fgcli.ops._util import sanitize_depth, sanitize_mv, sanitize_values, tune_allocator
from fgcli.ops.blend import (T_B, T_D_REL, blend_interp, blend_interp_depth, blend_linear,
                             brightness_difference, repeat_nearest)
from fgcli.ops.color import luminance, mulaw, srgb_eotf, srgb_oetf, to_display
from fgcli.ops.fill import extrap_hole_fill, fill_extrap_holes, gap_fill
from fgcli.ops.metrics import (flip_hdr, flip_ldr, masked_mean, psnr, ssim, ssim_map)
from fgcli.ops.motion import chain_mv, disocclusion_mask
from fgcli.ops.scene import confirm_cut, is_scene_change, motion_explains, scene_change_score
from fgcli.ops.splat import (SplatResult, dilate_nearest_depth, generated_mv,
                             motion_coefficients, splat_motion)
from fgcli.ops.warp import (backward_warp, mv_warp_extrap, mv_warp_interp, sample_nearest)

__all__ = [
    "SplatResult", "T_B", "T_D_REL", "backward_warp", "blend_interp", "blend_interp_depth",
    "blend_linear",
    "brightness_difference", "chain_mv", "dilate_nearest_depth", "disocclusion_mask",
    "extrap_hole_fill", "fill_extrap_holes", "flip_hdr", "flip_ldr", "gap_fill",
    "generated_mv", "luminance", "masked_mean", "is_scene_change", "scene_change_score",
    "confirm_cut", "motion_explains",
    "motion_coefficients", "mulaw",
    "mv_warp_extrap", "mv_warp_interp", "psnr", "repeat_nearest", "sample_nearest",
    "sanitize_depth", "sanitize_mv", "sanitize_values", "splat_motion", "srgb_eotf",
    "srgb_oetf", "ssim", "ssim_map", "to_display", "tune_allocator",
]
