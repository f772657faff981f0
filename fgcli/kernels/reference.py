"""Torch reference of the fused per-stage operations: compositions of fgcli.ops exactly as
the stages used them before the kernels existed. The numba kernels of fgcli.kernels.ops
match these; on CUDA (and with --backend torch) these run."""
from __future__ import annotations


def warp_frames(color1, depth1, to1, color0=None, depth0=None, to0=None, mode="bilinear"):
    """Mob-FGSR warp stage: frame 1 (and frame 0 when given) sampled along the generated
    motion. Returns (s1, v1, sd1, s0, v0, sd0); the frame-0 entries are None without it."""
    from fgcli.ops import backward_warp, sample_nearest

    s1, v1 = backward_warp(color1, to1, mode)
    sd1, _ = sample_nearest(depth1, to1)
    if color0 is None:
        return s1, v1, sd1, None, None, None
    s0, v0 = backward_warp(color0, to0, mode)
    sd0, _ = sample_nearest(depth0, to0)
    return s1, v1, sd1, s0, v0, sd0


def mv_warp(color, depth, mv, scale, mode="bilinear", raw_depth_flow=True):
    """mv-warp baseline for one source frame: colour backward-warped by
    ``sanitize_mv(mv) * scale``, depth fetched (nearest) at ``mv * scale`` (the raw vectors
    when raw_depth_flow, else the sanitised ones). Returns (color, depth)."""
    from fgcli.ops import backward_warp, sample_nearest, sanitize_mv

    flow = sanitize_mv(mv) * scale
    color_out, _ = backward_warp(color, flow, mode)
    depth_out, _ = sample_nearest(depth, mv * scale if raw_depth_flow else flow)
    return color_out, depth_out


def crossfade(color0, color1, depth0, depth1, mv1, alpha, mv_scale):
    """blend baseline: (lerp(c0, c1, alpha), min depth, sanitize_mv(mv1) * mv_scale)."""
    import torch

    from fgcli.ops import blend_linear, sanitize_depth, sanitize_mv

    return (blend_linear(color0, color1, alpha),
            torch.minimum(sanitize_depth(depth0), sanitize_depth(depth1)),
            sanitize_mv(mv1) * mv_scale)


def static_mask(motion):
    """Pixels whose surface does not move (the mob-fgsr blend stage's static cross-fade
    test): splatted, and both offsets below 1e-3 px in each component."""
    m = motion
    return m.valid & (m.to1.abs().amax(0, keepdim=True) < 1e-3) & (
        m.to0.abs().amax(0, keepdim=True) < 1e-3)


def blend_eq1(s0, s1, sd0, sd1, v0, v1, d_target, alpha, t_d, t_b, static_from=None):
    """Mob-FGSR blend stage: blend_interp with return_depth, and the static cross-fade mask
    computed from ``static_from`` (the generated motion) when given. Returns (color, depth)."""
    from fgcli.ops import blend_interp

    kw = {} if static_from is None else {"static": static_mask(static_from)}
    return blend_interp(s0, s1, sd0, sd1, v0, v1, d_target, alpha, t_d, t_b,
                        return_depth=True, **kw)


def warp_blend(color1, depth1, to1, color0, depth0, to0, d_target=None, alpha=0.5, t_d=0.02,
               t_b=0.13, static_from=None):
    """The mob-fgsr warp and blend stages one after the other (bilinear): (color, depth).
    (fgcli.kernels.ops.warp_blend does both in one pass.)"""
    s1, v1, sd1, s0, v0, sd0 = warp_frames(color1, depth1, to1, color0, depth0, to0)
    return blend_eq1(s0, s1, sd0, sd1, v0, v1, d_target, alpha, t_d, t_b, static_from)
