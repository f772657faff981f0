"""Blending of warped frames: Mob-FGSR's Eq. 1 selection rule and simple baselines."""
from __future__ import annotations

import torch

from fgcli.ops._util import (check_alpha, check_same, check_tensor, sanitize_depth,
                             sanitize_values)

# Default relative depth-agreement threshold for linear depth. The paper's T_D = 0.0028 is
# on [0, 1] device depth, which is not relative; FSR 3's disocclusion test on linear depth
# (|z_a - z_b| <= Ksep * Kfov * width * min(z)) works out to ~1-3 % at 1080p. 2 %.
T_D_REL = 0.02
# The paper's T_B, calibrated on display-referred LDR colour with the public code's
# brightness measure 0.5|dR| + |dG| + 0.5|dB|.
T_B = 0.13


def _encode_fast(c: torch.Tensor) -> torch.Tensor:
    """``x^(1/2.4)`` of x clamped to [0.0031308, 1]: the power branch of the sRGB OETF
    without its 1.055 scale (the caller scales differences) and 0.055 offset (cancels in
    differences). The linear toe is flattened (x < 0.0031308 reads as 0.0031308: display
    differences below 0.04, irrelevant against T_B). Finite input only.
    exp(log(x) / 2.4) is ~3x faster than pow on CPU."""
    return c.clamp(0.0031308, 1.0).log_().mul_(1.0 / 2.4).exp_()


def brightness_difference(c0: torch.Tensor, c1: torch.Tensor) -> torch.Tensor:
    """Mob-FGSR's brightness difference ``0.5|dR'| + |dG'| + 0.5|dB'|`` on display-referred
    colour x' = sRGB OETF of clip(x, 0, 1) (the linear toe below 0.0031308 is flattened, a
    < 0.04 change). (3, H, W) x2 (or batched) -> (1, H, W). Inputs must be finite."""
    d = _encode_fast(c0).sub_(_encode_fast(c1)).abs_()
    out = d[..., 0:1, :, :] + d[..., 2:3, :, :]
    return out.mul_(0.5 * 1.055).add_(d[..., 1:2, :, :], alpha=1.055)


def _agree(x, y, t_d):
    """|x - y| <= t_d * min(x, y), or equal (so +inf == +inf agrees)."""
    return (x == y).logical_or_((x - y).abs_() <= torch.minimum(x, y).mul_(t_d))


def interp_blend_args(c0_sample, c1_sample, d0_sample, d1_sample, valid0, valid1, d_target,
                      alpha, t_d_rel, t_b):
    """Validated arguments of blend_interp (shared by the numba kernel's wrapper):
    (c0, c1, d0, d1, v0, v1, d_target, alpha, t_d_rel, t_b)."""
    c0 = check_tensor(c0_sample, "c0_sample")
    c1 = check_tensor(c1_sample, "c1_sample")
    d0 = check_tensor(d0_sample, "d0_sample", 1)
    d1 = check_tensor(d1_sample, "d1_sample", 1)
    v0 = check_tensor(valid0, "valid0", 1, dtype_kind="bool")
    v1 = check_tensor(valid1, "valid1", 1, dtype_kind="bool")
    if d_target is not None:
        d_target = check_tensor(d_target, "d_target", 1)
    check_same(c0, "c0_sample", (c1, "c1_sample"), (d0, "d0_sample"), (d1, "d1_sample"),
               (v0, "valid0"), (v1, "valid1"), (d_target, "d_target"))
    if c0.shape != c1.shape:
        raise ValueError(f"c1_sample: shape {tuple(c1.shape)} does not match c0_sample "
                         f"{tuple(c0.shape)}")
    a = check_alpha(alpha)
    t_d = check_alpha(t_d_rel, "t_d_rel", 0.0, None)
    tb = check_alpha(t_b, "t_b", 0.0, None)
    return c0, c1, d0, d1, v0, v1, d_target, a, t_d, tb


def blend_interp(c0_sample: torch.Tensor, c1_sample: torch.Tensor, d0_sample: torch.Tensor,
                 d1_sample: torch.Tensor, valid0: torch.Tensor, valid1: torch.Tensor,
                 d_target: torch.Tensor | None = None, alpha: float = 0.5,
                 t_d_rel: float = T_D_REL, t_b: float = T_B, return_depth: bool = False,
                 static: torch.Tensor | None = None):
    """Mob-FGSR Eq. 1: combine frame 0 and frame 1 warped to time alpha.

    Per pixel, with d0, d1 the warped depths and B the brightness difference
    (``brightness_difference``: 0.5|dR'| + |dG'| + 0.5|dB'| on sRGB-encoded clip(c, 0, 1)):
      1. only one sample on-screen (valid) -> that sample; neither -> the temporally
         nearer one (frame 0 if alpha <= 0.5);
      2. depths agree, ``d0 == d1`` or ``|d0 - d1| <= t_d_rel * min(d0, d1)`` (relative
         to linear depth; default 2 %, see T_D_REL):
         B <= t_b -> the temporally nearer sample (frame 0 if alpha <= 0.5, as the paper);
         else ``lerp(c0, c1, alpha)`` (shading change);
      3. depths disagree -> the sample of the farther surface (the disoccluded
         background): c0 if d0 > d1 else c1.
    With ``d_target`` (the splatted depth of the generated pixel; optional, an fgen
    extension, off by default) case 3 first prefers the one sample whose depth agrees with
    d_target (same relative test), which keeps thin foreground objects whose warp to one
    frame slipped off them; if none or both agree, the farther sample as above.
    With ``static`` ((1, H, W) bool: the pixel's surface does not move; an fgen extension
    for shading motion, off by default as in the paper) case 2 becomes ``lerp(c0, c1,
    alpha)`` whatever B where static: both samples are the same point of the same static
    surface, so a cross-fade cannot ghost, and when only the lighting moves (B <= t_b: a
    soft shadow edge) it follows the light where picking one frame jumps.
    Endpoints are exact: alpha == 0 returns c0_sample and alpha == 1 returns c1_sample
    (the generated frame *is* the rendered frame there).

    Args:
        c0_sample, c1_sample: (3, H, W) (or any C) colours warped from frames 0 and 1.
        d0_sample, d1_sample: (1, H, W) warped linear depths (+inf sky).
        valid0, valid1: (1, H, W) bool: sample position on-screen.
        d_target: (1, H, W) or None. alpha in [0, 1]. t_d_rel >= 0, t_b >= 0.
        (All may carry a leading batch dim.)

    Returns:
        (C, H, W) float32 colour, finite (NaN -> 0, inf -> 1e30 in the inputs); with
        return_depth, ``(colour, depth)`` where depth is exactly ``blend_interp_depth`` of
        the same inputs, computed from the same masks in one pass.
    """
    c0, c1, d0, d1, v0, v1, d_target, a, t_d, tb = interp_blend_args(
        c0_sample, c1_sample, d0_sample, d1_sample, valid0, valid1, d_target, alpha, t_d_rel,
        t_b)
    c0 = sanitize_values(c0)
    c1 = sanitize_values(c1)
    if (a == 0.0 or a == 1.0) and not return_depth:
        return (c0 if a == 0.0 else c1).clone()
    d0 = sanitize_depth(d0)
    d1 = sanitize_depth(d1)
    # Every case of Eq. 1 is lerp(c0, c1, w) with w in {0, 1, alpha}: build w (one channel)
    # and blend once. torch.lerp returns an endpoint exactly for w = 0 or 1.
    near_w = 0.0 if a <= 0.5 else 1.0
    if c0.shape[-3] == 3:
        similar = brightness_difference(c0, c1) <= tb
    else:
        similar = (c0 - c1).abs_().amax(dim=-3, keepdim=True) <= tb
    both = v0 & v1
    agree = _agree(d0, d1, t_d)
    take0 = d0 > d1  # disagree: the farther surface
    if d_target is not None:
        dt = sanitize_depth(d_target)
        m0 = _agree(d0, dt, t_d)
        m1 = _agree(d1, dt, t_d)
        take0 = torch.where(m0 ^ m1, m0, take0)
    dis = both & ~agree
    # choice weights with the validity and disocclusion cases applied last (they win)
    pick0 = (dis & take0) | (v0 & ~v1)
    pick1 = (dis & ~take0) | (v1 & ~v0)
    none = ~(v0 | v1)
    w = torch.full_like(d0, a)
    if static is not None:
        st = check_tensor(static, "static", 1, dtype_kind="bool")
        w.masked_fill_(agree & similar & ~st, near_w)
    else:
        w.masked_fill_(agree & similar, near_w)
    w.masked_fill_(pick0, 0.0).masked_fill_(pick1, 1.0).masked_fill_(none, near_w)
    if a == 0.0 or a == 1.0:  # the generated frame is the rendered frame there
        color = (c0 if a == 0.0 else c1).clone()
    else:
        color = torch.lerp(c0, c1, w)
    if not return_depth:
        return color
    # depth: same surface -> the temporally nearer sample, else the colour's choice
    take_d0 = pick0 | ((agree | none) & ~pick1 & (near_w == 0.0))
    return color, torch.where(take_d0, d0, d1)


def blend_interp_depth(d0_sample: torch.Tensor, d1_sample: torch.Tensor,
                       valid0: torch.Tensor, valid1: torch.Tensor,
                       d_target: torch.Tensor | None = None, alpha: float = 0.5,
                       t_d_rel: float = T_D_REL) -> torch.Tensor:
    """Depth of the generated frame, chosen by the same rule as blend_interp's colour:
    the only on-screen sample; agreeing depths -> the temporally nearer one (frame 0 if
    alpha <= 0.5); disagreeing -> the one matching d_target if exactly one does, else the
    farther. (1, H, W) inputs (or batched) -> (1, H, W); +inf (sky) is kept, NaN -> +inf.
    """
    d0 = check_tensor(d0_sample, "d0_sample", 1)
    d1 = check_tensor(d1_sample, "d1_sample", 1)
    v0 = check_tensor(valid0, "valid0", 1, dtype_kind="bool")
    v1 = check_tensor(valid1, "valid1", 1, dtype_kind="bool")
    if d_target is not None:
        d_target = check_tensor(d_target, "d_target", 1)
    check_same(d0, "d0_sample", (d1, "d1_sample"), (v0, "valid0"), (v1, "valid1"),
               (d_target, "d_target"))
    a = check_alpha(alpha)
    t_d = check_alpha(t_d_rel, "t_d_rel", 0.0, None)
    d0 = sanitize_depth(d0)
    d1 = sanitize_depth(d1)
    near0 = a <= 0.5
    agree = _agree(d0, d1, t_d)
    take0 = d0 > d1
    if d_target is not None:
        dt = sanitize_depth(d_target)
        take0 = torch.where(_agree(d0, dt, t_d) ^ _agree(d1, dt, t_d), _agree(d0, dt, t_d),
                            take0)
    both = torch.where(agree, d0 if near0 else d1, torch.where(take0, d0, d1))
    return torch.where(v0 & v1, both, torch.where(v0, d0, torch.where(v1, d1, d0 if near0
                                                                      else d1)))


def blend_linear(c0: torch.Tensor, c1: torch.Tensor, alpha: float) -> torch.Tensor:
    """``blend`` baseline (cross-fade): ``(1 - alpha) c0 + alpha c1`` (torch.lerp).

    c0, c1: (C, H, W) or (B, C, H, W), same shape; alpha in [0, 1]. alpha 0 / 1 return c0 /
    c1 exactly. Non-finite inputs are sanitised (NaN -> 0, inf -> 1e30).
    """
    c0 = check_tensor(c0, "c0")
    c1 = check_tensor(c1, "c1")
    if c0.shape != c1.shape:
        raise ValueError(f"c1: shape {tuple(c1.shape)} does not match c0 {tuple(c0.shape)}")
    a = check_alpha(alpha)
    return torch.lerp(sanitize_values(c0), sanitize_values(c1), a)


def repeat_nearest(c0: torch.Tensor, c1: torch.Tensor, alpha: float) -> torch.Tensor:
    """``repeat`` baseline: a copy of the temporally nearest rendered frame (frame 0 if
    alpha <= 0.5, as Eq. 1's tie rule). Shapes (C, H, W) or batched, returned unchanged
    (NaN/inf sanitised)."""
    c0 = check_tensor(c0, "c0")
    c1 = check_tensor(c1, "c1")
    if c0.shape != c1.shape:
        raise ValueError(f"c1: shape {tuple(c1.shape)} does not match c0 {tuple(c0.shape)}")
    a = check_alpha(alpha)
    src = c0 if a <= 0.5 else c1
    out = sanitize_values(src)
    return out.clone() if out is src else out
