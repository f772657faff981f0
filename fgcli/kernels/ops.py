"""Torch-in, torch-out wrappers of the numba kernels, with the signatures of the reference
ops (fgcli.ops, fgcli.kernels.reference). Inputs are validated as the reference does;
anything a kernel does not implement (batched or non-CPU tensors, non-default variants)
runs the reference."""
from __future__ import annotations

import functools

import numpy as np
import torch

from fgcli import ops as R
from fgcli.kernels import reference as RF
from fgcli.ops._util import (ALPHA_MAX, any_set, aux, check_alpha, check_same,
                             check_tensor, is_scratch, mark_scratch)

F32 = np.float32
INF = float("inf")
_DUMMY3 = np.zeros((1, 1, 1), dtype=np.float32)
_DUMMY2 = np.zeros((1, 1), dtype=np.float32)
_DUMMYB = np.zeros((1, 1), dtype=np.bool_)
_DUMMYU8 = np.zeros((1, 1), dtype=np.uint8)
_NO_PLANES = np.zeros((0, 4, 1, 1), dtype=np.float32)  # (no trajectory planes to copy into)


def _a(t: torch.Tensor) -> np.ndarray:
    """Contiguous numpy view of a CPU tensor (a copy only when not contiguous)."""
    return t.detach().contiguous().numpy()


def _u8(t) -> np.ndarray:
    """uint8 view of a bool tensor (the kernels' mask inputs: a kernel that reads a bool
    array loses noalias on all its arguments, fgcli.kernels.blend)."""
    return _a(t).view(np.uint8)


def _cpu(*ts) -> bool:
    return all(t is None or (t.device.type == "cpu" and t.dim() == 3) for t in ts)


def _empty(*shape, dtype=torch.float32):
    return torch.empty(shape, dtype=dtype)


_LEVEL1 = "_fgen_inpaint_level1"  # (_keep_level1)


def _writable(in_place, *ts) -> bool:
    """Whether an op asked to work in place may write into ts: every one scratch
    (fgcli.ops._util.mark_scratch) and C-contiguous (the kernels' layout). A level 1 kept
    with one (_keep_level1) goes: it will not be the tensor's any more."""
    ok = bool(in_place) and is_scratch(*ts) and all(t.is_contiguous() for t in ts)
    if ok:
        for t in ts:
            t.__dict__.pop(_LEVEL1, None)
    return ok


def _own_copy(t: torch.Tensor) -> torch.Tensor:
    """A C-contiguous copy of t, marked scratch (fgcli.ops._util.mark_scratch)."""
    return mark_scratch(t.clone(memory_format=torch.contiguous_format))


@functools.lru_cache(maxsize=8)
def _grid(h: int, w: int):
    a = aux(h, w, "cpu")
    return (a["gxn"][0].contiguous().numpy(), a["gyn"][:, 0].contiguous().numpy(),
            F32(2.0 / w), F32(2.0 / h))


@functools.lru_cache(maxsize=1)
def _table():
    from fgcli.kernels.blend import encode_table

    return encode_table()


# ----------------------------------------------------------------------------- splat


def dilate_nearest_depth(depth, mv, radius: int = 1):
    depth = check_tensor(depth, "depth", 1)
    mv = check_tensor(mv, "mv", 2)
    if not _cpu(depth, mv) or not isinstance(radius, int) or isinstance(radius, bool) \
            or radius < 0:
        return R.dilate_nearest_depth(depth, mv, radius)
    check_same(depth, "depth", (mv, "mv"))
    from fgcli.kernels.splat import dilate3_kernel, dilate_kernel

    h, w = depth.shape[-2:]
    d, m = _empty(1, h, w), _empty(2, h, w)
    if radius == 1 and 2 * h * w < 2 ** 31:  # the default (3x3): the tap-by-tap kernel
        dilate3_kernel(_a(depth)[0], _a(mv), d.numpy()[0], m.numpy())
    else:
        dilate_kernel(_a(depth)[0], _a(mv), radius, d.numpy()[0], m.numpy())
    return d, m


def splat_motion(depth1, mv1, mv0, alpha, model="quadratic", mode="interp", depth0=None,
                 depth0_tol_rel=0.05, toward0=True):
    if not _cpu(depth1, mv1, mv0, depth0):
        return R.splat_motion(depth1, mv1, mv0, alpha, model, mode, depth0, depth0_tol_rel,
                              toward0)
    depth1, mv1, mv0, depth0, tol, a = R.splat.splat_args(depth1, mv1, mv0, alpha, model,
                                                          mode, depth0, depth0_tol_rel)
    h, w = depth1.shape[-2:]
    if (h + 2) * (w + 2) >= 2 ** 31:
        raise ValueError("splat_motion: image too large for 32-bit source indices")
    if h >= 65536 or w >= 65536 or 2 * h * w >= 2 ** 31:
        # (the kernel packs sources as y << 16 | x, and indexes the vectors in 32 bits)
        return R.splat_motion(depth1, mv1, mv0, alpha, model, mode, depth0, depth0_tol_rel,
                              toward0)
    from fgcli.kernels.splat import splat_kernel, splat_resolve_kernel

    ca, cb = R.motion_coefficients(a, model if mv0 is not None else "linear", mode)
    quad = cb != 0.0
    use_d0 = quad and depth0 is not None
    w0 = bool(toward0)
    to1, dt = _empty(2, h, w), _empty(1, h, w)
    to0 = _empty(2, h, w) if w0 else None
    valid = _empty(1, h, w, dtype=torch.bool)
    source = _empty(1, h, w, dtype=torch.int32)
    buf = np.empty((h + 2) * (w + 2), dtype=np.int64)
    disp = _empty(2, h, w).numpy() if quad else _DUMMY3  # (linear: unused)
    d1 = _a(depth1)[0]
    splat_kernel(d1, _a(mv1), _a(mv0) if quad else _DUMMY3, _a(depth0)[0] if use_d0 else d1,
                 F32(ca), F32(cb), quad, use_d0, F32(tol), buf, disp)
    splat_resolve_kernel(buf, d1, _a(mv1), disp, F32(ca), quad, w0, to1.numpy(),
                         to0.numpy() if w0 else _DUMMY3, dt.numpy()[0], valid.numpy()[0],
                         source.numpy()[0])
    return R.SplatResult(to1=to1, to0=to0, depth=dt, valid=valid, source=source,
                         alpha=float(a), mode=mode, scratch=True)


def _spend(result):
    """Mark a result whose planes an in-place refinement took over."""
    result.scratch = False


# ----------------------------------------------------------------------------- fill


def _in_place(result, in_place) -> bool:
    """Whether a refinement may write into result's planes: asked to, scratch (no one else
    holds them), and plain per-frame contiguous planes."""
    if not (in_place and result.scratch):
        return False
    planes = [result.to1, result.depth, result.valid, result.source] + \
        ([] if result.to0 is None else [result.to0])
    return all(t.is_contiguous() and t.dim() == 3 for t in planes)


def gap_fill(result, depth_threshold_rel=0.01, fill="nearest", fallback_mv=None,
             fallback_depth=None, in_place=False):
    if not isinstance(result, R.SplatResult) or fill != "nearest" or \
            not _cpu(result.depth, fallback_mv, fallback_depth):
        return R.gap_fill(result, depth_threshold_rel, fill, fallback_mv, fallback_depth)
    thr, fallback_mv, fallback_depth = R.fill.gap_fill_args(result, depth_threshold_rel,
                                                            fallback_mv, fallback_depth)
    from fgcli.kernels.fill import gap_fill_inplace_kernel, gap_fill_kernel

    h, w = result.depth.shape[-2:]
    a = result.alpha
    c1, c0 = (-(1.0 - a), a) if result.mode == "interp" else (a, 1.0 + a)
    has0 = result.to0 is not None
    has_fb = fallback_mv is not None
    has_fbd = has_fb and fallback_depth is not None
    if _in_place(result, in_place):
        filled, holes = (_empty(1, h, w, dtype=torch.bool) for _ in range(2))
        gap_fill_inplace_kernel(
            _a(result.to1), _a(result.to0) if has0 else _DUMMY3, has0, _a(result.depth)[0],
            _a(result.valid)[0].view(np.uint8), _a(result.source)[0], F32(1.0 - thr),
            _a(fallback_mv) if has_fb else _a(result.to1),
            _a(fallback_depth)[0] if has_fbd else _a(result.depth)[0], has_fb, has_fbd,
            F32(c1), F32(c0), filled.numpy()[0], holes.numpy()[0])
        _spend(result)
        return result.replace(filled=filled, holes=holes, scratch=True)
    to1, dep = _empty(2, h, w), _empty(1, h, w)
    to0 = _empty(2, h, w) if has0 else None
    valid, filled, holes = (_empty(1, h, w, dtype=torch.bool) for _ in range(3))
    source = _empty(1, h, w, dtype=torch.int32)
    gap_fill_kernel(_a(result.to1), _a(result.to0) if has0 else _DUMMY3, has0,
                    _a(result.depth)[0], _a(result.valid)[0], _a(result.source)[0],
                    F32(1.0 - thr),
                    # unused fields: same-shape stand-ins (the kernel may read them)
                    _a(fallback_mv) if has_fb else _a(result.to1),
                    _a(fallback_depth)[0] if has_fbd else _a(result.depth)[0], has_fb, has_fbd,
                    F32(c1), F32(c0), to1.numpy(), to0.numpy() if has0 else _DUMMY3,
                    dep.numpy()[0],
                    valid.numpy()[0], source.numpy()[0], filled.numpy()[0], holes.numpy()[0])
    # every plane is new: whoever gets this result may refine it in place
    return result.replace(to1=to1, to0=to0, depth=dep, valid=valid, source=source,
                          filled=filled, holes=holes, scratch=True)


def fill_extrap_holes(result, mv1, depth1, depth_threshold_rel=1e-3, in_place=False):
    if not isinstance(result, R.SplatResult) or result.mode != "extrap" or \
            not _cpu(result.depth, mv1, depth1):
        return R.fill_extrap_holes(result, mv1, depth1, depth_threshold_rel)
    mv1 = check_tensor(mv1, "mv1", 2)
    depth1 = check_tensor(depth1, "depth1", 1)
    check_same(mv1, "mv1", (depth1, "depth1"), (result.to1, "to1"))
    a = check_alpha(result.alpha, hi=ALPHA_MAX)
    thr = check_alpha(depth_threshold_rel, "depth_threshold_rel", 0.0, 1.0)
    from fgcli.kernels.fill import extrap_fill_inplace_kernel, extrap_fill_kernel

    h, w = depth1.shape[-2:]
    has0 = result.to0 is not None
    if _in_place(result, in_place):
        holes = _empty(1, h, w, dtype=torch.bool)
        extrap_fill_inplace_kernel(_a(mv1), _a(depth1)[0], _a(result.to1),
                                   _a(result.to0) if has0 else _DUMMY3, has0,
                                   _a(result.valid)[0], _a(result.depth)[0], F32(a),
                                   F32(1.0 - thr), holes.numpy()[0])
        _spend(result)
        return result.replace(holes=holes, scratch=True)
    to1, dep = _empty(2, h, w), _empty(1, h, w)
    to0 = _empty(2, h, w) if has0 else None
    holes = _empty(1, h, w, dtype=torch.bool)
    extrap_fill_kernel(_a(mv1), _a(depth1)[0], _a(result.to1),
                       _a(result.to0) if has0 else _DUMMY3, has0, _a(result.valid)[0],
                       _a(result.depth)[0], F32(a), F32(1.0 - thr), to1.numpy(),
                       to0.numpy() if has0 else _DUMMY3, dep.numpy()[0], holes.numpy()[0])
    return result.replace(to1=to1, to0=to0, depth=dep, holes=holes)


# ----------------------------------------------------------------------------- warp


def warp_frames(color1, depth1, to1, color0=None, depth0=None, to0=None, mode="bilinear"):
    if mode != "bilinear" or not _cpu(color1, depth1, to1, color0, depth0, to0):
        return RF.warp_frames(color1, depth1, to1, color0, depth0, to0, mode)
    color1 = check_tensor(color1, "img")
    to1 = check_tensor(to1, "flow", 2)
    depth1 = check_tensor(depth1, "img")
    check_same(color1, "img", (to1, "flow"), (depth1, "depth"))
    two = color0 is not None
    if two:
        color0 = check_tensor(color0, "img")
        to0 = check_tensor(to0, "flow", 2)
        depth0 = check_tensor(depth0, "img")
        check_same(color0, "img", (to0, "flow"), (depth0, "depth"))
    from fgcli.kernels.warp import flat_ok, warp_kernel

    if depth1.shape[0] != 1 or (two and depth0.shape[0] != 1) or color1.shape[0] != 3 or \
            (two and color0.shape[0] != 3) or not flat_ok(*color1.shape[1:], 3):
        return RF.warp_frames(color1, depth1, to1, color0, depth0, to0, mode)

    c, h, w = color1.shape
    gxn, gyn, kx, ky = _grid(h, w)
    s1, sd1, v1 = _empty(c, h, w), _empty(1, h, w), _empty(1, h, w, dtype=torch.bool)
    if two:
        s0, sd0 = _empty(color0.shape[0], h, w), _empty(1, h, w)
        v0 = _empty(1, h, w, dtype=torch.bool)
        c0a, d0a, t0a, s0a, sd0a, v0a = (_a(color0), _a(depth0)[0], _a(to0), s0.numpy(),
                                         sd0.numpy()[0], v0.numpy()[0])
    else:
        s0 = sd0 = v0 = None
        c0a, d0a, t0a, s0a, sd0a, v0a = _DUMMY3, _DUMMY2, _DUMMY3, _DUMMY3, _DUMMY2, _DUMMYB
    warp_kernel(_a(color1), _a(depth1)[0], _a(to1), c0a, d0a, t0a, two, gxn, gyn, kx, ky,
                s1.numpy(), sd1.numpy()[0], v1.numpy()[0], s0a, sd0a, v0a)
    return s1, v1, sd1, s0, v0, sd0


def mv_warp(color, depth, mv, scale, mode="bilinear", raw_depth_flow=True):
    from fgcli.kernels.warp import flat_ok

    if mode != "bilinear" or not _cpu(color, depth, mv) or depth.shape[0] != 1 or \
            color.shape[-3] != 3 or not flat_ok(*color.shape[-2:], 3):
        return RF.mv_warp(color, depth, mv, scale, mode, raw_depth_flow)
    color = check_tensor(color, "img")
    mv = check_tensor(mv, "mv", 2)
    depth = check_tensor(depth, "img")
    check_same(color, "img", (mv, "mv"), (depth, "depth"))
    from fgcli.kernels.warp import mv_warp_kernel

    c, h, w = color.shape
    gxn, gyn, kx, ky = _grid(h, w)
    out, dout = _empty(c, h, w), _empty(1, h, w)
    mv_warp_kernel(_a(color), _a(depth)[0], _a(mv), F32(scale), bool(raw_depth_flow), gxn, gyn,
                   kx, ky, out.numpy(), dout.numpy()[0])
    return out, dout


# ----------------------------------------------------------------------------- blend


BRIGHT_BOUNDS = True  # tests switch it off to compare with the table alone


def _bright_margins(tb):
    """(accept below, reject above) for the blend kernel's brightness bounds: t_b with the
    margins of fgcli.kernels.blend (relative 1e-5, absolute 4e-6); without the bounds,
    thresholds no bound can meet."""
    if not BRIGHT_BOUNDS:
        return F32(-INF), F32(INF)
    return F32(tb * (1.0 - 1e-5) - 4e-6), F32(tb * (1.0 + 1e-5) + 4e-6)


def blend_interp(c0_sample, c1_sample, d0_sample, d1_sample, valid0, valid1, d_target=None,
                 alpha=0.5, t_d_rel=R.T_D_REL, t_b=R.T_B, return_depth=False, static=None,
                 static_from=None):
    """As fgcli.ops.blend_interp; ``static_from`` (a SplatResult) computes the static mask
    of the mob-fgsr blend stage (valid, |to1| and |to0| < 1e-3) inside the kernel instead of
    taking ``static``."""
    args = (c0_sample, c1_sample, d0_sample, d1_sample, valid0, valid1, d_target)
    if not _cpu(*args, static) or c0_sample.shape[0] != 3 or \
            (static_from is not None and not _cpu(static_from.to1)):
        if static_from is not None:
            m = static_from
            static = RF.static_mask(m)
        kw = {"static": static} if static is not None else {}
        return R.blend_interp(*args, alpha=alpha, t_d_rel=t_d_rel, t_b=t_b,
                              return_depth=return_depth, **kw)
    from fgcli.ops.blend import interp_blend_args

    c0, c1, d0, d1, v0, v1, d_target, a, t_d, tb = interp_blend_args(
        c0_sample, c1_sample, d0_sample, d1_sample, valid0, valid1, d_target, alpha, t_d_rel,
        t_b)
    from fgcli.kernels.blend import blend_kernel

    h, w = d0.shape[-2:]
    if static_from is not None:
        m = static_from
        mvalid, to1, to0, has_static = _u8(m.valid)[0], _a(m.to1), _a(m.to0), True
    elif static is not None:
        st = check_tensor(static, "static", 1, dtype_kind="bool")
        # a given mask: offsets of zero make the in-kernel test reduce to the mask
        mvalid, has_static = _u8(st)[0], True
        to1 = to0 = np.zeros((2, h, w), dtype=np.float32)
    else:
        mvalid, to1, to0, has_static = _DUMMYU8, _DUMMY3, _DUMMY3, False
    table, base = _table()
    endpoint = 1 if a == 0.0 else 2 if a == 1.0 else 0
    out_c, out_d = _empty(3, h, w), _empty(1, h, w)
    blend_kernel(_a(c0), _a(c1), _a(d0)[0], _a(d1)[0], _u8(v0)[0], _u8(v1)[0],
                 _a(d_target)[0] if d_target is not None else _DUMMY2, d_target is not None,
                 mvalid, to1, to0, has_static, F32(a), F32(0.0 if a <= 0.5 else 1.0),
                 F32(t_d), F32(tb), *_bright_margins(tb), endpoint, table, base, out_c.numpy(),
                 out_d.numpy()[0])
    return (out_c, out_d) if return_depth else out_c


def blend_eq1(s0, s1, sd0, sd1, v0, v1, d_target, alpha, t_d, t_b, static_from=None):
    return blend_interp(s0, s1, sd0, sd1, v0, v1, d_target, alpha, t_d, t_b,
                        return_depth=True, static_from=static_from)


def warp_blend(color1, depth1, to1, color0, depth0, to0, d_target=None, alpha=0.5,
               t_d=R.T_D_REL, t_b=R.T_B, static_from=None):
    """warp_frames(color1, depth1, to1, color0, depth0, to0, 'bilinear') and then
    blend_eq1 on its samples, in one pass (fgcli.kernels.blend.warp_blend_kernel): (colour,
    depth), the same values; None where the fused kernel does not apply (no AVX-512 or AVX2, not
    3-channel float32 CPU frames, past 32-bit indices): then the two ops one after the
    other."""
    from fgcli.kernels._intrin import HAVE_WINDOW16
    from fgcli.kernels.warp import flat_ok

    frames = (color1, depth1, to1, color0, depth0, to0, d_target)
    if not HAVE_WINDOW16 or not _cpu(*frames) or \
            (static_from is not None and not _cpu(static_from.to1, static_from.to0)):
        return None
    if any(t is not None and (t.dtype != torch.float32 or t.dim() != 3)
           for t in frames) or color1.shape[0] != 3 or color0 is None or \
            color0.shape != color1.shape:
        return None
    h, w = color1.shape[-2:]
    if not flat_ok(h, w, 3) or any(tuple(t.shape) != (n, h, w) for t, n in (
            (depth1, 1), (depth0, 1), (to1, 2), (to0, 2))) or \
            (d_target is not None and tuple(d_target.shape) != (1, h, w)):
        return None
    from fgcli.ops.blend import interp_blend_args

    # (the blend's argument checks, on the inputs' shapes: the samples have them)
    _, _, _, _, _, _, _, a, t_d, tb = interp_blend_args(
        color0, color1, depth0, depth1, torch.ones(1, 1, 1, dtype=torch.bool).expand(1, h, w),
        torch.ones(1, 1, 1, dtype=torch.bool).expand(1, h, w), d_target, alpha, t_d, t_b)
    if static_from is not None:
        m = static_from
        mvalid, s_to1, s_to0, has_static = _u8(m.valid)[0], _a(m.to1), _a(m.to0), True
    else:
        mvalid, s_to1, s_to0, has_static = _DUMMYU8, _DUMMY3, _DUMMY3, False
    from fgcli.kernels.blend import warp_blend_kernel

    gxn, gyn, kx, ky = _grid(h, w)
    table, base = _table()
    endpoint = 1 if a == 0.0 else 2 if a == 1.0 else 0
    out_c, out_d = _empty(3, h, w), _empty(1, h, w)
    warp_blend_kernel(_a(color1), _a(depth1)[0], _a(to1), _a(color0), _a(depth0)[0], _a(to0),
                      gxn, gyn, kx, ky,
                      _a(d_target)[0] if d_target is not None else _DUMMY2,
                      d_target is not None, mvalid, s_to1, s_to0, has_static, F32(a),
                      F32(0.0 if a <= 0.5 else 1.0), F32(t_d), F32(tb), *_bright_margins(tb),
                      endpoint, table, base, out_c.numpy(), out_d.numpy()[0])
    return out_c, out_d


def crossfade(color0, color1, depth0, depth1, mv1, alpha, mv_scale):
    if not _cpu(color0, color1, depth0, depth1, mv1) or color0.shape != color1.shape or \
            depth0.shape[0] != 1:
        return RF.crossfade(color0, color1, depth0, depth1, mv1, alpha, mv_scale)
    a = check_alpha(alpha)
    from fgcli.kernels.blend import crossfade_kernel

    c, h, w = color0.shape
    out_c, out_d, out_mv = _empty(c, h, w), _empty(1, h, w), _empty(2, h, w)
    crossfade_kernel(_a(check_tensor(color0, "c0")), _a(check_tensor(color1, "c1")),
                     _a(check_tensor(depth0, "depth0", 1))[0],
                     _a(check_tensor(depth1, "depth1", 1))[0], _a(check_tensor(mv1, "mv1", 2)),
                     F32(a), F32(mv_scale), out_c.numpy(), out_d.numpy()[0], out_mv.numpy())
    return out_c, out_d, out_mv


# ----------------------------------------------------------------------------- mv-interp


def guiding_flows(depth1, mv1, alpha, mv0=None, depth0=None, undilated=True):
    """fgcli.ops.mvinterp.guiding_flows with the dilation, splat and gap fill kernels (the
    same chain, so the same result)."""
    from fgcli.ops import mvinterp as MI

    if not _cpu(depth1, mv1, mv0, depth0):
        return MI.guiding_flows(depth1, mv1, alpha, mv0, depth0, undilated)
    return MI.guiding_chain(dilate_nearest_depth, splat_motion, gap_fill, depth1, mv1, alpha,
                            mv0, depth0, undilated)


# ----------------------------------------------------------------------------- fsr3 passes


def disocclusion_masks(depth_t, depth_prev, depth1, vec, alpha=0.5, kfov=1.4, ksep=1.37e-5,
                       threshold=0.5):
    """fgcli.ops.fsr3.disocclusion_masks: both masks in one kernel pass."""
    from fgcli.ops import fsr3 as FS

    if not _cpu(depth_t, depth_prev, depth1, vec):
        return FS.disocclusion_masks(depth_t, depth_prev, depth1, vec, alpha, kfov, ksep,
                                     threshold)
    depth_t, depth_prev, depth1, vec, a, thr = FS.disocclusion_args(
        depth_t, depth_prev, depth1, vec, alpha, kfov, ksep)
    from fgcli.kernels.fsr3 import disocclusion_kernel
    from fgcli.kernels.warp import flat_ok

    h, w = depth_t.shape[-2:]
    if not flat_ok(h, w, 1):
        return FS.disocclusion_masks(depth_t, depth_prev, depth1, vec, alpha, kfov, ksep,
                                     threshold)
    mp, mc = _empty(1, h, w), _empty(1, h, w)
    disocclusion_kernel(_a(depth_t)[0], _a(depth_prev)[0], _a(depth1)[0], _a(vec), F32(a),
                        F32(1.0 - a), F32(thr), F32(threshold), mp.numpy()[0], mc.numpy()[0])
    return mp, mc


def interpolate_fsr3(color0, color1, vec, mask_prev, mask_cur, alpha=0.5, of_vec=None,
                     space="linear"):
    """fgcli.ops.fsr3.interpolate_fsr3 (linear space, 3-channel colour) in one kernel
    pass; display space and other shapes run the reference."""
    from fgcli.ops import fsr3 as FS

    args = (color0, color1, vec, mask_prev, mask_cur, alpha, of_vec, space)
    if not _cpu(color0, color1, vec, mask_prev, mask_cur, of_vec) or space != "linear":
        return FS.interpolate_fsr3(*args)
    color0, color1, vec, of_vec, a = FS.interpolate_args(color0, color1, vec, alpha, of_vec,
                                                         space)
    from fgcli.kernels.fsr3 import interp_flow_kernel, interp_game_kernel
    from fgcli.kernels.warp import flat_ok

    c, h, w = color0.shape
    if c != 3 or any(m.shape != (1, h, w) or m.dtype != torch.float32
                     for m in (mask_prev, mask_cur)) or not flat_ok(h, w, 3):
        return FS.interpolate_fsr3(*args)

    gxn, gyn, kx, ky = _grid(h, w)
    out, holes, bias = _empty(3, h, w), _empty(1, h, w, dtype=torch.bool), _empty(1, h, w)
    has_of = of_vec is not None
    from fgcli.kernels.fsr3 import WINDOW16

    if has_of and WINDOW16:  # both paths in one pass (the window fetches: AVX-512 / AVX2)
        from fgcli.kernels.fsr3 import interp_window_kernel

        *chain, lev1 = _chain(4, h, w)
        nh = np.empty((h + 1) // 2, dtype=np.int64)
        interp_window_kernel(_a(color0), _a(color1), _a(vec), _a(of_vec), _a(mask_prev)[0],
                             _a(mask_cur)[0], F32(a), F32(-(1.0 - a)), F32(1.0 - a), gxn, gyn,
                             kx, ky, out.numpy(), holes.numpy()[0], bias.numpy()[0], True,
                             lev1, nh)
        _keep_level1(out, holes, chain, nh)
        return mark_scratch(out), holes, bias
    T, G = np.empty((h, w), dtype=np.float32), np.empty((h, w), dtype=np.float32)
    S = np.empty((h, w), dtype=np.float32) if has_of else _DUMMY2
    a32, na32 = F32(a), F32(-(1.0 - a))
    interp_game_kernel(_a(color0), _a(color1), _a(vec), _a(mask_prev)[0], _a(mask_cur)[0],
                       has_of, a32, na32, F32(1.0 - a), gxn, gyn, kx, ky, out.numpy(),
                       holes.numpy()[0], T, G, S)
    if has_of:
        interp_flow_kernel(_a(color0), _a(color1), _a(of_vec), a32, na32, gxn, gyn, kx, ky,
                           T, G, S, out.numpy(), bias.numpy()[0])
    else:
        bias.fill_(1.0)
    return mark_scratch(out), holes, bias


def interpolated_depth(depth_t, vec, alpha=0.5, depth0=None, depth1=None):
    """fgcli.ops.fsr3.interpolated_depth by the numba kernel."""
    from fgcli.ops import fsr3 as FS

    if depth0 is None or depth1 is None or not _cpu(depth_t, vec, depth0, depth1) or \
            any(t.shape != depth_t.shape or t.dtype != torch.float32
                for t in (depth_t, depth0, depth1)) or depth_t.shape[0] != 1 \
            or depth_t.shape[1:] != vec.shape[1:] or vec.dtype != torch.float32 \
            or depth_t[0].numel() >= 2 ** 31:  # (32-bit indices; kernel reads (H, W) depths)
        return FS.interpolated_depth(depth_t, vec, alpha, depth0, depth1)
    a = check_alpha(alpha)
    from fgcli.kernels.fsr3 import interp_depth_kernel

    h, w = depth_t.shape[-2:]
    out = _empty(1, h, w)
    interp_depth_kernel(_a(depth_t)[0], _a(depth0)[0], _a(depth1)[0], _a(vec), F32(a),
                        F32(-(1.0 - a)), out.numpy()[0])
    return out


def output_vectors(vec, scale):
    """fgcli.ops.fsr3.output_vectors by one kernel pass (the reference reads the vectors
    twice to test them, then once more to scale them)."""
    from fgcli.ops import fsr3 as FS

    if not (_f32cpu(vec) and vec.shape[0] == 2):
        return FS.output_vectors(vec, scale)
    from fgcli.kernels.fsr3 import scale_mv_kernel

    out = _empty(*vec.shape)
    scale_mv_kernel(_a(vec), F32(float(scale)), out.numpy())
    return out


def avg_pool2(x):
    """fgcli.ops.pyramid.avg_pool2 (one mip level) by the numba kernel."""
    from fgcli.ops.pyramid import avg_pool2 as ref

    if x.device.type != "cpu" or x.dim() != 3 or x.dtype != torch.float32:
        return ref(x)
    from fgcli.kernels.pyramid import pool2_kernel

    c, h, w = x.shape
    out = _empty(c, (h + 1) // 2, (w + 1) // 2)
    pool2_kernel(_a(x), out.numpy())
    return out


def pyramid_inpaint(values, weight, holes=None, mode="blend", decay=10.0, eps=1e-12,
                    pool=None):
    """fgcli.ops.pyramid.pyramid_inpaint: the dense part (sanitised copy, cleaned weight,
    hole mask and count, level 1 straight from the image) in one kernel, the hole indices
    in another, the coarser levels and the fill at the hole pixels in two more
    (_inpaint_levels)."""
    from fgcli.ops import pyramid as PY

    ok = (_f32cpu(values) and _f32cpu(weight) and weight.shape[0] == 1
          and weight.shape[1:] == values.shape[1:] and values.shape[1] * values.shape[2] > 1
          and (holes is None or _boolcpu(holes, weight.shape)))
    if not ok:
        return PY.pyramid_inpaint(values, weight, holes, mode, decay, eps, pool=avg_pool2)
    values, weight, holes = PY.checked_inpaint_args(values, weight, holes, mode, decay)
    return _inpaint(values, weight, holes, mode, decay, eps)


def _inpaint(values, weight, holes, mode, decay, eps, in_place=False, want_filled=True):
    """pyramid_inpaint's kernel path on checked inputs; weight None: 1 everywhere (holes
    given). in_place (values marked scratch and contiguous, holes given): the holes are
    filled in values itself, and the given holes serve as the hole mask (no copies: 26 MB
    written less per 1080p colour frame). want_filled False: no filled mask (None)."""
    from fgcli.kernels.pyramid import inpaint_prep_kernel

    c, h, w = values.shape
    kept = _level1_of(values, holes) if holes is not None else None
    inp = holes is not None and _writable(in_place, values) and holes.is_contiguous()
    if kept is not None and inp and weight is None:  # (interpolate_fsr3's: level 1 made)
        return _inpaint_levels(values, holes, kept[0], kept[1], mode, decay, eps, want_filled)
    out = values if inp else _empty(c, h, w)
    hout = holes if inp else _empty(1, h, w, dtype=torch.bool)
    *chain, lev1 = _chain(c + 1, h, w)
    nh = np.empty((h + 1) // 2, dtype=np.int64)
    ha = _u8(holes)[0] if holes is not None else _u8(hout)[0]  # (unread when not given)
    va = _a(values)
    inpaint_prep_kernel(va, va[0] if weight is None else _a(weight)[0], weight is None, ha,
                        holes is not None, _a(out), _u8(hout)[0], lev1, nh, not inp)
    return _inpaint_levels(out, hout, chain, nh, mode, decay, eps, want_filled)


def _versions(*ts):
    """The tensors' version counters (bumped by torch's in-place ops), or None in
    inference mode (which keeps none)."""
    try:
        return tuple(t._version for t in ts)
    except RuntimeError:
        return None


def _keep_level1(color, holes, chain, nh):
    """Keep with color the inpainting's level 1 of it and its holes (inpaint_color's with
    unit weight: interp_window_kernel makes it as it writes the rows), until the
    inpainting takes it (_level1_of). It goes when a kernel op is let write color in place
    (_writable), when torch changes either tensor in place (their version counters, where
    torch keeps them: not in inference mode), and with other holes."""
    color.__dict__[_LEVEL1] = (holes, _versions(color, holes), chain, nh)


def _level1_of(color, holes):
    """(chain, nh) that _keep_level1 kept with color for these holes, if neither tensor
    changed since (else None); taken off color either way."""
    kept = color.__dict__.pop(_LEVEL1, None) if isinstance(color, torch.Tensor) else None
    if kept is None:
        return None
    h0, vs, chain, nh = kept
    if h0 is not holes or _versions(color, holes) != vs:
        return None
    return chain, nh


def _chain(c1, h, w):
    """An empty mip chain for an (H, W) image with c1 channels (levels 1.. in one buffer,
    fgcli.kernels.pyramid.chain_layout): (buffer, hs, ws, offs, level 1 as (c1, h2, w2))."""
    from fgcli.kernels.pyramid import chain_layout

    hs, ws, offs = chain_layout(c1, h, w)
    buf = np.empty(int(offs[-1]), dtype=np.float32)
    return buf, hs, ws, offs, buf[:offs[2]].reshape(c1, int(hs[1]), int(ws[1]))


def _inpaint_levels(out, hout, chain, nh, mode, decay, eps, want_filled=True):
    """pyramid_inpaint's kernel path after its dense part (out: the sanitised values,
    hout (1, H, W) the holes, chain = _chain(...)[:4] with level 1 and nh from
    inpaint_prep_kernel): the hole indices, the coarser levels (pool_chain_kernel) and the
    fill (fill_levels_kernel: fill_from_levels' values), in place on out. Returns (out,
    filled), filled None unless want_filled (a 2 MB plane zeroed per 1080p call)."""
    from fgcli.kernels.pyramid import fill_levels_kernel, hole_index_kernel, pool_chain_kernel

    h, w = out.shape[-2:]
    start = np.zeros(nh.size + 1, dtype=np.int64)
    np.cumsum(nh, out=start[1:])
    n = int(start[-1])
    filled = torch.zeros(1, h, w, dtype=torch.bool) if want_filled else None
    if n == 0:
        return out, filled
    idx = np.empty(n, dtype=np.int64)
    hole_index_kernel(_u8(hout)[0], start, idx)
    buf, hs, ws, offs = chain
    pool_chain_kernel(buf, hs, ws, offs)
    ms = np.zeros(hs.size, dtype=np.float32)  # fill_from_levels' level weights (as alpha)
    nb = 0
    while mode == "blend" and nb + 1 < hs.size:
        m = max(0.0, 1.0 - (nb + 1) / decay) ** 3
        if m <= 0.0:
            break
        nb += 1
        ms[nb] = m
    fl = _u8(filled).reshape(-1) if want_filled else np.empty(0, dtype=np.uint8)
    fill_levels_kernel(buf, hs, ws, offs, idx, ms, nb, F32(eps),
                       _a(out).reshape(out.shape[0], -1), fl)
    return out, filled


def fill_packed_field(field):
    """fgcli.ops.fsr3.fill_packed_field: the unpacking, the weight and the inpainting's
    dense part in one kernel (fgcli.kernels.field.field_fill_prep_kernel), then the
    inpainting's levels as pyramid_inpaint's kernel path."""
    from fgcli.ops import fsr3 as FS

    if not isinstance(field, torch.Tensor) or field.dim() != 3 or field.shape[0] != 2 or \
            field.device.type != "cpu" or field.dtype not in (torch.int64, torch.uint32) or \
            field.shape[1] * field.shape[2] <= 1 or \
            2 * (field.shape[1] + 2) * (field.shape[2] + 2) >= 2 ** 31:  # (32-bit indices)
        return FS.fill_packed_field(field)
    from fgcli.kernels.field import field_fill_prep_kernel

    h, w = field.shape[-2:]
    out = _empty(2, h, w)
    hout = _empty(1, h, w, dtype=torch.bool)
    valid = _empty(1, h, w, dtype=torch.bool)
    *chain, lev1 = _chain(3, h, w)
    nh = np.empty((h + 1) // 2, dtype=np.int64)
    src, o = _padded_base(field)
    field_fill_prep_kernel(_a(field) if src is None else src, o, out.numpy(), _u8(hout)[0],
                           _u8(valid)[0], lev1, nh)
    if not nh.any():
        return out, valid
    return _inpaint_levels(out, hout, chain, nh, "first", 10.0, 1e-12, False)[0], valid


def inpaint_color(color, holes, decay=10.0, in_place=False):
    """fgcli.ops.fsr3.inpaint_color with the inpainting by numba kernels (the weight
    (~holes).float() never made: 1 everywhere, the given holes zero it). in_place: the
    caller gives color up; where it is marked scratch (interpolate_fsr3's) the holes are
    filled in it (fgcli.ops._util)."""
    from fgcli.ops import fsr3 as FS

    if not (_f32cpu(color) and isinstance(holes, torch.Tensor) and holes.dim() == 3
            and _boolcpu(holes, (1,) + tuple(color.shape[1:]))
            and color.shape[1] * color.shape[2] > 1):
        return FS.inpaint_color(color, holes, decay, pool=avg_pool2, inpaint=pyramid_inpaint)
    if not (decay > 0):
        raise ValueError(f"decay: expected > 0, got {decay!r}")
    out, _ = _inpaint(color, None, holes, "blend", decay, 1e-12, in_place, False)
    return out


# ----------------------------------------------------------------------------- start-up


def _inputs():
    """8x8 inputs for one call of every kernel, made with the torch reference ops (so a
    group of kernels can be compiled without the others)."""
    g = torch.Generator().manual_seed(0)
    d = torch.rand(1, 8, 8, generator=g) + 1.0
    mv = torch.randn(2, 8, 8, generator=g)
    c = torch.rand(3, 8, 8, generator=g)
    dd, mm = R.dilate_nearest_depth(d, mv)
    gf = R.gap_fill(R.splat_motion(dd, mm, mv, 0.5, "quadratic", "interp", d, 0.05), 0.01,
                    "nearest", mv, d)
    e = R.gap_fill(R.splat_motion(dd, mm, None, 0.5, "linear", "extrap"), 0.01)
    s1, v1, sd1, s0, v0, sd0 = RF.warp_frames(c, d, gf.to1, c, d, gf.to0)
    return locals()


# every kernel call warm() makes, each tagged with its kernel family: "core" (mob-fgsr,
# mv-warp, blend and the shared dilation / splat / gap fill), "fsr3", "gffe" (a run loads
# the families its stages use). On a cold cache two processes take the tasks in this order,
# each the next one not yet taken: about longest compile first, and a task's shared kernels
# in an earlier task, so that the other process finds them in the cache instead of
# compiling them a second time. The comments: seconds each task took in this order in one
# process, fresh cache, Zen 3 (benchmarks/compile_time.py; 0: compiled by an earlier task).
_TASKS = (
    ("core", lambda i: dilate_nearest_depth(i["d"], i["mv"])),  # 6 (every mv pipeline)
    ("core", lambda i: warp_blend(i["c"], i["d"], i["gf"].to1, i["c"], i["d"], i["gf"].to0,
                                  None, 0.5, 0.02, 0.13, static_from=i["gf"])),  # 42
    ("gffe", lambda i: _warm_gffe_geom(i)),  # 76 (the geometry of every gffe task below)
    ("fsr3", lambda i: interpolate_fsr3(i["c"], i["c"], i["mv"], i["d"], i["d"], 0.5,
                                        i["mv"])),  # 31 (one-pass, with AVX2 / AVX-512)
    ("gffe", lambda i: _warm_gffe_push_pull(i)),  # 35
    ("fsr3", lambda i: interpolate_fsr3(i["c"], i["c"], i["mv"], i["d"], i["d"], 0.5)),  # 13
    ("gffe", lambda i: _warm_gffe_background(i)),  # 43
    ("core", lambda i: blend_eq1(i["s0"], i["s1"], i["sd0"], i["sd1"], i["v0"], i["v1"], None,
                                 0.5, 0.02, 0.13, static_from=i["gf"])),  # 25
    ("core", lambda i: warp_frames(i["c"], i["d"], i["gf"].to1, i["c"], i["d"],
                                   i["gf"].to0)),  # 19
    ("gffe", lambda i: _warm_gffe_history(i)),  # 21
    ("core", lambda i: splat_motion(i["dd"], i["mm"], i["mv"], 0.5, "quadratic", "interp",
                                    i["d"], 0.05)),  # 0
    ("gffe", lambda i: _warm_gffe_trajectory(i)),  # 13
    ("fsr3", lambda i: fill_packed_field(vector_field(i["c"], i["c"], i["mv"],
                                                      (i["d"] * 100).to(torch.int64)))),  # 31
    ("core", lambda i: gap_fill(i["gf"], 0.01, "nearest", i["mv"], i["d"])),  # 12
    ("core", lambda i: gap_fill(splat_motion(i["dd"], i["mm"], i["mv"], 0.5, "quadratic",
                                             "interp", i["d"], 0.05),
                                0.01, "nearest", i["mv"], i["d"], in_place=True)),  # 0
    ("gffe", lambda i: _warm_gffe_fills(i)),  # 8
    ("core", lambda i: mv_warp(i["c"], i["d"], i["mv"], 0.5)),  # 10
    ("fsr3", lambda i: disocclusion_masks(i["d"], i["d"], i["d"], i["mv"])),  # 8
    ("fsr3", lambda i: vector_field(i["c"], i["c"], i["mv"][:, :1, :1].contiguous(),
                                    torch.ones(1, 1, 1, dtype=torch.int64), 0.5, False,
                                    block=8)),
    # (the general path's scatter and walk: frames one pixel wide)
    ("fsr3", lambda i: vector_field(i["c"][:, :, :1].contiguous(),
                                    i["c"][:, :, :1].contiguous(),
                                    torch.full((2, 8, 1), 3.0),
                                    (i["d"][:, :, :1] * 100).to(torch.int64))),
    ("fsr3", lambda i: pyramid_inpaint(i["c"], i["d"], i["d"] > 1.0, mode="first")),
    ("core", lambda i: fill_extrap_holes(i["e"], i["mv"], i["dd"])),  # 4
    ("core", lambda i: fill_extrap_holes(
        gap_fill(splat_motion(i["dd"], i["mm"], None, 0.5, "linear", "extrap", toward0=False),
                 0.01, in_place=True), i["mv"], i["dd"], in_place=True)),
    ("core", lambda i: dilate_nearest_depth(i["d"], i["mv"], 2)),
    ("fsr3", lambda i: reconstruct_depths(i["d"], i["mv"])),
    ("fsr3", lambda i: interpolated_depth(i["d"] * INF, i["mv"], 0.5, i["d"], i["d"])),
    ("fsr3", lambda i: block_flow(i["c"][:1] * 255.0, i["c"][1:2] * 255.0, 2, 8, 8)),
    ("core", lambda i: crossfade(i["c"], i["c"], i["d"], i["d"], i["mv"], 0.5, 0.5)),
    ("core", lambda i: any_nonzero(i["mv"])),
    ("core", lambda i: scene_change_score_tensor(i["c"], i["c"])),
    ("core", lambda i: scene_change_score_tensor(i["c"], i["c"], levels=False)),
    ("fsr3", lambda i: avg_pool2(i["c"])),
    ("fsr3", lambda i: luma8(i["c"])),
    ("fsr3", lambda i: luma8_u8(i["c"])),
    ("fsr3", lambda i: luma8_u8_of(field_luminance(i["c"]))),
    # (the per-level search and median: sub-pixel steps, other block sizes; the default
    # block flow is one chain kernel)
    ("fsr3", lambda i: block_flow(luma8(i["c"]), luma8(i["c"]), 7, 8, 8, True, True)),
    ("fsr3", lambda i: depth_priority(i["d"])),
    ("fsr3", lambda i: game_vector_field(i["c"], i["c"], i["mv"], i["d"])),
    ("fsr3", lambda i: output_vectors(i["mv"], 0.5)),
    ("fsr3", lambda i: field_luminance(i["c"])),
)
FAMILIES = ("core", "fsr3", "gffe")


def families_of(stages) -> set:
    """The kernel families a built pipeline's stages call (fgcli.stages.fsr3 -> "fsr3",
    fgcli.stages.gffe -> "gffe"; every kernel pipeline also uses the shared "core" ones)."""
    fams = {"core"}
    for st in stages:
        mod = type(st).__module__.rsplit(".", 1)[-1]
        if getattr(st, "uses_kernels", False) and mod in FAMILIES:
            fams.add(mod)
    return fams


def _warm_tasks(families=None, claims=None) -> None:
    """Call the kernels of _TASKS (of the given families; default all). With ``claims`` (a
    folder two processes share) only the tasks this process claims first: a task is taken
    by creating its file there, which succeeds in one process only."""
    import os

    i = _inputs()
    for k, (fam, call) in enumerate(_TASKS):
        if families is not None and fam not in families:
            continue
        if claims is not None:
            try:
                os.close(os.open(os.path.join(claims, str(k)), os.O_CREAT | os.O_EXCL))
            except FileExistsError:  # the other process has it
                continue
        call(i)


def _cache_cold(families=None) -> bool:
    """True when some kernel (of the given families; default all) has no usable on-disk
    cache index: none yet (a fresh install), or a stale one (its sources changed since: an
    upgrade; fgcli.kernels._common's stamp covers every kernel source file, so any change
    makes every index stale). warm() then compiles them in two processes."""
    try:
        import os

        for k in _warm_kernels(families):
            f = k._cache._cache_file
            if not os.path.exists(f._index_path) or not f._load_index():
                return True
        return False
    except AttributeError:  # numba internals moved: assume warm
        return False


def _warm_kernels(families=None) -> tuple:
    """The kernels warm(families) compiles on this CPU (what _cache_cold checks: one that
    warm() does not compile would leave the cache cold for ever)."""
    from fgcli.kernels import blend, field, fill, flow, fsr3, pyramid, scene, splat, warp

    from fgcli.kernels._intrin import HAVE_WINDOW16

    fams = set(FAMILIES if families is None else families)
    kernels = ()
    if "core" in fams:
        kernels += (splat.dilate_kernel, splat.dilate3_kernel, splat.splat_kernel,
                    splat.splat_resolve_kernel,
                    fill.gap_fill_kernel, fill.extrap_fill_kernel, warp.warp_kernel,
                    fill.gap_fill_inplace_kernel, fill.extrap_fill_inplace_kernel,
                    warp.mv_warp_kernel, blend.blend_kernel, blend.crossfade_kernel,
                    *((blend.warp_blend_kernel,) if HAVE_WINDOW16 else ()),
                    blend.any_nonzero_kernel, scene.scene_luma_kernel,
                    scene.scene_counts_kernel, scene.scene_bins_kernel)
    if "fsr3" in fams:
        from fgcli.kernels._intrin import HAVE_MPSADBW

        if HAVE_MPSADBW:  # (each search kernel compiled only where it runs: FSR 3's sizes)
            kernels += (flow.block_search_sad_kernel, flow.luma_u8_kernel,
                        flow.block_flow_u8_kernel)
        else:
            kernels += (flow.block_search_kernel,)
        kernels += (flow.vector_median3_kernel,
                    field.field_scatter_kernel, field.field_walk_kernel,
                    field.depth_scatter_pair_kernel, fsr3.disocclusion_kernel,
                    fsr3.interp_game_kernel, pyramid.pool2_kernel,
                    fsr3.interp_window_kernel if HAVE_WINDOW16 else fsr3.interp_flow_kernel,
                    pyramid.inpaint_prep_kernel, field.field_fill_prep_kernel,
                    pyramid.hole_index_kernel, pyramid.pool_chain_kernel,
                    pyramid.fill_levels_kernel,
                    flow.luma8_kernel, flow.luma8_u8_kernel,
                    flow.luma8_u8_plane_kernel,
                    field.entries_prio_kernel, field.agreement_block_kernel,
                    field.field_scatter_block_kernel, field.field_scatter_prio_kernel,
                    field.field_walk_prio_kernel, field.walk_sources_kernel,
                    field.walk_back_kernel,
                    field.luma_plane_kernel,
                    field.depth_rank_kernel,
                    fsr3.interp_depth_kernel, fsr3.scale_mv_kernel)
    from fgcli.kernels import geom, gffe

    if "gffe" in fams:
        kernels += (geom.unproject_kernel, geom.unproject_sky_kernel, geom.project_kernel,
                    geom.reproject_kernel, geom.reproject_sky_kernel)
        kernels += (gffe.sample_where_kernel, gffe.offsets_kernel, gffe.dilate_traj_kernel,
                    gffe.splat_min_kernel, gffe.bg_resolve_kernel, gffe.bg_bilinear_kernel,
                    gffe.pp_down0_kernel, gffe.pp_down_kernel, gffe.pp_up_kernel,
                    gffe.pp_final_kernel, gffe.reproject_took_kernel, gffe.vector_rule_kernel,
                    gffe.bg_fill_kernel, gffe.cells_of_kernel, gffe.hist_at_kernel,
                    gffe.hist_p_kernel,
                    gffe.hist_match_kernel, gffe.hist_taps_kernel, gffe.hist_sel_kernel,
                    gffe.select_rows_kernel, gffe.bits_count_kernel,
                    gffe.col_init_kernel, gffe.col_case_kernel, gffe.col_behind_kernel,
                    gffe.max3_kernel,
                    gffe.layer_fill_kernel, gffe.dilate_pos_kernel, gffe.dilate_dyn_pos_kernel,
                    gffe.row_counts_kernel, gffe.splat_fill_sparse_kernel,
                    gffe.reproject_mv_kernel,
                    gffe.pp_tile_scan_kernel, gffe.pp_tiles_kernel)
    return kernels


def warm(parallel: bool = True, families=None) -> float:
    """Load (or, on a machine's first run, compile into numba's on-disk cache) every kernel
    of the given families (default: all; see families_of) by calling it once on an 8x8
    input, so that cost is paid and measured at start-up instead of inside the first
    frame's timings. A cold cache is filled by two processes at once (numba compiles under
    the GIL; ~2x faster on 2 cores), each taking the next task of _TASKS that the other has
    not taken. Returns the seconds it took."""
    import os
    import subprocess
    import sys
    import time

    t0 = time.perf_counter()
    proc = claims = None
    fams = None if families is None else sorted(set(families) & set(FAMILIES))
    if parallel and (os.cpu_count() or 1) > 1 and sys.executable and _cache_cold(fams):
        import tempfile

        claims = tempfile.mkdtemp(prefix="fgen-warm-")
        try:
            proc = subprocess.Popen(
                [sys.executable, "-c", "from fgcli.kernels.ops import _warm_tasks; "
                 f"_warm_tasks({fams!r}, {claims!r})"], stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL)
        except OSError:  # no second process here: compile everything in this one
            proc = None
    try:
        if proc is not None:
            try:
                _warm_tasks(fams, claims)
            finally:
                proc.wait()
        # every kernel loaded here: the other process's from the cache it wrote (or compiled
        # here, one task after the other, if it failed)
        _warm_tasks(fams)
    finally:
        if claims is not None:
            import shutil

            shutil.rmtree(claims, ignore_errors=True)
    return time.perf_counter() - t0


def any_nonzero(t) -> bool:
    """frame_facts' motion test: any non-zero (or NaN) element, with an early exit."""
    if t.device.type != "cpu" or t.dtype != torch.float32:
        lo, hi = torch.aminmax(t)
        return not (float(lo) == 0.0 and float(hi) == 0.0)
    from fgcli.kernels.blend import any_nonzero_kernel

    return bool(any_nonzero_kernel(_a(t).reshape(-1)))


# ----------------------------------------------------------------------------- scene cuts


SCENE_WINDOW = 256  # float32 steps of the luma either side of a level's edge (_scene_levels)


@functools.lru_cache(maxsize=4)
def _scene_levels(bins: int):
    """scene_bins_kernel's tables: the reference's level of a sampled luma L in [0, 1],
    round(pow(L, 1/2.2) * (bins - 1)), as a function of L's float32 bits, made from
    torch's own pow. Level k + 1 begins near L_k = ((k + 0.5) / (bins - 1))^2.2; in a
    window of SCENE_WINDOW float32 steps either side of it (tab: every level there, by
    both of torch's pow paths: the vector one, and the scalar one a tensor's tail takes;
    -1 where they disagree, the caller's sign to take the reference's own pow) the level
    is the table's, elsewhere it is the number of windows below: pow's error (an ulp or
    two; ~2.2 float32 steps of L per ulp of the level) cannot move a luma that far from
    an edge across it. lut: per bucket of 2**LUT_SHIFT bit patterns, its level, or -1
    where a window reaches into it. None when the windows overlap or their ends do not
    hold the levels expected (the caller takes the reference's pow)."""
    from fgcli.kernels.scene import LUT_SHIFT

    if not isinstance(bins, int) or not 2 <= bins <= 127:
        return None
    e = 1.0 / 2.2
    r = SCENE_WINDOW
    nb = bins - 1
    lo = np.empty(nb, dtype=np.int64)
    for k in range(nb):
        lo[k] = int(np.float32(((k + 0.5) / nb) ** 2.2).view(np.int32)) - r
    if lo[0] <= 0 or np.any(np.diff(lo) <= 2 * r) or lo[-1] + 2 * r >= 0x3F800000:
        return None
    bits = (lo[:, None] + np.arange(2 * r + 1)[None, :]).astype(np.int32)
    x = torch.from_numpy(bits.view(np.float32).reshape(-1).copy())

    def level(v):
        return torch.round(v * float(nb)).clamp(0, nb).to(torch.int64).numpy()

    n = x.numel()
    pad = -n % 64  # (a multiple of 64 elements: every one in the vector body)
    vec = level(torch.pow(torch.cat([x, x[:pad]]), e)[:n])
    sca = level(torch.cat([torch.pow(x[i:i + 15].clone(), e) for i in range(0, n, 15)]))
    vec, sca = vec.reshape(nb, -1), sca.reshape(nb, -1)
    k = np.arange(nb)
    if not (np.all(vec[:, 0] == k) and np.all(sca[:, 0] == k) and np.all(vec[:, -1] == k + 1)
            and np.all(sca[:, -1] == k + 1)):
        return None
    tab = np.where(vec == sca, vec, -1).astype(np.int8)
    top = 0x3F800000 >> LUT_SHIFT  # (L <= 1: buckets up to 1.0's)
    start = np.arange(top + 1, dtype=np.int64) << LUT_SHIFT
    end = start + (1 << LUT_SHIFT) - 1
    lut = np.searchsorted(lo + 2 * r, start, side="right").astype(np.int8)  # (windows below)
    for k in range(nb):  # (buckets a window reaches into)
        lut[(start <= lo[k] + 2 * r) & (end >= lo[k])] = -1
    return lut, lo.astype(np.int32), tab


def scene_change_score_tensor(c0, c1, bins=32, regions=3, stride=None, levels=True):
    """fgcli.ops.scene.scene_change_score_tensor with the sampling and counting in numba
    (fgcli.kernels.scene): the same score, bit for bit. The gamma levels by
    scene_bins_kernel's tables (_scene_levels: one pass, no pow), or where those leave a
    sample open, or with levels False, by the reference's own torch pow of the sampled
    luma (scene_luma_kernel, then scene_counts_kernel): 1.8x faster."""
    from fgcli.ops import scene as SC

    if not _cpu(c0, c1) or not isinstance(bins, int) or not isinstance(regions, int) or \
            bins < 1 or regions < 1:
        return SC.scene_change_score_tensor(c0, c1, bins, regions, stride)
    c0 = check_tensor(c0, "c0", 3, allow_batch=False)
    c1 = check_tensor(c1, "c1", 3, allow_batch=False)
    check_same(c0, "c0", (c1, "c1"))
    from fgcli.kernels.scene import scene_bins_kernel, scene_counts_kernel, scene_luma_kernel

    h, w = c0.shape[-2:]
    s = SC.score_stride(h, w, regions, stride)
    tabs = _scene_levels(bins) if levels else None
    counts = np.zeros((2, regions * regions, bins), dtype=np.float32)
    if tabs is None or scene_bins_kernel(_a(c0), _a(c1), s, *tabs, regions, bins, counts):
        lum = np.empty((2, -(-h // s), -(-w // s)), dtype=np.float32)
        scene_luma_kernel(_a(c0), _a(c1), s, lum)
        gamma = torch.from_numpy(lum).pow_(1.0 / 2.2)  # the reference's own pow
        counts[:] = 0.0
        scene_counts_kernel(gamma.numpy(), bins, regions, counts)
    hist = torch.from_numpy(counts)
    hist = hist / hist.sum(dim=2, keepdim=True).clamp(min=1.0)
    return SC.kl_score(hist[0], hist[1])


# ----------------------------------------------------------------------------- optical flow


MPSADBW = True  # tests switch it off to compare with the portable kernel


def _block_level(cur, prev, pred, block, search):
    """fgcli.ops.fsr3._block_level (integer vectors) by the numba kernel."""
    from fgcli.kernels._intrin import HAVE_MPSADBW
    from fgcli.kernels.flow import block_search_kernel, block_search_sad_kernel

    out = np.empty((2,) + tuple(pred.shape[-2:]), dtype=np.int64)
    if block == 8 and search == 8 and MPSADBW and HAVE_MPSADBW:
        # (cur and prev hold whole numbers in 0..255: the 8-bit conversion is exact)
        block_search_sad_kernel(_a(cur.to(torch.uint8)), _a(prev.to(torch.uint8)),
                                _a(pred.to(torch.int64)), out)
        return torch.from_numpy(out).to(torch.float32)
    block_search_kernel(_a(cur.to(torch.int32)), _a(prev.to(torch.int32)),
                        _a(pred.to(torch.int64)), int(block), int(search), out)
    return torch.from_numpy(out).to(torch.float32)


def _median3(f):
    """fgcli.ops.fsr3._vector_median3 (integer vector fields) by the numba kernel (the
    reference's stacked 9 x 9 distances cost ~1 ms per level in op overhead)."""
    from fgcli.kernels.flow import vector_median3_kernel

    fa = _a(f.to(torch.float32))
    out = np.empty_like(fa)
    vector_median3_kernel(fa, out)
    return torch.from_numpy(out)


def block_flow(lum0, lum1, levels=7, block=8, search=8, median=True, subpixel=False):
    from fgcli.kernels._intrin import HAVE_MPSADBW
    from fgcli.ops import fsr3 as FS

    if not _cpu(lum0, lum1) or block > 256:  # (the kernel's float32 SADs: exact below 2**24)
        return FS.block_flow(lum0, lum1, levels, block, search, median, subpixel)
    if block == 8 and search == 8 and MPSADBW and HAVE_MPSADBW and not subpixel:
        return _block_flow_u8(lum0, lum1, levels, median)
    return FS.block_flow_chain(_block_level, lum0, lum1, levels, block, search, median,
                               subpixel, pool=avg_pool2, median3=_median3)


def _block_flow_u8(lum0, lum1, levels, median):
    """fgcli.ops.fsr3.block_flow_chain for FSR 3's sizes (8x8 blocks, offsets -8..7, no
    sub-pixel step) with the pyramids as bytes (luma8_u8's, or fgcli.kernels.flow's
    luma_u8_kernel of float levels: the reference's whole-number levels, exactly) searched
    by the mpsadbw kernel, the whole chain (pyramids, then search and median per level) in
    one kernel call (block_flow_u8_kernel): no float32 levels, no per-level conversions,
    no per-level calls. The same vectors."""
    from fgcli.kernels.flow import block_flow_u8_kernel, flow_chain_layout, luma_u8_kernel
    from fgcli.ops import fsr3 as FS

    if not (lum0.dtype == lum1.dtype == torch.uint8 and lum0.dim() == 3 and
            lum0.shape == lum1.shape and lum0.shape[0] == 1 and lum0.numel() > 0):
        lum0 = FS.check_tensor(lum0, "lum0", 1, allow_batch=False)
        lum1 = FS.check_tensor(lum1, "lum1", 1, allow_batch=False)
        FS.check_same(lum0, "lum0", (lum1, "lum1"))
    planes = []
    for lum in (lum0, lum1):
        if lum.dtype == torch.uint8:  # (luma8_u8's bytes: the level as it is)
            planes.append(_a(lum)[0])
            continue
        lv = np.empty(lum.shape[-2:], dtype=np.uint8)
        luma_u8_kernel(_a(lum)[0], lv)
        planes.append(lv)
    h, w = planes[0].shape
    hs, ws, offs, bh, bw, boffs = flow_chain_layout(h, w, levels)
    bufs = [np.empty(int(offs[-1]), dtype=np.uint8) for _ in range(2)]
    fbuf = np.empty(int(boffs[-1]), dtype=np.float32)
    block_flow_u8_kernel(planes[0], planes[1], bufs[0], bufs[1], hs, ws, offs, bh, bw, boffs,
                         bool(median), fbuf)
    return torch.from_numpy(fbuf[:int(boffs[1])].reshape(2, int(bh[0]), int(bw[0])))


@functools.lru_cache(maxsize=None)
def packed_steps(table):
    """A step table (fgcli.ops.fsr3.step_table: luma8_table, depth_priority_table) packed
    for fgcli.kernels._common.step_code, one int32 per bucket: base[i] << (shift + 1) |
    the low shift bits of thr[i] (1 << shift: no step in the bucket). Returns (tab, b0,
    shift, bottom = base[0]), the scalars int32."""
    from fgcli.ops import fsr3 as FS

    base, thr, b0 = table()
    sh = {FS.luma8_table: FS.LUMA8_SHIFT, FS.depth_priority_table: FS.DEPTH_SHIFT}[table]
    n = base.shape[0]
    tb = thr.view(np.int32).astype(np.int64)
    has = ~np.isnan(thr)
    # each step inside its own bucket; none in the last (values above it read it), and
    # the packed fields fit an int32
    assert np.array_equal(tb[has] >> sh, np.arange(n)[has] + b0) and not has[-1]
    assert base.max() < 2 ** (30 - sh) and np.array_equal(base, np.floor(base))
    low = np.where(has, tb & ((1 << sh) - 1), 1 << sh)
    tab = ((base.astype(np.int64) << (sh + 1)) | low).astype(np.int32)
    return tab, np.int32(b0), np.int32(sh), np.int32(base[0])


def luma8(color):
    """fgcli.ops.fsr3.luma8: the luminance, its clip and the table lookup in one kernel
    (the reference's table)."""
    from fgcli.ops import fsr3 as FS

    if not (_f32cpu(color) and color.shape[0] == 3):
        return FS.luma8(color)
    from fgcli.kernels.flow import luma8_kernel

    h, w = color.shape[-2:]
    out = _empty(1, h, w)
    luma8_kernel(_a(color), *packed_steps(FS.luma8_table), out.numpy()[0])
    return out


def luma8_u8(color):
    """fgcli.ops.fsr3.luma8_u8 by one kernel (luma8's, bytes out)."""
    from fgcli.ops import fsr3 as FS

    if not (_f32cpu(color) and color.shape[0] == 3):
        return FS.luma8_u8(color)
    from fgcli.kernels.flow import luma8_u8_kernel

    h, w = color.shape[-2:]
    out = _empty(1, h, w, dtype=torch.uint8)
    luma8_u8_kernel(_a(color), *packed_steps(FS.luma8_table), out.numpy()[0])
    return out


def luma8_u8_of(lum):
    """fgcli.ops.fsr3.luma8_u8_of by one kernel pass over the plane."""
    from fgcli.ops import fsr3 as FS

    if not (_f32cpu(lum) and lum.dim() == 3 and lum.shape[0] == 1):
        return FS.luma8_u8_of(lum)
    from fgcli.kernels.flow import luma8_u8_plane_kernel

    h, w = lum.shape[-2:]
    out = _empty(1, h, w, dtype=torch.uint8)
    luma8_u8_plane_kernel(_a(lum)[0], *packed_steps(FS.luma8_table), out.numpy()[0])
    return out


def depth_priority(depth):
    """fgcli.ops.fsr3.depth_priority: the sanitising and the table lookup in one kernel
    (the reference's table)."""
    from fgcli.ops import fsr3 as FS

    if not (_f32cpu(depth) and depth.shape[0] == 1):
        return FS.depth_priority(depth)
    from fgcli.kernels.field import depth_rank_kernel

    h, w = depth.shape[-2:]
    hi = _empty(1, h, w, dtype=torch.int64)
    depth_rank_kernel(_a(depth)[0], *packed_steps(FS.depth_priority_table), hi.numpy()[0])
    return hi


def sample_flow_field(field, h, w, block=8):
    """fgcli.ops.fsr3.sample_flow_field: the block field unpacked and the per-axis taps by
    the reference's own torch code (block resolution, 1-D), the per-pixel mean by the
    numba kernel."""
    from fgcli.ops import fsr3 as FS

    if not (isinstance(field, torch.Tensor) and field.device.type == "cpu" and
            field.dim() == 3 and field.shape[0] == 2 and h > 0 and w > 0):
        return FS.sample_flow_field(field, h, w, block)
    from fgcli.kernels.fsr3 import sample_flow_kernel

    vec, _, _ = FS.unpack_vector_field(field)
    fh, fw = vec.shape[-2:]
    ys = [_a(t) for t in FS.flow_field_coords(h, fh, block)]
    xs = [_a(t) for t in FS.flow_field_coords(w, fw, block)]
    out = _empty(2, h, w)
    sample_flow_kernel(_a(vec), *ys, *xs, out.numpy())
    return out


def _padded_base(field):
    """(buffer, 1) when field is the interior view of a padded (2, H + 2, W + 2) buffer
    (vector_field's result: read in place, no contiguous copy), else (None, 0)."""
    h, w = field.shape[-2:]
    start = field.storage_offset() - (w + 3)
    if field.is_contiguous() or start < 0 or \
            field.stride() != ((h + 2) * (w + 2), w + 2, 1) or \
            field.untyped_storage().nbytes() < \
            (start + 2 * (h + 2) * (w + 2)) * field.element_size():
        return None, 0
    b = field.as_strided((2, h + 2, w + 2), ((h + 2) * (w + 2), w + 2, 1), start)
    return b.numpy(), 1


def field_luminance(color):
    """fgcli.ops.fsr3.field_luminance by luma_plane_kernel."""
    from fgcli.ops import fsr3 as FS

    if not (_f32cpu(color) and color.shape[0] == 3):
        return FS.field_luminance(color)
    from fgcli.kernels.field import luma_plane_kernel

    out = _empty(1, *color.shape[-2:])
    luma_plane_kernel(_a(color), out.numpy()[0])
    return out


def _block_field(color0, color1, vec, hi, alpha, sh, thr, luma0):
    """vector_field of block vectors without the secondary walk (the optical-flow field):
    the pixels' agreement by one kernel, the entries made and scattered by another, or
    None where the general path serves (frames too large for pair loads)."""
    from fgcli.ops import fsr3 as FS

    from fgcli.kernels.field import agreement_block_kernel, field_scatter_block_kernel
    from fgcli.kernels.warp import flat_ok

    h, w = color1.shape[-2:]
    if not flat_ok(h, w, 1):
        return None
    color0, color1, _, a = FS.entries_args(color0, color1, color1[:2], alpha)
    l0 = _frame0_luma(color0, luma0, h, w)
    gxn, gyn, kx, ky = _grid(h, w)
    va = _a(vec)
    lo = np.empty((h, w), dtype=np.uint8)
    agreement_block_kernel(l0, _a(color1), va, sh, gxn, gyn, kx, ky, lo)
    padded = np.empty((2, h + 2, w + 2), dtype=np.uint32)  # (zeroed by the kernel)
    field_scatter_block_kernel(va, _a(hi).reshape(hi.shape[-2:]), sh, lo, F32(1.0 - a),
                               F32(thr), padded[0].reshape(-1), padded[1].reshape(-1))
    return torch.from_numpy(padded)[:, 1:h + 1, 1:w + 1]


def _frame0_luma(color0, luma0, h, w):
    """vector_field's plane of frame 0's luminance: luma0 (checked) or made here."""
    from fgcli.kernels.field import luma_plane_kernel

    if luma0 is not None and tuple(luma0.shape) != (1, h, w):
        raise ValueError(f"luma0: expected shape {(1, h, w)}, got {tuple(luma0.shape)}")
    if luma0 is not None and _f32cpu(luma0):
        return _a(luma0)[0]
    l0 = np.empty((h, w), dtype=np.float32)  # (a luma0 of another type or device: this
    luma_plane_kernel(_a(color0), l0)        # frame's own, the same values)
    return l0


def _pixel_field(color0, color1, vec, hi, alpha, walk_on, max_secondary, thr, luma0,
                 depth=None):
    """vector_field of per-pixel vectors (the game field): each pixel's priority (and the
    walk's lengths) by one kernel, the primary scatter and the secondary walk by kernels
    that make the positions, entries and steps from the vectors and priorities as they go
    (no frame-sized positions, entries and steps: 41 MB written and read back at 1080p);
    or None where the general path serves (vector_field). depth (hi None): the priorities
    are depth_priority(depth), made by the priority kernel (game_vector_field)."""
    from fgcli.ops import fsr3 as FS

    from fgcli.kernels.field import (entries_prio_kernel, field_scatter_prio_kernel,
                                     field_walk_prio_kernel)
    from fgcli.kernels.warp import flat_ok

    if depth is not None:
        if not (_f32cpu(depth) and tuple(depth.shape) == (1,) + tuple(vec.shape[-2:])):
            return None
    elif hi.dtype != torch.int64 or hi.numel() != vec[0].numel():
        return None
    vh, vw = vec.shape[-2:]  # (the walk's pre-pass indexes the padded fields in int32)
    if color0.shape[0] != 3 or not (flat_ok(vh, vw, 1) and flat_ok(vh + 2, vw + 2, 1)):
        return None
    color0, color1, vec, a = FS.entries_args(color0, color1, vec, alpha)
    h, w = color1.shape[-2:]
    l0 = _frame0_luma(color0, luma0, h, w)
    gxn, gyn, kx, ky = _grid(h, w)
    va = _a(vec)
    a1 = F32(1.0 - a)
    prio = np.empty((h, w), dtype=np.uint16)
    dist = np.empty((h, w), dtype=np.float32) if walk_on else l0  # (unwritten without)
    cnt = np.empty(h, dtype=np.int64)
    # the walking pixels: torch.sqrt of the squared length >= 1 (tw: the least such
    # float32, checked against torch.sqrt itself; <= 1, so the others stay below 1)
    tw = _sqrt_at_least(1.0)
    sparse = tw is not None and tw <= 1.0
    if depth is None:
        hv, dv = _a(hi).reshape(h, w), np.empty((0, 0), dtype=np.float32)
    else:
        hv, dv = np.empty((0, 0), dtype=np.int64), _a(depth)[0]
    entries_prio_kernel(l0, _a(color1), va, hv, a1, gxn, gyn, kx, ky, prio, bool(walk_on), dist,
                        dv, *packed_steps(FS.depth_priority_table),
                        F32(tw if sparse else 0.0), cnt)
    padded = np.empty((2, h + 2, w + 2), dtype=np.uint32)  # (zeroed by the kernel)
    buf = [padded[0].reshape(-1), padded[1].reshape(-1)]
    field_scatter_prio_kernel(va, prio, a1, F32(thr), buf[0], buf[1])
    if walk_on and h * w:
        steps = _walk_lengths(dist, cnt, tw, max_secondary) if sparse else None
        if steps is None:  # (every pixel's root, as the reference takes them)
            dt = torch.from_numpy(dist)
            torch.sqrt(dt, out=dt)  # the reference's sqrt (MKL's: not IEEE's everywhere)
            steps = int(min(max_secondary, np.floor(float(dt.max()))))
        if steps >= 1:
            field_walk_prio_kernel(va, prio, dist, cnt, a1, steps, buf[0], buf[1])
    return torch.from_numpy(padded)[:, 1:h + 1, 1:w + 1]


def _walk_lengths(dist, cnt, tw, max_secondary):
    """The secondary walk's lengths in place in dist (H, W), the squared lengths: torch.sqrt
    of those at or above tw only (cnt: entries_prio_kernel's per-row counts; the square
    root of a value does not depend on its position or neighbours, which
    test_torch_math_position_free checks), the others (below 1: they do not walk) left as
    they are. Returns the walk's steps (the reference's floor of the largest length, at
    most max_secondary; 0 when none walks). ~0.8 ms less per 1080p frame than the whole
    plane's roots and maximum, with a few percent of the pixels walking."""
    from fgcli.kernels.field import walk_back_kernel, walk_sources_kernel

    start = np.zeros(cnt.size + 1, dtype=np.int64)
    np.cumsum(cnt, out=start[1:])
    n = int(start[-1])
    if n == 0:
        return 0
    vals = np.empty(n, dtype=np.float32)
    walk_sources_kernel(dist, F32(tw), start, vals)
    lv = torch.from_numpy(vals)
    torch.sqrt(lv, out=lv)  # (the reference's sqrt, MKL's)
    rmax = np.empty(dist.shape[0], dtype=np.float32)
    walk_back_kernel(dist, F32(tw), start, vals, rmax)
    return int(min(max_secondary, np.floor(float(rmax.max()))))


def game_vector_field(color0, color1, vec, depth, alpha=0.5, secondary=True,
                      max_secondary=64, tap_threshold=0.05, length_bound=None, luma0=None):
    """fgcli.ops.fsr3.game_vector_field: vector_field's per-pixel path with the depth
    priorities made inside its priority kernel (no int64 plane: ~1.5 ms per 1080p frame);
    other inputs: depth_priority, then vector_field."""
    if _cpu(color0, color1, vec, depth) and isinstance(depth, torch.Tensor) and \
            isinstance(vec, torch.Tensor) and vec.dim() == 3 and \
            (vec.shape[-2] + 2) * (vec.shape[-1] + 2) < 2 ** 31:  # (int32 indices)
        r = _pixel_field(color0, color1, vec, None, alpha, secondary and max_secondary > 0,
                         max_secondary, tap_threshold, luma0, depth=depth)
        if r is not None:
            return r
    from fgcli.ops import fsr3 as FS

    FS.check_same(FS.check_tensor(vec, "vec", 2, allow_batch=False), "vec",
                  (FS.check_tensor(depth, "depth", 1, allow_batch=False), "depth"))
    return vector_field(color0, color1, vec, depth_priority(depth), alpha, secondary,
                        max_secondary, tap_threshold, length_bound, luma0=luma0)


def vector_field(color0, color1, vec, hi, alpha=0.5, secondary=True, max_secondary=64,
                 tap_threshold=0.05, length_bound=None, block=1, luma0=None):
    """fgcli.ops.fsr3.vector_field: the pixels' priorities (and the secondary walk's
    lengths) by one numba kernel, the scatter (primary footprints, then the secondary
    walk) by others, which make the positions and entries as they go (_pixel_field; block
    vectors without the walk: _block_field). The field is uint32 (2, H, W), the
    reference's entries (all below 2**32) in half the bytes; unpack_vector_field reads
    either. block (a power of two, no walk): the kernels read each pixel's block's vector
    and priority themselves (the upsampled copies, (2, H, W) float32 and (1, H, W) int64,
    cost ~3 ms per 1080p frame). luma0: field_luminance(color0), when the caller has it
    (~1 ms per 1080p field)."""
    from fgcli.ops import fsr3 as FS

    sh = 0
    if block != 1:
        h, w = color1.shape[-2:] if isinstance(color1, torch.Tensor) else (0, 0)
        b = block if isinstance(block, int) and not isinstance(block, bool) else 0
        grid = (-(-h // b), -(-w // b)) if b > 0 else None
        if (b > 1 and b & (b - 1) == 0 and _cpu(color0, color1, vec, hi)
                and color0.shape[0] == 3 and tuple(color0.shape) == tuple(color1.shape)
                and vec.dtype == torch.float32 and tuple(vec.shape) == (2,) + grid
                and hi.dtype == torch.int64 and tuple(hi.shape) == (1,) + grid):
            sh = b.bit_length() - 1
        else:
            vec = FS.upsample_block_flow(vec, h, w, block)
            hi = FS.upsample_block_flow(hi, h, w, block)
    if not _cpu(color0, color1, vec, hi) or \
            (color1.shape[-2] + 2) * (color1.shape[-1] + 2) >= 2 ** 31:  # (int32 indices)
        return FS.vector_field(color0, color1, vec, hi, alpha, secondary, max_secondary,
                               tap_threshold, length_bound, luma0=luma0)
    walk_on = secondary and max_secondary > 0
    if sh > 0 and not walk_on:
        r = _block_field(color0, color1, vec, hi, alpha, sh, tap_threshold, luma0)
        if r is not None:
            return r
    if sh > 0:  # per pixel: the walk's sources, or frames too large for pair loads
        h, w = color1.shape[-2:]
        vec = FS.upsample_block_flow(vec, h, w, block)
        hi = FS.upsample_block_flow(hi, h, w, block)
    r = _pixel_field(color0, color1, vec, hi, alpha, walk_on, max_secondary, tap_threshold,
                     luma0)
    if r is not None:
        return r
    # other inputs (frames too large for pair loads, priorities of another type): the
    # reference's own entries, scattered by the kernels
    from fgcli.kernels.field import field_scatter_kernel, field_walk_kernel

    vf, pos, _, _, keys, (h, w, a) = FS.field_entries(color0, color1, vec, hi, alpha, luma0)
    k0, k1 = [_a(k).astype(np.uint32) for k in keys]  # (entries are below 2**32)
    padded = np.empty((2, h + 2, w + 2), dtype=np.uint32)  # (zeroed by the kernel)
    buf = [padded[0].reshape(-1), padded[1].reshape(-1)]
    pa = _a(pos)
    field_scatter_kernel(pa, k0, k1, h, w, F32(tap_threshold), buf[0], buf[1])
    if walk_on and vf.shape[1]:
        dt = FS._length(vf * (1.0 - a))
        steps = int(min(max_secondary, np.floor(float(dt.max()))))
        if steps >= 1:
            field_walk_kernel(pa, k0, k1, _a(dt), _a(vf / dt.clamp(min=1e-6)), h, w, steps,
                              buf[0], buf[1])
    # the interior of the padded buffers, as a view (unpack_vector_field reads it in place;
    # the stacked copy cost 1.4 ms per 1080p field); uint32, not the reference's int64:
    # the entries are below 2**32, and half the bytes made the scatter ~30 % faster
    return torch.from_numpy(padded)[:, 1:h + 1, 1:w + 1]


_BAND = 1 << 16  # float32 values each side of short**2 that _sqrt_at_least checks


@functools.lru_cache(maxsize=16)
def _sqrt_at_least(short: float):
    """The least float32 x with ``torch.sqrt(x) >= short`` (the reference's test of a
    vector's length, _length(v) >= short_mv), so that a kernel decides it on the squared
    length alone as ``x >= T``, without the square root (MKL's vsSqrt on the CPU: not
    correctly rounded, so neither IEEE sqrt nor x >= short**2 would always agree).

    Found with torch.sqrt itself on the 2 * _BAND float32 values around short**2: T is
    returned only when the test is false below T and true from T on within that band
    (monotone: far outside it no sqrt error of a few ulps could change the answer);
    else None (the caller takes the square roots). short <= 0: 0.0 (every length passes);
    NaN or inf: inf (none does)."""
    s = float(short)
    if s != s or s == float("inf"):
        return np.float32(np.inf)
    if s <= 0.0:
        return np.float32(0.0)
    c = int(np.float32(s * s).view(np.int32))
    lo, hi = max(c - _BAND, 0), min(c + _BAND, 0x7F800000)
    x = torch.from_numpy(np.arange(lo, hi, dtype=np.int32).view(np.float32))
    ok = (torch.sqrt(x) >= s).numpy()
    first = int(np.argmax(ok))
    if not ok[-1] or (first == 0 and lo > 0) or not ok[first:].all() or ok[:first].any():
        return None
    return x[first].numpy().astype(np.float32)[()]


def reconstruct_depths(depth, mv, alpha=0.5, short_mv=0.1, tap_threshold=0.05):
    """fgcli.ops.fsr3.reconstruct_depths: the sources and both footprint scatters in one
    numba kernel. The short-vector test runs on the squared lengths against
    _sqrt_at_least's threshold (no length plane, no square roots: ~2 ms per 1080p frame)."""
    from fgcli.ops import fsr3 as FS

    if not (_cpu(depth, mv) and depth.dtype == torch.float32 and mv.dtype == torch.float32
            and depth.shape[0] == 1 and mv.shape[0] == 2 and depth.shape[1:] == mv.shape[1:]
            and 0 < depth.numel() < 2 ** 31):  # (int32 texel indices)
        return FS.reconstruct_depths(depth, mv, alpha, short_mv, tap_threshold)
    from fgcli.kernels.field import depth_scatter_pair_kernel

    a = check_alpha(alpha)
    h, w = depth.shape[-2:]
    out = _empty(2, h, w)  # (set to +inf by the kernel)
    ks = np.array([1.0, 1.0 - a], dtype=np.float32)  # torch rounds the scalars so
    ma = _a(mv)
    t = _sqrt_at_least(short_mv)
    if t is None:  # (never seen: the lengths themselves, as the reference takes them)
        from fgcli.kernels.field import length_kernel

        lens = np.empty((h, w), dtype=np.float32)
        length_kernel(ma, lens)
        torch.sqrt(torch.from_numpy(lens), out=torch.from_numpy(lens))  # (MKL's, as _length)
        depth_scatter_pair_kernel(_a(depth)[0], ma, lens, F32(short_mv), False, ks,
                                  F32(tap_threshold), out.numpy())
    else:
        depth_scatter_pair_kernel(_a(depth)[0], ma, _DUMMY2, t, True, ks, F32(tap_threshold),
                                  out.numpy())
    return out[0:1], out[1:2]


# ----------------------------------------------------------------------------- gffe

from fgcli.ops import gffe as G  # noqa: E402


def _f32(*xs) -> tuple:
    """float64 coefficients -> float32 scalars (as torch rounds a Python float scalar)."""
    return tuple(F32(float(x)) for x in xs)


def _unproject_coefs(cam, size):
    """unproject_kernel's (kx, ky, A, M) from a camera, computed as fgcli.ops.gffe.unproject
    does in float64 (remembered per matrices and size: a gffe frame asks for them five
    times, ~50 us each)."""
    v, p = G._mats(cam)
    return _unproject_coefs_of(v.tobytes(), p.tobytes(), int(size[0]), int(size[1]))


def _project_coefs(cam, size):
    """project_kernel's (V, P, hw, hh), as fgcli.ops.gffe.project computes them
    (remembered as _unproject_coefs)."""
    v, p = G._mats(cam)
    return _project_coefs_of(v.tobytes(), p.tobytes(), int(size[0]), int(size[1]))


@functools.lru_cache(maxsize=32)
def _unproject_coefs_of(vb, pb, H, W):
    v = np.frombuffer(vb, dtype=np.float64).reshape(4, 4)
    p = np.frombuffer(pb, dtype=np.float64).reshape(4, 4)
    ip = np.linalg.inv(p)
    ivm = np.linalg.inv(v)
    a = []
    for zn in (-1.0, 1.0):
        c = ip @ np.array([0.0, 0.0, zn, 1.0])
        for i in range(4):
            a += [ip[i, 0], ip[i, 1], c[i]]
    return F32(2.0 / W), F32(2.0 / H), _f32(*a), _f32(*ivm[:3].reshape(-1))


@functools.lru_cache(maxsize=32)
def _project_coefs_of(vb, pb, H, W):
    v = np.frombuffer(vb, dtype=np.float64).reshape(4, 4)
    p = np.frombuffer(pb, dtype=np.float64).reshape(4, 4)
    m = p @ v
    return _f32(*v[2]), _f32(*m[[0, 1, 3]].reshape(-1)), F32(0.5 * W), F32(0.5 * H)


def _samples(depth, px, py):
    """unproject_kernel's px (h, w) or (1, w) and py (h, w) or (h, 1) numpy arrays, or
    None where the kernel does not take these (the reference runs)."""
    h, w = depth.shape[-2:]
    if px is None and py is None:
        return _grid_half(h, w)
    if px is None or py is None or not all(
            isinstance(t, torch.Tensor) and t.device.type == "cpu" and t.dtype == torch.float32
            and tuple(t.shape) == (h, w) for t in (px, py)):
        return None
    qx = px[:1] if px.stride(0) == 0 else px
    qy = py[:, :1] if py.stride(1) == 0 else py
    return _a(qx), _a(qy)


@functools.lru_cache(maxsize=8)
def _grid_half(h: int, w: int):
    """Pixel centres (x + 0.5 as a (1, w) row, y + 0.5 as an (h, 1) column)."""
    a = aux(h, w, "cpu")
    return _a(a["xh"].reshape(1, w)), _a(a["yh"].reshape(h, 1))


def _geom_ok(depth, size) -> bool:
    if not (isinstance(depth, torch.Tensor) and depth.device.type == "cpu"
            and depth.dtype == torch.float32 and depth.dim() == 3 and depth.shape[0] == 1
            and depth.numel() > 0):
        return False
    return size is None or len(size) == 2


def _sky_rows(nsky, ss):
    """(y0, ss's rows y0 .. y1 with torch.sqrt taken of those with sky pixels) for the rows
    that have sky pixels, or None: the sky directions' norms by the function the reference
    calls (MKL's sqrt is not IEEE's; fgcli.kernels.geom)."""
    rows = np.flatnonzero(nsky)
    if rows.size == 0:
        return None
    y0, y1 = int(rows[0]), int(rows[-1]) + 1
    if rows.size == y1 - y0:
        nrm = torch.from_numpy(ss[y0:y1])
        torch.sqrt(nrm, out=nrm)
    else:  # the sky rows alone (the rows between them are never read; those a rows=
        # pass skipped hold garbage: NaNs and denormals slow MKL's sqrt down 5x): MKL's
        # result for an element does not depend on its neighbours or its position
        # (tests/test_kernels.py::test_torch_math_position_free)
        sub = torch.from_numpy(ss[rows])
        torch.sqrt(sub, out=sub)
        ss[rows] = sub.numpy()
    return y0, ss[y0:y1]


def unproject(depth, cam, px=None, py=None, size=None):
    """fgcli.ops.gffe.unproject by geom.unproject_kernel (+ unproject_sky_kernel where
    there is sky)."""
    s = _samples(depth, px, py) if _geom_ok(depth, size) else None
    if s is None:
        return G.unproject(depth, cam, px, py, size)
    h, w = depth.shape[-2:]
    out = _empty(4, h, w)
    _unproject_into(depth, cam, s, size or (h, w), out.numpy())
    return out


def _unproject_into(depth, cam, s, size, o):
    """unproject's kernels, writing into o ((4, h, w) float32, C-contiguous): s as
    _samples returns them."""
    from fgcli.kernels.geom import unproject_kernel, unproject_sky_kernel

    h, w = depth.shape[-2:]
    kx, ky, A, M = _unproject_coefs(cam, size)
    d = _a(depth)[0]
    ss = np.empty((h, w), dtype=np.float32)
    nsky = np.empty(h, dtype=np.int64)
    unproject_kernel(d, s[0], s[1], kx, ky, A, M, o, ss, nsky)
    sky = _sky_rows(nsky, ss)
    if sky is not None:
        unproject_sky_kernel(d, s[0], s[1], kx, ky, A, M, sky[1], sky[0], o, _NO_PLANES)


def reproject(depth, cam_from, cam_to, size, px=None, py=None, rows=None, valid=None,
              run=None, vrun=None):
    """project(unproject(depth, cam_from, px, py, size), cam_to, size) by
    geom.reproject_kernel (+ reproject_sky_kernel where there is sky): the same values,
    the positions never written out. rows: an (h,) uint8 array; only the rows it marks
    are computed (the others' outputs: garbage); with run and vrun (an (h, w) uint8 0 / 1
    array), only the runs of run pixels of those rows that hold a 0 in vrun (no valid
    then). valid: a (1, h, w) bool mask; the result is that of where(valid, depth, 0) with
    ok & valid (a layer's fragments, without that depth plane)."""
    s = _samples(depth, px, py) if _geom_ok(depth, size) else None
    if valid is not None and (s is None or not _boolcpu(valid, tuple(depth.shape))):
        p = reproject(torch.where(valid, depth, 0.0), cam_from, cam_to, size, px, py, rows,
                      run=run, vrun=vrun)
        return p[:3] + (p[3] & valid[0],)
    if s is None:
        return project(unproject(depth, cam_from, px, py, size), cam_to, size)
    from fgcli.kernels.geom import reproject_kernel, reproject_sky_kernel

    h, w = depth.shape[-2:]
    kx, ky, A, M = _unproject_coefs(cam_from, size or (h, w))
    V, P, hw, hh = _project_coefs(cam_to, size)
    d = _a(depth)[0]
    ss = np.empty((h, w), dtype=np.float32)
    nsky = np.empty(h, dtype=np.int64)
    opx, opy, od = _empty(h, w), _empty(h, w), _empty(h, w)
    ook = _empty(h, w, dtype=torch.bool)
    outs = (opx.numpy(), opy.numpy(), od.numpy(), ook.numpy())
    some = rows is not None
    hv = valid is not None
    runs = some and run is not None and vrun is not None
    if runs and (hv or tuple(vrun.shape) != (h, w) or vrun.dtype != np.uint8):
        raise ValueError("reproject: runs need vrun, an (h, w) uint8 array, and no valid")
    rows = rows if some else np.zeros(1, dtype=np.uint8)
    dm = np.empty((h, w), dtype=np.float32) if hv else _DUMMY2  # (the sky rows' masked depth)
    reproject_kernel(d, s[0], s[1], kx, ky, A, M, V, P, hw, hh, *outs, ss, nsky, rows, some,
                     np.int64(run if runs else w), vrun if runs else _DUMMYU8,
                     _u8(valid)[0] if hv else _DUMMYU8, hv, dm)
    sky = _sky_rows(nsky, ss)
    if sky is not None:
        reproject_sky_kernel(dm if hv else d, s[0], s[1], kx, ky, A, M, V, P, hw, hh, sky[1],
                             sky[0], *outs, nsky)
    return opx, opy, od, ook


def project(X, cam, size):
    """fgcli.ops.gffe.project by geom.project_kernel."""
    if not (isinstance(X, torch.Tensor) and X.device.type == "cpu"
            and X.dtype == torch.float32 and X.dim() >= 2 and X.shape[0] == 4
            and X.numel() > 0):
        return G.project(X, cam, size)
    from fgcli.kernels.geom import project_kernel

    shape = tuple(X.shape[1:])
    x = X.reshape(4, shape[0], -1) if X.dim() >= 3 else X.reshape(4, 1, -1)
    V, P, hw, hh = _project_coefs(cam, size)
    h, w = x.shape[1:]
    px, py, d = _empty(h, w), _empty(h, w), _empty(h, w)
    ok = _empty(h, w, dtype=torch.bool)
    project_kernel(_a(x), V, P, hw, hh, px.numpy(), py.numpy(), d.numpy(), ok.numpy())
    return px.view(shape), py.view(shape), d.view(shape), ok.view(shape)


def _gffe_inputs(i) -> dict:
    """warm()'s gffe tasks' inputs: a sky pixel (the geometry's second pass too), camera
    positions made by the reference (a task compiles only the kernels it is for)."""
    d = i["d"].clone()
    d[0, 0] = float("inf")
    cam = (np.eye(4), np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, -1.0, -0.2],
                                [0, 0, -1.0, 0]]))
    h, w = d.shape[-2:]
    c = torch.rand(3, h, w, generator=torch.Generator().manual_seed(0))
    return dict(d=d, cam=cam, h=h, w=w, c=c, mv=torch.zeros(2, h, w), v=d < 1.5,
                p=G.unproject(d, cam))


def _warm_gffe_geom(i) -> None:
    g = _gffe_inputs(i)
    d, cam = g["d"], g["cam"]
    p = unproject(d, cam)
    project(p, cam, tuple(d.shape[-2:]))
    reproject(d, cam, cam, tuple(d.shape[-2:]))
    warp_positions(g["c"], p, cam)
    median_depth(d)


def _warm_gffe_trajectory(i) -> None:
    g = _gffe_inputs(i)
    d, cam, p, v = g["d"], g["cam"], g["p"], g["v"]
    dilate_trajectory(torch.stack([p, p]), d, cam, v)
    dilated_positions(torch.stack([p, p]), d, cam, v, 0.5)
    dilated_positions(torch.stack([p, p]), d, cam, None, 0.5)


def _warm_gffe_history(i) -> None:
    g = _gffe_inputs(i)
    d, cam = g["d"], g["cam"]
    mv1 = torch.full((2, g["h"], g["w"]), 3.0)
    traj, _ = track_history(d, mv1, cam, cam, d, None, 3, 0.5)
    track_history(d, mv1, cam, cam, None, traj, 3, 0.5)


def _warm_gffe_background(i) -> None:
    g = _gffe_inputs(i)
    c, d, mv, v, cam, p, h, w = (g[k] for k in ("c", "d", "mv", "v", "cam", "p", "h", "w"))
    layers = collect_background(c, d, v, cam, layer1_scale=1)
    layers = collect_background(c, d, v, cam, layers, cam, layer1_scale=1)
    half = collect_background(c, d, v, cam, layers, cam, layer1_scale=2)
    lay = G.empty_layer(h, w, "cpu")  # (_splat_fill's sparse and dense paths)
    for use in (np.zeros((h, w), dtype=np.uint8), np.ones((h, w), dtype=np.uint8)):
        _splat_fill(p[0], p[1], 1.0, d[0], use, h, w, _a(c), lay["color"].numpy(),
                    lay["depth"].numpy()[0], _u8(lay["valid"])[0])
    project_background(layers, cam, cam, ~v, "bilinear")
    background_fill(c, d, mv, v, layers, cam, cam, "bilinear", c, d, mv, 0.5, True, True)
    # (a half-size layer 1 with valid cells: an empty layer is not projected)
    half = [half[0], dict(half[1], valid=torch.ones_like(half[1]["valid"]))]
    background_fill(c, d, mv, v, half, cam, cam, "nearest")


def _warm_gffe_push_pull(i) -> None:
    g = _gffe_inputs(i)
    c, d, v = g["c"], g["d"], g["v"]
    push_pull_fill(c, v, d, tile_k=12)  # (a frame of one tile: the dense path)
    one = torch.ones_like(v)
    one[0, 0, 1] = False  # (one hole, in a 4 x 4 tile with valid finite depths: tiles)
    push_pull_fill(c, one, d, tile_k=2)


def _warm_gffe_fills(i) -> None:
    g = _gffe_inputs(i)
    c, d, mv, v, cam = (g[k] for k in ("c", "d", "mv", "v", "cam"))
    reproject_fill(c, v, d, c, d, cam, cam)
    fill_holes(c, d, mv, v, 0.1, "reproject", "clamp", True, c, d, cam, cam)
    vector_rule_fill(c, v, d, mv, c, d, mv, 0.5)


# the gffe ops with these kernels for their camera geometry (the ops' ``geom`` argument;
# every other step of them stays the reference's torch code)
GEOM = G.Geometry(unproject, project, reproject)


def _with_geom(name: str):
    ref = getattr(G, name)

    @functools.wraps(ref)
    def op(*args, **kw):
        kw.setdefault("geom", GEOM)
        return ref(*args, **kw)

    return op


def track_history(depth1, mv1, cam1, cam0=None, depth0=None, prev=None, k=2, threshold=0.5,
                  first_frame="mv", lookup="match", match_tol=0.1, geom=None):
    """fgcli.ops.gffe.track_history with a camera history: P_0's unprojection, its
    projection and the static test in one kernel, then the match search and the previous
    frame's points at the dynamic pixels only (fgcli.kernels.gffe.hist_*); the logarithms
    of the search by torch.log, of the values the search reads only. Without a history
    (first frame): the reference (GEOM)."""
    h, w = depth1.shape[-2:] if isinstance(depth1, torch.Tensor) else (0, 0)
    ok = (cam0 is not None and (depth0 is not None or prev is not None)
          and _f32cpu(depth1) and depth1.shape[0] == 1 and _f32cpu(mv1)
          and tuple(mv1.shape) == (2, h, w) and isinstance(k, int) and k >= 2
          and lookup in ("match", "nearest")
          and (depth0 is None or (_f32cpu(depth0) and depth0.shape == depth1.shape))
          and (prev is None or (_f32cpu(prev, 4) and prev.shape[0] >= 1
                                and tuple(prev.shape[1:]) == (4, h, w))))
    if not ok:
        return G.track_history(depth1, mv1, cam1, cam0, depth0, prev, k, threshold,
                               first_frame, lookup, match_tol, geom=GEOM)
    from fgcli.kernels.geom import unproject_sky_kernel
    from fgcli.kernels.gffe import (hist_at_kernel, hist_match_kernel, hist_p_kernel,
                                    hist_sel_kernel, hist_taps_kernel, select_rows_kernel)

    # P_0 is unprojected straight into the trajectory, tested there (fgcli.kernels.gffe's
    # history notes), then copied into the older planes
    traj = _empty(k, 4, h, w)
    pa = traj[0].numpy()
    older = traj.numpy()[1:]
    d1a = _a(depth1)[0]
    gx, gy = _grid_half(h, w)
    kx, ky, A, M = _unproject_coefs(cam1, (h, w))
    V, P, hw, hh = _project_coefs(cam0, (h, w))
    ss = np.empty((h, w), dtype=np.float32)
    nsky = np.empty(h, dtype=np.int64)
    use = np.empty((h, w), dtype=np.uint8)
    nuse = np.empty(h, dtype=np.int64)
    hist_p_kernel(d1a, gx, gy, kx, ky, A, M, V, P, hw, hh, _a(mv1), F32(threshold * threshold),
                  pa, ss, nsky, use, nuse, older)
    sky = _sky_rows(nsky, ss)
    if sky is not None:  # (the rows with sky: copied into the older planes there)
        unproject_sky_kernel(d1a, gx, gy, kx, ky, A, M, sky[1], sky[0], pa, older)
    dyn = torch.zeros(1, h, w, dtype=torch.bool)
    end = np.cumsum(nuse)
    if end[-1] == 0:
        return traj, dyn
    # the selected pixels' x' and the pixel each reads (flat int64), made again here
    n = int(end[-1])
    sel = np.empty(n, dtype=np.int64)
    select_rows_kernel(use, end, sel)
    xs, ys, ids = np.empty(n, np.float32), np.empty(n, np.float32), np.empty(n, np.int64)
    hist_at_kernel(sel, _a(mv1), xs, ys, ids)
    fb = np.zeros(n, dtype=np.uint8)
    if lookup == "match" and depth0 is not None:
        # the logarithms the search reads (10 per selected pixel: 9 taps of frame 0, the
        # pixel of frame 1), by torch.log as the reference's
        lg = torch.empty(n, 10)
        hist_taps_kernel(sel, _a(depth0)[0], d1a, xs, ys, lg.numpy())
        lg.log_()
        hist_match_kernel(lg.numpy(), xs, ys, w, h, F32(1e-7), F32(np.log1p(match_tol)), ids,
                          fb)
    kx0, ky0, A0, M0 = _unproject_coefs(cam0, (h, w))
    pv = _a(prev) if prev is not None else pa[None]
    hist_sel_kernel(sel, pa, ids, fb, d1a, _a(depth0)[0] if depth0 is not None else d1a,
                    depth0 is None, xs, ys, kx0, ky0, A0, M0, pv,
                    prev.shape[0] if prev is not None else 0, traj.numpy(), _u8(dyn)[0])
    return traj, dyn


project_border = _with_geom("project_border")


# the ops fused further (fgcli.kernels.gffe): the reference's glue around the geometry as
# kernels too; anything they do not implement runs the reference with GEOM


def _f32cpu(t, dim=3) -> bool:
    return (isinstance(t, torch.Tensor) and t.device.type == "cpu"
            and t.dtype == torch.float32 and t.dim() == dim and t.numel() > 0)


def _boolcpu(t, shape) -> bool:
    return (isinstance(t, torch.Tensor) and t.device.type == "cpu" and t.dtype == torch.bool
            and tuple(t.shape) == tuple(shape))


def _sample_where(img, flow, sel, base=None, fbase=None, flow_out=True, in_place=False,
                  flow_in_place=False):
    """(where(sel, backward_warp(img, flow, 'bilinear'), base or 0),
    where(sel, flow, fbase or 0) or None without flow_out) for a 3-channel img, by one
    kernel. in_place: base is the caller's own scratch; it becomes the first result.
    flow_in_place (no fbase): flow is the caller's own scratch; it becomes the second
    result (each row's flow is masked before that row's samples read it: the unselected
    pixels' samples are not used)."""
    from fgcli.kernels.gffe import sample_where_kernel
    from fgcli.kernels.warp import flat_ok

    h, w = sel.shape[-2:]
    if not flat_ok(h, w, 3):  # (one column, or past 32-bit indices) the torch ops
        from fgcli.ops.warp import backward_warp

        smp, _ = backward_warp(R.sanitize_values(img), flow, "bilinear")
        out = torch.where(sel, smp, torch.zeros_like(smp) if base is None else base)
        if in_place and base is not None:
            out = base.copy_(out)
        fout = None
        if flow_out:
            fout = torch.where(sel, flow, torch.zeros_like(flow) if fbase is None else fbase)
        return out, fout
    gxn, gyn, kx, ky = _grid(h, w)
    inp = in_place and base is not None
    out = base if inp else _empty(3, h, w)
    fout = None
    if flow_out:
        fout = flow if flow_in_place and fbase is None else _empty(2, h, w)
    ia, fa = _a(img), _a(flow)
    # without base / fbase / fout, same-shape stand-ins (the kernel's selects read them)
    sample_where_kernel(ia, fa, _u8(sel).reshape(h, w), ia if base is None else _a(base),
                        base is not None, fa if fbase is None else _a(fbase),
                        fbase is not None, gxn, gyn, kx, ky, out.numpy(),
                        fa if fout is None else fout.numpy(), inp, flow_out, fout is flow)
    return out, fout


def warp_positions(color1, positions, cam_x, filter="bilinear", crack_fill=True, geom=None,
                   origin=None):
    """fgcli.ops.gffe.warp_positions: the projection and the splat vectors in one kernel
    (with the origin test), splat_motion and gap_fill (their kernels), the bilinear read and
    the masking in one kernel."""
    if filter != "bilinear" or not (_f32cpu(color1) and color1.shape[0] == 3
                                    and _f32cpu(positions) and positions.shape[0] == 4
                                    and positions.shape[1:] == color1.shape[1:]
                                    and (origin is None or (_f32cpu(origin) and
                                                            origin.shape == positions.shape))):
        return G.warp_positions(color1, positions, cam_x, filter, crack_fill, geom=GEOM,
                                origin=origin)
    from fgcli.kernels.gffe import offsets_kernel

    h, w = color1.shape[-2:]
    disp, dn = _empty(2, h, w), _empty(1, h, w)
    V, P, hw, hh = _project_coefs(cam_x, (h, w))
    X = _a(positions)
    offsets_kernel(X, V, P, hw, hh, disp.numpy(), dn.numpy(),
                   X if origin is None else _a(origin), origin is not None)
    res = splat_motion(dn, disp, None, 1.0, model="linear", mode="extrap")
    if crack_fill:
        res = gap_fill(res, 0.01, "nearest", in_place=True)  # (res: this call's own scratch)
    col, mv = _sample_where(color1, res.to1, res.valid, flow_in_place=True)  # (res: ours)
    # (fresh planes, this call's alone: the hole stages may fill them in place)
    return {"color": mark_scratch(col), "depth": mark_scratch(res.depth),
            "mv": mark_scratch(mv), "valid": res.valid}


def dilate_trajectory(traj, depth1, cam1, dynamic=None, geom=None):
    """fgcli.ops.gffe.dilate_trajectory: the dilation kernel, then the gathers and selects
    in one kernel."""
    ok = _f32cpu(traj, 4) and traj.shape[1] == 4 and _f32cpu(depth1) and \
        depth1.shape == (1,) + tuple(traj.shape[-2:]) and \
        (dynamic is None or _boolcpu(dynamic, depth1.shape))
    if not ok:
        return G.dilate_trajectory(traj, depth1, cam1, dynamic, geom=GEOM)
    from fgcli.kernels.gffe import dilate_traj_kernel

    k, _, h, w = traj.shape
    a = aux(h, w, "cpu")
    coords = torch.stack([a["xh"].expand(h, w), a["yh"].expand(h, w)])
    dd, src = dilate_nearest_depth(depth1, coords)
    pd = unproject(dd, cam1)
    dyn = _u8(dynamic)[0] if dynamic is not None else np.zeros((h, w), dtype=np.uint8)
    out = _empty(k, 4, h, w)
    dilate_traj_kernel(_a(traj), _a(src), dyn, dynamic is not None, _a(pd), out.numpy())
    return out


def dilated_positions(traj, depth1, cam1, dynamic, alpha, motion="linear", geom=None):
    """fgcli.ops.gffe.dilated_positions: the dilation kernel, then the dilated P_0', P_1'
    (P_2') and Eq. 1 in one kernel (dilate_pos_kernel; the k-plane trajectory is never
    written)."""
    ok = _f32cpu(traj, 4) and traj.shape[1] == 4 and traj.shape[0] >= 2 and \
        _f32cpu(depth1) and depth1.shape == (1,) + tuple(traj.shape[-2:]) and \
        (dynamic is None or _boolcpu(dynamic, depth1.shape)) and \
        motion in ("linear", "quadratic")
    if ok:
        try:
            a = check_alpha(alpha, hi=None)
        except (ValueError, TypeError):
            ok = False
    if not ok:
        return G.dilated_positions(traj, depth1, cam1, dynamic, alpha, motion, geom=GEOM)
    from fgcli.kernels.gffe import dilate_dyn_pos_kernel, dilate_pos_kernel

    k, _, h, w = traj.shape
    quad = motion == "quadratic" and k >= 3
    out = _empty(4, h, w)
    if dynamic is not None:
        # dilate=dynamic: the dilation and its unprojection inside the kernel, on the rows
        # beside a dynamic pixel only (blade, 1080p: 21 -> ~8 ms for the stage)
        kx, ky, A, M = _unproject_coefs(cam1, (h, w))
        gx, gy = _grid_half(h, w)
        dilate_dyn_pos_kernel(_a(traj), _a(depth1)[0], _u8(dynamic)[0], gx, gy, kx, ky, A, M,
                              F32(a), quad, F32(a * (a + 1.0) / 2.0), out.numpy())
        return out
    ax = aux(h, w, "cpu")
    coords = torch.stack([ax["xh"].expand(h, w), ax["yh"].expand(h, w)])
    dd, src = dilate_nearest_depth(depth1, coords)
    pd = unproject(dd, cam1)
    dyn = np.zeros((h, w), dtype=np.uint8)
    dilate_pos_kernel(_a(traj), _a(src), dyn, False, _a(pd), F32(a), quad,
                      F32(a * (a + 1.0) / 2.0), out.numpy())
    return out


def _splat_min(px, py, sc, dn, use, h, w, want=None):
    """fgcli.ops.gffe._splat_min(floor(px / sc), floor(py / sc), dn, use, h, w) by one
    kernel (px / 1.0 is px itself). want: an (h, w) uint8 array (0 / 1); only those target
    cells are splatted, and only the rows with one are written (their other cells: empty;
    the other rows: unwritten memory), for callers that read no other rows."""
    from fgcli.kernels.gffe import splat_min_kernel

    src, dep = _empty(h, w, dtype=torch.int64), _empty(h, w)
    buf = np.empty(h * w, dtype=np.int64)
    hs, ws = dn.shape[-2:]
    if want is not None and h * w >= 2 ** 31:  # (the kernel's want test is in int32: the
        want = None  # rows with want come out the same, the others written as well)
    wa = want.reshape(-1) if want is not None else np.zeros(1, dtype=np.uint8)
    splat_min_kernel(_a(px).reshape(hs, ws), _a(py).reshape(hs, ws), F32(sc),
                     _a(dn).reshape(hs, ws), _u8(use).reshape(hs, ws), h, w, wa,
                     want is not None, buf, src.numpy(), dep.numpy())
    return src, dep


def _layer_ok(layer, shape) -> bool:
    c, d, v = layer.get("color"), layer.get("depth"), layer.get("valid")
    return (_f32cpu(c) and c.shape[0] == 3 and tuple(c.shape[1:]) == tuple(shape)
            and _f32cpu(d) and tuple(d.shape) == (1,) + tuple(shape)
            and _boolcpu(v, (1,) + tuple(shape)))


def _splat_layers(layers, cam_bg, cam_x, H, W, sc, h2, w2, holes=None):
    """Both background layers' fragments seen from cam_x, nearest-depth splatted: (source
    index, depth) of layer 0 at H x W and of layer 1 at h2 x w2 (layer scale sc), and the
    fragments' positions (px0, py0, px1, py1) for _read_layers_bilinear. holes: an (H, W)
    uint8 array; only the cells a hole reads are splatted, on the rows a hole reads (the
    rest of those rows comes out empty; other rows are unwritten: bg_fill_kernel reads
    the splats only in spans of 64 pixels with a hole, at (y, x) or, for a half-size
    layer 1, (y // 2, x // 2), whose want row has that hole's cell). A
    layer without a valid cell is not projected at all (its splat: empty everywhere, as
    _splat_min would make it; ~5 ms per 1080p frame of the stateless benchmark, where
    layer 1 is always empty)."""
    empty = [not any_set(lay["valid"]) for lay in layers]  # (numpy: early exit)
    want0 = want1 = None
    if holes is not None:
        from fgcli.kernels.gffe import cells_of_kernel

        want0 = holes
        want1 = holes
        if (h2, w2) != (H, W) and not empty[1]:
            want1 = np.empty((h2, w2), dtype=np.uint8)
            cells_of_kernel(holes, want1)

    def splat(layer, scale, h, w, want, empty):
        if empty:  # no fragment (layer 1 of a sequence's first frame): nothing to project;
            # the positions are never read (no cell of this layer is ever chosen)
            return _no_fragments(h, w)
        px, py, dn, fok = _layer_fragments(layer, cam_bg, cam_x, (H, W), scale)
        return _splat_min(px, py, scale, dn, fok, h, w, want) + (px, py)

    s0, d0, px, py = splat(layers[0], 1.0, H, W, want0, empty[0])
    s1, d1, px1, py1 = splat(layers[1], sc, h2, w2, want1, empty[1])
    return s0, d0, s1, d1, (px, py, px1, py1)


_NO_FRAGMENTS: dict = {}
_EMPTY_LAYERS: dict = {}


def _empty_layer(h, w):
    """A new dict holding an empty layer's planes (colour 0, depth +inf, valid False), made
    once per size and shared, as _no_fragments: a layer's readers (the projections, the
    fills, the next frame's collection) never write its planes; collect_background writes
    only the layers it makes itself. Filling layer 1 for every first frame of a sequence
    cost ~2 ms at 1080p (full-size layer 1)."""
    r = _EMPTY_LAYERS.get((h, w))
    if r is None:
        if len(_EMPTY_LAYERS) >= 4:
            _EMPTY_LAYERS.clear()
        r = _EMPTY_LAYERS[(h, w)] = G.empty_layer(h, w, "cpu")
    return dict(r)


def _no_fragments(h, w):
    """An empty layer's splat (source -1, depth inf) and fragment positions (never read),
    made once per size and shared: its readers (bg_resolve_kernel, bg_fill_kernel,
    bg_bilinear_kernel) never write it. Filling it for every frame cost 2.3 ms at 1080p."""
    r = _NO_FRAGMENTS.get((h, w))
    if r is None:
        if len(_NO_FRAGMENTS) >= 4:
            _NO_FRAGMENTS.clear()
        r = _NO_FRAGMENTS[(h, w)] = (torch.full((h, w), -1, dtype=torch.int64),
                                     torch.full((h, w), np.inf), torch.empty(h, w),
                                     torch.empty(h, w))
    return r


def _layer_fragments(layer, cam_from, cam_to, size, scale):
    """fgcli.ops.gffe._layer_fragments with the layer's valid mask applied inside the
    reprojection kernel (reproject's valid: no where / and planes, ~1.4 ms per 1080p
    layer)."""
    h, w = layer["depth"].shape[-2:]
    cx, cy = G._centres(h, w, scale, layer["depth"].device)
    return reproject(layer["depth"], cam_from, cam_to, size, cx, cy, valid=layer["valid"])


def _read_layers_bilinear(code, layers, s0, s1, frags, c):
    """The bilinear layer reads of the pixels the resolve pass marked (code) into c."""
    from fgcli.kernels.gffe import bg_bilinear_kernel

    l0, l1 = layers
    px, py, px1, py1 = frags
    l1v = _u8(l1["valid"])[0]
    bg_bilinear_kernel(code, s0.numpy(), s1.numpy(), _a(l0["color"]), _a(l0["depth"])[0],
                       _u8(l0["valid"])[0], px.numpy(), py.numpy(), _a(l1["color"]),
                       _a(l1["depth"])[0], l1v, _a(px1).reshape(l1v.shape),
                       _a(py1).reshape(l1v.shape), F32(0.05), c.numpy())


def project_background(layers, cam_bg, cam_x, holes, filter="nearest", geom=None):
    """fgcli.ops.gffe.project_background: the layers' geometry (geom kernels), both splats,
    the choice between the layers and the bilinear reads as kernels."""
    H, W = holes.shape[-2:]
    ok = (isinstance(layers, (list, tuple)) and len(layers) == 2
          and _boolcpu(holes, (1, H, W)) and filter in ("nearest", "bilinear")
          and _layer_ok(layers[0], (H, W)))
    if ok:
        sc = G._layer_scale(layers[1], H, W)
        h2, w2 = (H, W) if sc == 1.0 else G._half(H, W)
        ok = _layer_ok(layers[1], (h2, w2))
    if not ok:
        return G.project_background(layers, cam_bg, cam_x, holes, filter, geom=GEOM)
    from fgcli.kernels.gffe import bg_resolve_kernel

    l0, l1 = layers
    s0, d0, s1, d1, frags = _splat_layers(layers, cam_bg, cam_x, H, W, sc, h2, w2)
    bil0 = filter == "bilinear"
    bil1 = bil0 and sc == 1.0
    c, d, m = _empty(3, H, W), _empty(1, H, W), _empty(2, H, W)
    filled = _empty(1, H, W, dtype=torch.bool)
    code = np.empty((H, W), dtype=np.uint8)
    bg_resolve_kernel(s0.numpy(), d0.numpy(), s1.numpy(), d1.numpy(), sc == 2.0, F32(sc),
                      _u8(holes)[0], _a(l0["color"]), _a(l1["color"]), bil0, bil1, c.numpy(),
                      d.numpy()[0], m.numpy(), _u8(filled)[0], code)
    if bil0:
        _read_layers_bilinear(code, layers, s0, s1, frags, c)
    return c, d, m, filled


def collect_background(color1, depth1, static, cam1, prev_layers=None, cam_prev=None,
                       depth_tol=0.02, edge_guard=False, layer1_scale=2, geom=None):
    """fgcli.ops.gffe.collect_background (edge_guard off): the new layer 0, both cases of
    the previous layer 0, the previous layer 1 behind layer 0, the three splats and their
    winners as kernels (fgcli.kernels.gffe.col_* / layer_fill_kernel, _splat_min); the
    layers' geometry by the geom kernels. edge_guard: the reference (GEOM)."""
    H, W = depth1.shape[-2:] if isinstance(depth1, torch.Tensor) else (0, 0)
    ok = (not edge_guard and layer1_scale in (1, 2) and _f32cpu(color1)
          and tuple(color1.shape) == (3, H, W) and _f32cpu(depth1)
          and tuple(depth1.shape) == (1, H, W) and _boolcpu(static, (1, H, W)))
    hist = ok and prev_layers is not None and cam_prev is not None
    if hist:
        ok = (isinstance(prev_layers, (list, tuple)) and len(prev_layers) == 2
              and _layer_ok(prev_layers[0], (H, W)))
        if ok:
            sp = G._layer_scale(prev_layers[1], H, W)
            ok = _layer_ok(prev_layers[1], (H, W) if sp == 1.0 else G._half(H, W))
    if not ok:
        return G.collect_background(color1, depth1, static, cam1, prev_layers, cam_prev,
                                    depth_tol, edge_guard, layer1_scale, geom=GEOM)
    from fgcli.kernels.gffe import (col_behind_kernel, col_case_kernel, col_init_kernel,
                                    max3_kernel)

    sc = float(layer1_scale)
    h2, w2 = G._half(H, W) if layer1_scale == 2 else (H, W)
    d1 = np.empty((H, W), dtype=np.float32)
    l0 = {"color": _empty(3, H, W), "depth": _empty(1, H, W),
          "valid": _empty(1, H, W, dtype=torch.bool)}
    l0c, l0d, l0v = l0["color"].numpy(), l0["depth"].numpy()[0], _u8(l0["valid"])[0]
    col_init_kernel(_a(color1), _a(depth1)[0], _u8(static)[0], d1, l0c, l0d, l0v)
    if not hist:  # (layer 1 of a sequence's first frame: empty; shared, never written)
        return [l0, _empty_layer(h2, w2)]
    l1 = G.empty_layer(h2, w2, "cpu")
    l1c, l1d, l1v = l1["color"].numpy(), l1["depth"].numpy()[0], _u8(l1["valid"])[0]
    tol = F32(1.0 + float(depth_tol))
    p0, p1 = prev_layers
    px, py, dn, fok = _layer_fragments(p0, cam_prev, cam1, (H, W), 1.0)
    c1, c2 = np.empty((H, W), dtype=np.uint8), np.empty((H, W), dtype=np.uint8)
    far3 = np.empty((H, W), dtype=np.float32)
    max3_kernel(l0d, far3)
    col_case_kernel(_a(px), _a(py), _a(dn), _u8(fok), far3, l0v, d1, tol, c1, c2)
    pc = _a(p0["color"])
    _splat_fill(px, py, 1.0, dn, c1, H, W, pc, l0c, l0d, l0v)
    _splat_fill(px, py, sc, dn, c2, h2, w2, pc, l1c, l1d, l1v)
    px, py, dn, fok = _layer_fragments(p1, cam_prev, cam1, (H, W), sp)
    bm = np.empty(tuple(px.shape), dtype=np.uint8)
    col_behind_kernel(_a(px), _a(py), _a(dn), _u8(fok), l0d, l0v, d1, l1v, tol, F32(sc), bm)
    _splat_fill(px, py, sc, dn, bm, h2, w2, _a(p1["color"]), l1c, l1d, l1v)
    return [l0, l1]


def _splat_fill(px, py, sc, dn, use, h, w, pc, lc, ld, lv, sparse=None):
    """_splat_min of the fragments use (uint8 0 / 1, the fragment grid's shape) marks,
    then layer_fill_kernel of its winners into the layer (lc, ld, lv, in place). Where at
    most one fragment in 16 is used (a sequence's background cases: 0-2 % of a 1080p
    frame), the sparse kernel does both over those fragments alone (the same winners:
    splat_fill_sparse_kernel); else the dense pair. sparse: force one (tests)."""
    from fgcli.kernels.gffe import (layer_fill_kernel, row_counts_kernel,
                                    select_rows_kernel, splat_fill_sparse_kernel)

    hs, ws = use.shape
    counts = np.empty(hs, dtype=np.int64)
    row_counts_kernel(use, counts)
    end = np.cumsum(counts)
    n = int(end[-1]) if hs else 0
    if (16 * n <= hs * ws) if sparse is None else sparse:
        sel = np.empty(n, dtype=np.int64)
        if n:
            select_rows_kernel(use, end, sel)
        splat_fill_sparse_kernel(_a(px).reshape(hs, ws), _a(py).reshape(hs, ws), F32(sc),
                                 _a(dn).reshape(hs, ws), sel, h, w,
                                 np.empty(h * w, dtype=np.int64), pc, lc, ld, lv)
        return
    src, dep = _splat_min(px, py, sc, dn, torch.from_numpy(use.view(np.bool_)), h, w)
    layer_fill_kernel(src.numpy(), dep.numpy(), pc, lc, ld, lv)


def background_fill(color, depth, mv, valid, layers, cam_bg, cam_x, filter="nearest",
                    color1=None, depth1=None, mv1=None, alpha=0.5, entering=False,
                    emerging=False, geom=None, in_place=False):
    """fgcli.ops.gffe.background_fill: the layers' geometry (geom kernels) and both
    splats as project_background, then the choice between the layers, the entering
    surface and the stage's selects in one kernel (bg_fill_kernel), the bilinear reads
    last. in_place: where color, depth and mv are all scratch (fgcli.ops._util), the
    filled holes are written into them (no copy of the other pixels); the results are
    scratch either way."""
    H, W = valid.shape[-2:]
    ok = (isinstance(layers, (list, tuple)) and len(layers) == 2
          and _boolcpu(valid, (1, H, W)) and filter in ("nearest", "bilinear")
          and _f32cpu(color) and color.shape == (3, H, W) and _f32cpu(depth)
          and depth.shape == (1, H, W) and _f32cpu(mv) and mv.shape == (2, H, W)
          and _layer_ok(layers[0], (H, W)))
    ent = bool(entering) and mv1 is not None
    if ok and ent:
        ok = (_f32cpu(color1) and color1.shape == (3, H, W) and _f32cpu(depth1)
              and depth1.shape == (1, H, W) and _f32cpu(mv1) and mv1.shape == (2, H, W))
    if ok:
        sc = G._layer_scale(layers[1], H, W)
        h2, w2 = (H, W) if sc == 1.0 else G._half(H, W)
        ok = _layer_ok(layers[1], (h2, w2))
    if not ok:
        return G.background_fill(color, depth, mv, valid, layers, cam_bg, cam_x, filter,
                                 color1, depth1, mv1, alpha, entering, emerging, geom=GEOM)
    from fgcli.kernels.gffe import bg_fill_kernel

    l0, l1 = layers
    # bg_fill_kernel reads the splats at the holes only: splat those cells alone
    holes = np.empty((H, W), dtype=np.uint8)
    np.equal(_u8(valid)[0], 0, out=holes.view(np.bool_))
    s0, d0, s1, d1, frags = _splat_layers(layers, cam_bg, cam_x, H, W, sc, h2, w2, holes)
    bil0 = filter == "bilinear"
    bil1 = bil0 and sc == 1.0
    inp = _writable(in_place, color, depth, mv)
    c, d, m = (color, depth, mv) if inp else \
        mark_scratch(_empty(3, H, W), _empty(1, H, W), _empty(2, H, W))
    v = _empty(1, H, W, dtype=torch.bool)
    code = np.empty((H, W), dtype=np.uint8)
    ca, da, ma = _a(color), _a(depth), _a(mv)
    # without the entering surface, same-shape stand-ins (the kernel's selects read them)
    c1, e1, m1 = (_a(color1), _a(depth1), _a(mv1)) if ent else (ca, da, ma)
    a = F32(float(alpha)) if ent else F32(0.0)
    bg_fill_kernel(s0.numpy(), d0.numpy(), s1.numpy(), d1.numpy(), sc == 2.0, F32(sc),
                   _a(l0["color"]), _a(l1["color"]), bil0, bil1, ca, da[0], ma,
                   _u8(valid)[0], c1, e1[0], m1, a, ent, bool(emerging), c.numpy(),
                   d.numpy()[0], m.numpy(), _u8(v)[0], code, inp)
    if bil0:
        _read_layers_bilinear(code, layers, s0, s1, frags, c)
    return c, d, m, v


def median_depth(depth):
    """fgcli.ops.gffe.median_depth by an exact selection on the float32 bits
    (bits_hist, bits_rank): the value of rank (n - 1) // 2 among the n finite
    positive depths, the lower median torch.nanmedian returns."""
    if not (isinstance(depth, torch.Tensor) and depth.device.type == "cpu"
            and depth.dtype == torch.float32 and depth.numel() > 0):
        return G.median_depth(depth)
    from fgcli.kernels.gffe import bits_hist, bits_rank

    d = _a(depth).reshape(-1)
    hist, bounds = bits_hist(d)
    cum = np.cumsum(hist)
    n = int(cum[-1])
    if n == 0:
        return float("nan")
    r = (n - 1) // 2
    top = int(np.searchsorted(cum, r, side="right"))
    rank = r - (int(cum[top - 1]) if top > 0 else 0)
    return float(np.int32(bits_rank(d, top, rank, bounds)).view(np.float32))


PP_TILE_K = 5  # push_pull_fill's tiles: 32 x 32 pixels


def push_pull_fill(color, valid, depth=None, far_bias=0.1, tile_k=PP_TILE_K, in_place=False):
    """fgcli.ops.gffe.push_pull_fill (3-channel colour, with depth, far_bias >= 0) by the
    push-pull kernels of fgcli.kernels.gffe, one pass per level and direction; or, when
    every aligned 2**tile_k tile with a hole has a valid pixel and a valid finite depth
    (and the frame is larger than a tile), the pyramids of those tiles alone
    (pp_tiles_kernel: the same values; ~3x faster where few tiles have holes). Frames
    whose holes reach a tile without a valid finite depth (a border strip of a moving
    camera, sky) take the frame's pyramid after the scan. in_place: on the tile path, where color and depth are scratch
    (fgcli.ops._util), the holes are written into them (the results are they)."""
    ok = (_f32cpu(color) and color.shape[0] == 3 and color.shape[1] * color.shape[2] > 1
          and _f32cpu(depth) and tuple(depth.shape) == (1,) + tuple(color.shape[1:])
          and _boolcpu(valid, depth.shape) and float(far_bias) >= 0)
    if not ok:
        return G.push_pull_fill(color, valid, depth, far_bias)
    from fgcli.kernels.gffe import (pp_down0_kernel, pp_down_kernel, pp_final_kernel,
                                    pp_tile_scan_kernel, pp_tiles_kernel, pp_up_kernel)

    h, w = color.shape[-2:]
    col, dep, val = _a(color), _a(depth)[0], _u8(valid)[0]
    fb = F32(1.0 - float(far_bias))
    T = 1 << int(tile_k)
    # (a frame of one tile has the tile's top level: the dense path)
    if tile_k >= 1 and max(h, w) > T:
        holes = np.empty((-(-h // T), -(-w // T)), dtype=np.uint8)
        tok = np.empty_like(holes)
        pp_tile_scan_kernel(dep, val, int(tile_k), holes, tok)
        if not np.any(holes & (1 - tok)):
            inp = _writable(in_place, color, depth)
            out_c, out_d = (color, depth) if inp else (_empty(3, h, w), _empty(1, h, w))
            pp_tiles_kernel(col, dep, val, fb, int(tile_k), holes, out_c.numpy(),
                            out_d.numpy()[0], inp)
            return out_c, out_d
    levels = []  # levels 1, 2, ... (level 0's planes are made as pp_down0_kernel reads)
    while h > 1 or w > 1:
        h, w = (h + 1) // 2, (w + 1) // 2
        nxt = (np.empty((3, h, w), dtype=np.float32),) + tuple(
            np.empty((h, w), dtype=np.float32) for _ in range(3))
        if levels:
            pp_down_kernel(*levels[-1], fb, *nxt)
        else:
            pp_down0_kernel(col, dep, val, fb, *nxt)
        levels.append(nxt)
    filled = levels[-1]
    for lv in reversed(levels[:-1]):
        hh, ww = lv[1].shape
        out = (np.empty((3, hh, ww), dtype=np.float32),) + tuple(
            np.empty((hh, ww), dtype=np.float32) for _ in range(3))
        pp_up_kernel(*lv, *filled, *out)
        filled = out
    H, W = color.shape[-2:]
    out_c, out_d = _empty(3, H, W), _empty(1, H, W)
    pp_final_kernel(col, dep, val, filled[0], filled[1], filled[3], out_c.numpy(),
                    out_d.numpy()[0])
    return out_c, out_d


def reproject_fill(color, valid, depth, color1, depth1, cam1, cam_x, depth_tol=0.05,
                   offscreen="clamp", border=None, geom=None):
    """fgcli.ops.gffe.reproject_fill: the proxy geometry (geom kernels), the proxy test
    and the bilinear read as kernels. With a border: the reference (geom kernels)."""
    H, W = color.shape[-2:]
    ok = (border is None and offscreen in ("clamp", "skip") and _f32cpu(color)
          and color.shape[0] == 3 and _f32cpu(color1) and color1.shape == color.shape
          and _f32cpu(depth) and _f32cpu(depth1) and depth.shape == (1, H, W)
          and depth1.shape == (1, H, W) and _boolcpu(valid, (1, H, W)))
    if not ok:
        return G.reproject_fill(color, valid, depth, color1, depth1, cam1, cam_x, depth_tol,
                                offscreen, border, geom=GEOM)
    from fgcli.kernels.gffe import reproject_took_kernel

    px, py, _, pok = reproject(depth, cam_x, cam1, (H, W))
    took = _empty(1, H, W, dtype=torch.bool)
    flow = _empty(2, H, W)
    reproject_took_kernel(px.numpy(), py.numpy(), _u8(pok), _u8(valid)[0], _a(depth)[0],
                          _a(depth1)[0], offscreen == "clamp", F32(1.0 - float(depth_tol)),
                          _u8(took)[0], flow.numpy())
    out, _ = _sample_where(color1, flow, took, base=color, flow_out=False)
    return out, flow, took


def fill_holes(color, depth, mv, valid, far_bias=0.1, mode="reproject", offscreen="clamp",
               border_splat=True, color1=None, depth1=None, cam1=None, cam_x=None,
               border=None, geom=None, in_place=False):
    """fgcli.ops.gffe.fill_holes: push_pull_fill's kernels, then (no border, mode
    'reproject') the proxy test and the vectors in one kernel (reproject_mv_kernel) and
    the bilinear read; anything else: the reference's composition of these ops.
    in_place: where color, depth and mv are scratch (fgcli.ops._util) and the push-pull
    takes its tile path, the holes are written into them (no copy of the other pixels)."""
    H, W = color.shape[-2:] if isinstance(color, torch.Tensor) else (0, 0)
    cams = cam1 is not None and cam_x is not None
    ok = (border is None and mode == "reproject" and cams and offscreen in ("clamp", "skip")
          and _f32cpu(color) and color.shape[0] == 3 and _f32cpu(color1)
          and color1.shape == color.shape and _f32cpu(depth) and _f32cpu(depth1)
          and depth.shape == (1, H, W) and depth1.shape == (1, H, W) and _f32cpu(mv)
          and mv.shape == (2, H, W) and _boolcpu(valid, (1, H, W)))
    if not ok:
        return G.fill_holes(color, depth, mv, valid, far_bias, mode, offscreen, border_splat,
                            color1, depth1, cam1, cam_x, border,
                            parts=(project_border, push_pull_fill, reproject_fill))
    from fgcli.kernels.gffe import SPAN, reproject_mv_kernel

    inp = _writable(in_place, mv)
    c, d = push_pull_fill(color, valid, depth, far_bias, in_place=inp)
    inp = inp and c is color and d is depth  # (the tile path took them)
    vu = _u8(valid)[0]
    # the proxy points of the runs of SPAN pixels with holes only (no other pixel reads
    # them: reproject_mv_kernel works those runs alone); a moving camera's rows nearly all
    # hold a hole, most of their runs none
    rows = (vu.min(axis=1) == 0).view(np.uint8)
    px, py, _, pok = reproject(d, cam_x, cam1, (H, W), rows=rows, run=SPAN, vrun=vu)
    took = _empty(1, H, W, dtype=torch.bool)
    flow, out = _empty(2, H, W), (mv if inp else mark_scratch(_empty(2, H, W)))
    reproject_mv_kernel(px.numpy(), py.numpy(), _u8(pok), vu, _a(d)[0], _a(depth1)[0],
                        offscreen == "clamp", F32(1.0 - 0.05), _a(mv), _u8(took)[0],
                        flow.numpy(), out.numpy(), rows, True, inp)
    c, _ = _sample_where(color1, flow, took, base=c, flow_out=False, in_place=True)
    holes = torch.tensor(int(vu.size - np.count_nonzero(vu)), dtype=torch.int64)
    return c, d, out, holes


def vector_rule_fill(color, valid, depth, mv, color1, depth1, mv1, alpha,
                     depth_threshold_rel=1e-3, in_place=False):
    """fgcli.ops.gffe.vector_rule_fill: the extrapolation rule on the holes and the
    bilinear read of frame 1 as kernels, which write the holes they fill only: into color,
    depth and mv themselves with in_place where all three are scratch
    (fgcli.ops._util.mark_scratch), else into copies (marked scratch)."""
    H, W = color.shape[-2:]
    ok = (_f32cpu(color) and color.shape[0] == 3 and _f32cpu(color1)
          and color1.shape == color.shape and _f32cpu(depth) and _f32cpu(depth1)
          and depth.shape == (1, H, W) and depth1.shape == (1, H, W) and _f32cpu(mv)
          and _f32cpu(mv1) and mv.shape == (2, H, W) and mv1.shape == (2, H, W)
          and _boolcpu(valid, (1, H, W)))
    if not ok:
        return G.vector_rule_fill(color, valid, depth, mv, color1, depth1, mv1, alpha,
                                  depth_threshold_rel)
    a = check_alpha(alpha, hi=ALPHA_MAX)
    thr = check_alpha(depth_threshold_rel, "depth_threshold_rel", 0.0, 1.0)
    from fgcli.kernels.gffe import vector_rule_kernel

    inp = _writable(in_place, color, depth, mv)
    dep, mvo = (depth, mv) if inp else (_own_copy(depth), _own_copy(mv))
    took = _empty(1, H, W, dtype=torch.bool)
    flow = _empty(2, H, W)
    vector_rule_kernel(_a(mv1), _a(depth1)[0], _u8(valid)[0], F32(a), F32(1.0 - thr),
                       _u8(took)[0], flow.numpy(), dep.numpy()[0], mvo.numpy())
    if inp:
        out, _ = _sample_where(color1, flow, took, base=color, flow_out=False, in_place=True)
    else:
        out = mark_scratch(_sample_where(color1, flow, took, base=color, flow_out=False)[0])
    return out, dep, mvo, took
