"""GFFE (Wu et al., SIGGRAPH Asia 2024) geometry-aware extrapolation (GAE), as pure tensor
functions: history tracking with the static test (Algorithm 1), world-space position
estimation (Eq. 1), camera extrapolation (Eq. 2), forward warp with nearest depth winning
(the packed-key splat of fgcli.ops.splat), two-layer background collection and projection
(Sec. 4.2, Fig. 5), the adaptive rendering window (Sec. 4.3, appendix C, Eq. 5) and a
push-pull fill for the holes nothing else covers.

World positions are homogeneous (4, H, W) tensors: w = 1 for a surface point, w = 0 for
a sky pixel (a direction at infinity: only the camera rotation moves it, never NaN), and
all zeros where the depth is unusable (0, negative, NaN): such pixels produce no fragment.
Cameras are (world_to_camera, projection) 4x4 float64 numpy arrays (fgcli.frame.Camera,
OpenGL: view looks down -Z). Pixel coordinates: centres at integer + 0.5, x right, y down.
"""
from __future__ import annotations

import math
from typing import Callable, NamedTuple

import numpy as np
import torch

from fgcli.ops._util import (MV_MAX, aux, check_alpha, check_choice, check_same, check_tensor,
                             gather_pixels, reads_back, sanitize_values)
from fgcli.ops.splat import I64_MAX, _pack_key, splat_motion
from fgcli.ops.warp import backward_warp

OFF = float(MV_MAX)  # displacement that sends a fragment off-screen (dropped by the splat)


# ----------------------------------------------------------------------------- cameras

def _mats(cam):
    """(world_to_camera, projection) float64 (4, 4) from a Camera or a pair."""
    if hasattr(cam, "world_to_camera"):
        v, p = cam.world_to_camera, cam.projection
    else:
        v, p = cam
    v = np.asarray(v, dtype=np.float64).reshape(4, 4)
    p = np.asarray(p, dtype=np.float64).reshape(4, 4)
    if not (np.isfinite(v).all() and np.isfinite(p).all()):
        raise ValueError("camera: non-finite matrix")
    return v, p


def camera_pose(world_to_camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(position, direction, up) in world space of a world-to-view matrix (view looks down -Z)."""
    v = np.asarray(world_to_camera, dtype=np.float64)
    r, t = v[:3, :3], v[:3, 3]
    return -r.T @ t, -r[2], r[1]


def look_at(pos, direction, up) -> np.ndarray:
    """World-to-view 4x4 (OpenGL) from position, viewing direction and up (need not be unit)."""
    f = np.asarray(direction, dtype=np.float64)
    f = f / max(np.linalg.norm(f), 1e-300)
    s = np.cross(f, up)
    ns = np.linalg.norm(s)
    if ns < 1e-12:  # up parallel to the direction: any perpendicular
        s = np.cross(f, [1.0, 0, 0] if abs(f[0]) < 0.9 else [0, 1.0, 0])
        ns = np.linalg.norm(s)
    s = s / ns
    u = np.cross(s, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = s, u, -f
    m[:3, 3] = -m[:3, :3] @ np.asarray(pos, dtype=np.float64)
    return m


def _hat(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _so3_exp(w):
    th = float(np.linalg.norm(w))
    k = _hat(w)
    if th < 1e-12:
        return np.eye(3) + k
    return np.eye(3) + math.sin(th) / th * k + (1.0 - math.cos(th)) / th ** 2 * (k @ k)


def _so3_log(r):
    th = math.acos(float(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0)))
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if th < 1e-9:
        return 0.5 * v
    if th > math.pi - 1e-6:  # half-turn: ill-conditioned axis; no sensible constant motion
        raise ArithmeticError("camera turned by 180 degrees between frames")
    return th / (2.0 * math.sin(th)) * v


def _se3_v(w):
    th = float(np.linalg.norm(w))
    k = _hat(w)
    if th < 1e-9:
        return np.eye(3) + 0.5 * k
    return np.eye(3) + (1.0 - math.cos(th)) / th ** 2 * k + (th - math.sin(th)) / th ** 3 * (k @ k)


def se3_power(m, a: float) -> np.ndarray:
    """m ** a for a rigid 4x4 transform m (screw motion: exp(a log m))."""
    w = _so3_log(m[:3, :3])
    u = np.linalg.solve(_se3_v(w), m[:3, 3])
    out = np.eye(4)
    out[:3, :3] = _so3_exp(a * w)
    out[:3, 3] = _se3_v(a * w) @ (a * u)
    return out


def extrapolate_camera(cam_prev, cam, alpha: float, model: str = "linear"):
    """Camera of the extrapolated frame, projection of the current camera.

    model 'linear' = Eq. 2: C~ = C + alpha (C - C_prev) per pose component (position,
    direction, up). model 'rigid' (fgen): the camera keeps its last relative rigid motion,
    V~ = (V V_prev^-1)^alpha V (screw motion): exact for constant translation, orbits and
    turns, where Eq. 2's chord leaves the arc (a 0.1 px error on the orbit scene).
    Returns (world_to_camera, projection) float64. Without a previous camera, or when the
    pose did not change, the current matrices exactly."""
    check_choice(model, "model", ("linear", "rigid"))
    v1, p1 = _mats(cam)
    if cam_prev is None:
        return v1.copy(), p1.copy()
    v0, _ = _mats(cam_prev)
    if np.array_equal(v0, v1):
        return v1.copy(), p1.copy()
    a = check_alpha(alpha, hi=None)
    if model == "rigid":
        r0, r1 = v0[:3, :3], v1[:3, :3]
        # only for orthonormal (rigid) view matrices; anything else falls back to Eq. 2
        if np.allclose(r0 @ r0.T, np.eye(3), atol=1e-5) and \
                np.allclose(r1 @ r1.T, np.eye(3), atol=1e-5):
            try:
                out = se3_power(v1 @ np.linalg.inv(v0), a) @ v1
                if np.isfinite(out).all():
                    return out, p1.copy()
            except (ArithmeticError, np.linalg.LinAlgError):
                pass
    (o0, d0, u0), (o1, d1, u1) = camera_pose(v0), camera_pose(v1)
    return look_at(o1 + a * (o1 - o0), d1 + a * (d1 - d0), u1 + a * (u1 - u0)), p1.copy()


def _t(m, dev):
    return torch.as_tensor(np.asarray(m, dtype=np.float64), dtype=torch.float32, device=dev)


def unproject(depth: torch.Tensor, cam, px: torch.Tensor | None = None,
              py: torch.Tensor | None = None, size: tuple[int, int] | None = None) -> torch.Tensor:
    """Homogeneous world positions of pixels from linear view depth and a camera.

    Args:
        depth: (1, h, w) linear view depth; +inf = sky; <= 0 or NaN = unusable.
        cam: Camera or (world_to_camera, projection).
        px, py: (h, w) pixel coordinates of the samples (default: the pixel centres of the
            depth grid); size: (H, W) of the image the camera's NDC spans (default: depth's).

    Returns:
        (4, h, w) float32: (x, y, z, 1) for surfaces, (dx, dy, dz, 0) unit directions for
        sky, zeros where the depth is unusable. Always finite.
    """
    depth = check_tensor(depth, "depth", 1, allow_batch=False)
    h, w = depth.shape[-2:]
    dev = depth.device
    H, W = size or (h, w)
    if px is None:
        a = aux(h, w, dev)
        px, py = a["xh"].expand(h, w), a["yh"].expand(h, w)
    v, p = _mats(cam)
    ip = np.linalg.inv(p)
    ivm = np.linalg.inv(v)
    nx = px * (2.0 / W) - 1.0
    ny = 1.0 - py * (2.0 / H)

    def at(zn):  # view-space point at NDC depth zn (near -1, far +1)
        c = ip @ np.array([0.0, 0.0, zn, 1.0])
        pts = [nx * float(ip[i, 0]) + ny * float(ip[i, 1]) + float(c[i]) for i in range(4)]
        wv = pts[3]
        wv = torch.where(wv.abs() < 1e-30, torch.full_like(wv, 1e-30), wv)
        return [q / wv for q in pts[:3]]

    na, fa = at(-1.0), at(1.0)
    dvec = [fa[i] - na[i] for i in range(3)]
    d = depth[0]
    finite = torch.isfinite(d) & (d > 0)
    sky = torch.isinf(d) & (d > 0)
    dz = dvec[2]
    dz = torch.where(dz.abs() < 1e-30, torch.full_like(dz, -1e-30), dz)
    s = torch.where(finite, (-d - na[2]) / dz, torch.zeros_like(d))
    view = [na[i] + dvec[i] * s for i in range(3)]
    norm = torch.sqrt(dvec[0] ** 2 + dvec[1] ** 2 + dvec[2] ** 2).clamp_min(1e-30)
    dirs = [dvec[i] / norm for i in range(3)]
    out = torch.zeros(4, h, w, dtype=torch.float32, device=dev)
    for i in range(3):
        pt = sum(float(ivm[i, j]) * view[j] for j in range(3)) + float(ivm[i, 3])
        dr = sum(float(ivm[i, j]) * dirs[j] for j in range(3))
        out[i] = torch.where(finite, pt, torch.where(sky, dr, torch.zeros_like(pt)))
    out[3] = finite.to(torch.float32)
    return torch.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0)


def project(X: torch.Tensor, cam, size: tuple[int, int]):
    """Project homogeneous world positions (4, ...) with a camera onto an image of size (H, W).

    Returns (px, py, depth, ok): pixel coordinates (...), view depth (... ; +inf for
    directions), ok (...) bool: a usable position in front of the camera. Finite
    everywhere (px, py of not-ok entries are OFF)."""
    H, W = size
    v, p = _mats(cam)
    m = p @ v
    xs = [X[i] for i in range(4)]
    vz = sum(float(v[2, j]) * xs[j] for j in range(4))
    c = [sum(float(m[i, j]) * xs[j] for j in range(4)) for i in (0, 1, 3)]
    cw = c[2]
    ok = (cw > 1e-12) & (vz < 0) & ((xs[3] != 0) | (xs[0] != 0) | (xs[1] != 0) | (xs[2] != 0))
    safe = torch.where(ok, cw, torch.ones_like(cw))
    px = (c[0] / safe + 1.0) * (0.5 * W)
    py = (1.0 - c[1] / safe) * (0.5 * H)
    ok = ok & torch.isfinite(px) & torch.isfinite(py) & (px.abs() < OFF) & (py.abs() < OFF)
    px = torch.where(ok, px, torch.full_like(px, OFF))
    py = torch.where(ok, py, torch.full_like(py, OFF))
    depth = torch.where(xs[3] > 0, -vz, torch.full_like(vz, math.inf))
    depth = torch.where(ok, torch.nan_to_num(depth, nan=math.inf, posinf=math.inf).clamp_min(0.0),
                        torch.full_like(depth, math.inf))
    return px, py, depth, ok


class Geometry(NamedTuple):
    """The implementation of unproject / project the ops below use (their ``geom``
    argument): None = these torch functions (the reference, and the GPU path);
    fgcli.kernels.ops.GEOM = the numba kernels (bit-identical). reproject: project of
    unproject in one step (same values), or None: the two one after the other."""
    unproject: Callable
    project: Callable
    reproject: Callable | None = None


TORCH_GEOM = Geometry(unproject, project)


def _reproject(g, depth, cam_from, cam_to, size, px=None, py=None):
    """g.project(g.unproject(depth, cam_from, px, py, size), cam_to, size), by
    g.reproject where the geometry has one."""
    if g.reproject is not None:
        return g.reproject(depth, cam_from, cam_to, size, px, py)
    return g.project(g.unproject(depth, cam_from, px, py, size), cam_to, size)


# ----------------------------------------------------------------------------- history

def _sample_nearest_idx(px, py, h, w):
    """Flat index of the pixel containing pixel coordinates (px, py), and inside mask."""
    ix = torch.floor(px)
    iy = torch.floor(py)
    inside = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
    idx = (iy.clamp(0, h - 1) * w + ix.clamp(0, w - 1)).to(torch.int64).view(-1)
    return idx, inside


def track_history(depth1: torch.Tensor, mv1: torch.Tensor, cam1, cam0=None,
                  depth0: torch.Tensor | None = None, prev: torch.Tensor | None = None,
                  k: int = 2, threshold: float = 0.5,
                  first_frame: str = "mv", lookup: str = "match",
                  match_tol: float = 0.1, geom: Geometry | None = None
                  ) -> tuple[torch.Tensor, torch.Tensor]:
    """Algorithm 1 (history tracking with static test).

    For each pixel x: p = unproject(x, D_t, C_t); x^ = project(p, C_t-1) (where the pixel
    would have been if only the camera moved); x' = x + V_t->t-1[x] (where the motion vector
    says it was). ||x^ - x'|| > threshold (pixels): dynamic, P_i = P'_{i-1}[x'] for i >= 1,
    P_0 = p; else static: P_i = p for all i.

    P'_0 is the previous frame's own unprojected depth: read at the exact sub-pixel x' with
    the depth of the nearest pixel (depth0, cam0; lookup='nearest', the paper) when given,
    else from ``prev``; P'_i for i >= 1 come from ``prev`` at the same pixel.
    lookup='match' (fgen, default): of the 3x3 pixels around x', the one whose depth0 is
    nearest (in ratio) to the pixel's current depth; where none is within match_tol
    (relative), x' fell off the surface (a silhouette: its vector ends on the wall behind
    or on an occluder) and the surface's previous position is taken at x' with its current
    depth (screen-space motion). The nearest pixel alone makes an edge pixel whose x' lands
    on a far background lag behind its object (held-out scenes: +0.5-0.65 dB,
    docs/results.md). Where x' is off-screen, the previous sample
    is unusable, or it is a surface where p is sky (or the reverse), the pixel keeps
    P_i = p. Without cam0 (first frame, empty history) every pixel passes as static
    (first_frame='static', the paper), or (first_frame='mv', fgen) pixels whose vector
    exceeds the threshold get P_i = the point seen at x' at the same depth with the same
    camera (screen-space linear motion); the dynamic mask is then those
    moving pixels (they stay out of the background layers).

    Args:
        depth1: (1, H, W) current depth. mv1: (2, H, W) current vectors (toward t-1).
        cam1, cam0: Camera or (world_to_camera, projection); cam0 None = no history.
        depth0: (1, H, W) previous depth or None. prev: (k, 4, H, W) previous trajectory
            or None (then older positions equal P'_0).
        k: trajectory length (>= 2). threshold: static-test distance in pixels.
        geom: unproject / project (None: the torch functions; see Geometry).

    Returns:
        (traj (k, 4, H, W) homogeneous world positions, newest first; dynamic (1, H, W) bool).
    """
    depth1 = check_tensor(depth1, "depth1", 1, allow_batch=False)
    mv1 = check_tensor(mv1, "mv1", 2, allow_batch=False)
    if k < 2:
        raise ValueError(f"k: expected >= 2, got {k}")
    check_choice(lookup, "lookup", ("match", "nearest"))
    h, w = depth1.shape[-2:]
    g = geom or TORCH_GEOM
    p = g.unproject(depth1, cam1)
    traj = p[None].repeat(k, 1, 1, 1)
    dyn = torch.zeros(1, h, w, dtype=torch.bool, device=depth1.device)
    if cam0 is None or (depth0 is None and prev is None):
        if first_frame == "mv" and mv1 is not None:
            # no camera history: screen-space fallback (fgen): the surface seen at x was at
            # x' at the same view depth under the same camera; the static mask stays empty
            a = aux(h, w, depth1.device)
            mv = torch.nan_to_num(mv1, nan=0.0).clamp(-OFF, OFF)
            xp, yp = a["xh"] + mv[0], a["yh"] + mv[1]
            moving = (mv[0] ** 2 + mv[1] ** 2 > threshold * threshold) & (p[3] > 0)
            if not reads_back(moving) or bool(moving.any()):
                p1 = g.unproject(depth1, cam1, xp, yp, (h, w))
                m = (moving & (p1[3] == p[3]))[None]
                for i in range(1, k):
                    traj[i] = torch.where(m, p1, p)
                dyn = moving[None]  # moving pixels stay out of the background layers
        return traj, dyn
    xh, yh, _, ok = g.project(p, cam0, (h, w))
    a = aux(h, w, depth1.device)
    mv = torch.nan_to_num(mv1, nan=0.0).clamp(-OFF, OFF)
    xp = a["xh"] + mv[0]
    yp = a["yh"] + mv[1]
    dist2 = (xh - xp) ** 2 + (yh - yp) ** 2
    dyn = ok & (dist2 > threshold * threshold) & (p[3] > 0)  # sky follows the camera
    idx, inside = _sample_nearest_idx(xp, yp, h, w)
    use = dyn & inside.view(h, w)
    fallback = None
    if lookup == "match" and depth0 is not None:
        idx, fallback = _match_idx(depth0, depth1, xp, yp, idx, use, match_tol)
    # P'_0 at x': exact sub-pixel position, depth of the nearest pixel
    if depth0 is not None:
        d0 = gather_pixels(check_tensor(depth0, "depth0", 1, allow_batch=False), idx).view(1, h, w)
        p1 = g.unproject(d0, cam0, xp, yp, (h, w))
    else:
        p1 = gather_pixels(prev[0], idx).view(4, h, w)
    olds = [p1]
    for i in range(1, k - 1):
        src = prev[i] if prev is not None and prev.shape[0] > i else None
        olds.append(p1 if src is None else gather_pixels(src, idx).view(4, h, w))
    if fallback is not None and (not reads_back(fallback) or bool(fallback.any())):
        # no pixel near x' shows this surface (a silhouette: x' fell on the surface behind
        # or in front): it was at x' at its current view depth (screen-space motion)
        pf = g.unproject(depth1, cam0, xp, yp, (h, w))
        p1 = torch.where(fallback[None], pf, p1)
        olds = [torch.where(fallback[None], pf, q) for q in olds]
    same_kind = (p1[3] == p[3]) & (p1[3] > 0)
    use = use & same_kind
    for i, q in enumerate(olds):
        ok_i = use & (q[3] == p[3])
        traj[i + 1] = torch.where(ok_i[None], q, p)
    return traj, use[None]


def _selection(mask: torch.Tensor) -> torch.Tensor | None:
    """Flat indices of ``mask``'s pixels where it reads back cheaply (the CPU: compute only
    those), else None (a GPU: every pixel, no host round-trip). See _pick."""
    return mask.reshape(-1).nonzero().squeeze(1) if reads_back(mask) else None


def _pick(t: torch.Tensor, sel: torch.Tensor | None) -> torch.Tensor:
    """t flattened, at the _selection indices (all of it for None)."""
    flat = t.reshape(-1)
    return flat if sel is None else flat[sel]


def _match_idx(depth0, depth1, xp, yp, idx, use, tol):
    """fgen: the pixel of the 3x3 block around x' whose previous depth is nearest (in ratio)
    to the current depth; (idx, fallback) where fallback marks pixels with no neighbour
    within tol (relative). Only the ``use`` pixels are searched (on the CPU, only they are
    computed: usually a small part of the frame)."""
    h, w = depth1.shape[-2:]
    ld0 = torch.log(torch.nan_to_num(depth0[0], nan=0.0, posinf=1e30).clamp_min(1e-30)).view(-1)
    sel = _selection(use)
    if sel is not None and sel.numel() == 0:
        return idx, torch.zeros_like(use)
    ld1 = torch.log(_pick(torch.nan_to_num(depth1[0], nan=0.0, posinf=1e30), sel)
                    .clamp_min(1e-30))
    ix = torch.floor(_pick(xp, sel)).clamp(0, w - 1).to(torch.int64)
    iy = torch.floor(_pick(yp, sel)).clamp(0, h - 1).to(torch.int64)
    best = torch.full_like(ld1, math.inf)
    bidx = _pick(idx, sel).clone()
    for oy in (0, -1, 1):
        for ox in (0, -1, 1):
            j = (iy + oy).clamp(0, h - 1) * w + (ix + ox).clamp(0, w - 1)
            err = (ld0[j] - ld1).abs()
            better = err < best - 1e-7
            best = torch.where(better, err, best)
            bidx = torch.where(better, j, bidx)
    miss = best > math.log1p(tol)
    if sel is None:
        return bidx, use & miss.view(h, w)
    out = idx.clone()
    out[sel] = bidx
    fb = torch.zeros(h * w, dtype=torch.bool, device=use.device)
    fb[sel] = miss
    return out, fb.view(h, w)


def dilate_trajectory(traj: torch.Tensor, depth1: torch.Tensor, cam1,
                      dynamic: torch.Tensor | None = None,
                      geom: Geometry | None = None) -> torch.Tensor:
    """fgen: Mob-FGSR's / FSR 2's 3x3 nearest-depth dilation in world space. Each pixel x
    takes the depth of the nearest-depth pixel n of its window (fgcli.ops.splat.
    dilate_nearest_depth, same tie rules; it is unprojected on x's own ray) and moves as n
    moves: P_i(x) = P_0'(x) + (P_i(n) - P_0(n)). Anti-aliased silhouettes and contact
    shadows then travel with their object. Only where x and n are both surfaces; with
    ``dynamic`` (1, H, W) bool, only static pixels x whose winner n is dynamic (a moving
    object's rim and the shadow it drags; the position stage's dilate=dynamic).

    Args: traj (k, 4, H, W) newest first; depth1 (1, H, W); cam1 frame 1's camera.
    Returns a new (k, 4, H, W)."""
    from fgcli.ops.splat import dilate_nearest_depth

    k, _, h, w = traj.shape
    a = aux(h, w, traj.device)
    coords = torch.stack([a["xh"].expand(h, w), a["yh"].expand(h, w)])
    dd, src = dilate_nearest_depth(depth1, coords)
    idx = (torch.floor(src[1]).clamp(0, h - 1) * w + torch.floor(src[0]).clamp(0, w - 1))
    idx = idx.to(torch.int64).view(-1)
    tn = [gather_pixels(traj[i], idx).view(4, h, w) for i in range(k)]
    p0 = traj[0]
    both = ((tn[0][3] > 0) & (p0[3] > 0))[None]
    if dynamic is not None:  # only static pixels, only toward dynamic winners
        both = both & (gather_pixels(dynamic.float(), idx).view(1, h, w) > 0.5) & ~dynamic
    out = traj.clone()
    # x also takes n's depth (its place in the splat)
    pd = (geom or TORCH_GEOM).unproject(dd, cam1)
    p0 = torch.where(both & (pd[3] > 0)[None], pd, p0)
    out[0] = p0
    for i in range(1, k):
        ok = both & (tn[i][3] == tn[0][3])
        out[i] = torch.where(ok, p0 - (tn[0] - tn[i]), traj[i])
    return out


def estimate_positions(traj: torch.Tensor, alpha: float, motion: str = "linear") -> torch.Tensor:
    """Eq. 1: NP = alpha (P0 - P1) + P0 (linear in world space). motion='quadratic' fits a
    parabola through P0, P1, P2 (the paper's higher-order ablation, needs k >= 3):
    NP = P0 + alpha (P0 - P1) + alpha (alpha + 1) / 2 (P0 - 2 P1 + P2).

    Args: traj (k, 4, H, W) homogeneous world positions (newest first); alpha >= 0.
    Returns (4, H, W). Entries whose history mixes surfaces and directions keep P0."""
    a = check_alpha(alpha, hi=None)
    check_choice(motion, "motion", ("linear", "quadratic"))
    p0, p1 = traj[0], traj[1]
    vel = p0 - p1
    out = p0 + a * vel
    if motion == "quadratic" and traj.shape[0] >= 3:
        acc = p0 - 2.0 * p1 + traj[2]
        out = out + (a * (a + 1.0) / 2.0) * acc
        same = (traj[2][3] == p0[3])
    else:
        same = torch.ones_like(p0[3], dtype=torch.bool)
    same = same & (p1[3] == p0[3])
    out[3] = p0[3]
    return torch.where(same[None], out, p0)


def dilated_positions(traj: torch.Tensor, depth1: torch.Tensor, cam1,
                      dynamic: torch.Tensor | None, alpha: float, motion: str = "linear",
                      geom: Geometry | None = None) -> torch.Tensor:
    """The position stage with dilation: estimate_positions(dilate_trajectory(traj,
    depth1, cam1, dynamic), alpha, motion) (4, H, W)."""
    return estimate_positions(dilate_trajectory(traj, depth1, cam1, dynamic, geom=geom),
                              alpha, motion)


# ----------------------------------------------------------------------------- splats

def _splat_min(tx: torch.Tensor, ty: torch.Tensor, key_depth: torch.Tensor, use: torch.Tensor,
               h: int, w: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Nearest-depth-wins splat of fragments (any grid) into an (h, w) target grid, with the
    packed int64 keys of fgcli.ops.splat (float32 depth bits << 32 | source index).

    tx, ty: integer-valued float target pixel indices; key_depth: >= 0 depth (+inf allowed);
    use: bool. Returns (src (h, w) int64 flat source index or -1, depth (h, w), +inf empty)."""
    n = key_depth.numel()
    dev = key_depth.device
    d = torch.nan_to_num(key_depth.reshape(1, -1), nan=math.inf, posinf=math.inf).clamp_min(0.0).contiguous()
    key = _pack_key(d, aux(1, n, dev))
    inside = use.reshape(-1) & (tx.reshape(-1) >= 0) & (tx.reshape(-1) < w) & \
        (ty.reshape(-1) >= 0) & (ty.reshape(-1) < h)
    q = (ty.reshape(-1).clamp(0, h - 1) * w + tx.reshape(-1).clamp(0, w - 1)).to(torch.int64)
    q = torch.where(inside, q, torch.full_like(q, h * w))
    buf = torch.full((h * w + 1,), I64_MAX, dtype=torch.int64, device=dev)
    buf.scatter_reduce_(0, q, key, reduce="amin", include_self=True)
    win = buf[:h * w]
    halves = win.view(torch.int32).view(h * w, 2)
    src = halves[:, 0].to(torch.int64)
    hit = win != I64_MAX
    src = torch.where(hit, src, torch.full_like(src, -1))
    dep = torch.where(hit, halves[:, 1].contiguous().view(torch.float32),
                      torch.full((h * w,), math.inf, device=dev))
    return src.view(h, w), dep.view(h, w)


def warp_positions(color1: torch.Tensor, positions: torch.Tensor, cam_x, filter: str = "bilinear",
                   crack_fill: bool = True, geom: Geometry | None = None,
                   origin: torch.Tensor | None = None):
    """Forward warp of frame 1's fragments to their estimated positions seen by the
    extrapolated camera; nearest depth wins (fgcli.ops.splat.splat_motion's packed keys).

    Args:
        color1: (3, H, W) rendered color. positions: (4, H, W) estimated world positions
            (estimate_positions). cam_x: extrapolated camera.
        filter: 'bilinear' (sample frame 1 at the winner's exact sub-pixel source position
            plus the target's rounding offset) or 'nearest' (the winner's own color, as the
            paper's atomic splat).
        crack_fill: fill one-pixel splat cracks inside nearer surfaces with Mob-FGSR's
            2x2-block rule (fgcli.ops.fill.gap_fill; an fgen addition: the paper leaves these
            "thin black lines" of forward warping to later stages).
        origin: (4, H, W) the points that cam_x sees at the pixel centres (frame 1's
            unprojected depth P_0 when cam_x is frame 1's camera, a still camera), or None.
            A position equal to its pixel's origin stays on its pixel exactly: its splat
            vector is zero (float32's projection of the unprojection would move it by
            ~1e-5 px, and the bilinear read would mix in its neighbours by as much).

    Returns dict: color (3, H, W) (0 in holes), depth (1, H, W) view depth in the new view
    (+inf holes and sky), mv (2, H, W) toward frame 1 (0 in holes), valid (1, H, W) bool.
    """
    color1 = check_tensor(color1, "color1", 3, allow_batch=False)
    check_choice(filter, "filter", ("bilinear", "nearest"))
    h, w = color1.shape[-2:]
    px, py, dn, ok = (geom or TORCH_GEOM).project(positions, cam_x, (h, w))
    a = aux(h, w, color1.device)
    dx, dy = px - a["xh"], py - a["yh"]
    if origin is not None:  # (the positions at their origin: on their pixels)
        origin = check_tensor(origin, "origin", 4, allow_batch=False)
        check_same(positions, "positions", (origin, "origin"))
        rest = (positions == origin).all(0)
        dx = torch.where(rest, torch.zeros_like(dx), dx)
        dy = torch.where(rest, torch.zeros_like(dy), dy)
    dx = torch.where(ok, dx, torch.full_like(px, OFF))
    dy = torch.where(ok, dy, torch.full_like(py, OFF))
    # splat_motion (linear, extrap, alpha 1) moves each source by exactly -mv1
    res = splat_motion(dn[None], -torch.stack([dx, dy]), None, 1.0, model="linear",
                       mode="extrap")
    if crack_fill:
        from fgcli.ops.fill import gap_fill

        res = gap_fill(res, 0.01, "nearest")
    valid = res.valid
    c1 = sanitize_values(color1)
    if filter == "bilinear":
        col, _ = backward_warp(c1, res.to1, "bilinear")
    else:
        src = res.source.view(-1).clamp_min(0).to(torch.int64)
        col = gather_pixels(c1, src).view(3, h, w)
    col = torch.where(valid, col, torch.zeros_like(col))
    mv = torch.where(valid, res.to1, torch.zeros_like(res.to1))
    return {"color": col, "depth": res.depth, "mv": mv, "valid": valid}


# ----------------------------------------------------------------------------- background

def _half(h, w):
    return (h + 1) // 2, (w + 1) // 2


def _layer_scale(layer, H: int, W: int) -> float:
    """Full pixels per cell of a layer grid: 1 (full size) or 2 (half width and height;
    a 1x1 image is both)."""
    return 1.0 if tuple(layer["depth"].shape[-2:]) == (H, W) else 2.0


def _centres(h, w, scale, dev):
    """Pixel-coordinate centres (full-image units) of an (h, w) grid of cells `scale` wide."""
    ys = (torch.arange(h, dtype=torch.float32, device=dev) + 0.5) * scale
    xs = (torch.arange(w, dtype=torch.float32, device=dev) + 0.5) * scale
    return xs[None, :].expand(h, w), ys[:, None].expand(h, w)


def empty_layer(h, w, dev):
    return {"color": torch.zeros(3, h, w, device=dev), "depth": torch.full((1, h, w), math.inf, device=dev),
            "valid": torch.zeros(1, h, w, dtype=torch.bool, device=dev)}


def _layer_fragments(layer, cam_from, cam_to, size, scale, geom=None):
    """Reproject a layer's valid fragments (grid cells `scale` full pixels wide) to cam_to."""
    h, w = layer["depth"].shape[-2:]
    cx, cy = _centres(h, w, scale, layer["depth"].device)
    d = torch.where(layer["valid"], layer["depth"], 0.0)  # (a scalar: no zero plane made)
    g = geom or TORCH_GEOM
    px, py, dn, ok = _reproject(g, d, cam_from, cam_to, size, cx, cy)
    return px, py, dn, ok & layer["valid"][0]


def _edge_pixels(depth: torch.Tensor, dynamic: torch.Tensor, depth_tol: float) -> torch.Tensor:
    """(1, H, W) bool: pixels whose color may carry a nearer surface (anti-aliased
    silhouettes): a 3x3 neighbour is dynamic, or a 4-neighbour is nearer than the surface's
    linear continuation (2 d - the opposite neighbour) by more than depth_tol (relative), so
    slanted floors are no edges."""
    d = torch.where(torch.isfinite(depth) & (depth > 0), depth, torch.full_like(depth, 1e30))[0]
    p = torch.nn.functional.pad(d[None, None], (1, 1, 1, 1), value=1e30)[0, 0]
    H, W = d.shape
    nb = [p[1:H + 1, 0:W], p[1:H + 1, 2:W + 2], p[0:H, 1:W + 1], p[2:H + 2, 1:W + 1]]
    edge = torch.zeros_like(d, dtype=torch.bool)
    tol = 1.0 - float(depth_tol)
    for a, b in ((nb[0], nb[1]), (nb[1], nb[0]), (nb[2], nb[3]), (nb[3], nb[2])):
        # no opposite neighbour (border, sky): no continuation, no test
        cont = torch.where(b < 1e29, 2.0 * d - b, torch.zeros_like(d)).clamp_min(0.0)
        edge |= a < torch.minimum(cont, d) * tol
    dyn = torch.nn.functional.max_pool2d(dynamic[None].float(), 3, 1, 1)[0] > 0
    return edge[None] | dyn


def collect_background(color1: torch.Tensor, depth1: torch.Tensor, static: torch.Tensor, cam1,
                       prev_layers: list | None = None, cam_prev=None,
                       depth_tol: float = 0.02, edge_guard: bool = False,
                       layer1_scale: int = 2, geom: Geometry | None = None) -> list:
    """Layered background collection (Sec. 4.2, Fig. 5), L = 2: layer 0 full size, layer 1
    half width and height (a quarter of the pixels). Layers are registered to cam1's view.

    B_0 starts as the static fragments of the rendered frame. Each fragment of the previous
    layer B'_l, reprojected (static) to x' in the current view:
      * Case 1: B_l[x'] invalid -> the fragment fills B_l[x'] (layer 0: only when it lies
        behind what the frame shows at x', e.g. behind a dynamic object);
      * Case 2: B_l[x'] valid and the fragment is deeper (by more than depth_tol, relative)
        -> it goes to B_{l+1}[x'] (dropped past the last layer).
    Several fragments on one pixel: the nearest wins (packed-key splat).

    Args:
        color1 (3, H, W), depth1 (1, H, W), static (1, H, W) bool, cam1; prev_layers: list
        of 2 dicts {color, depth, valid} from the previous call (or None), cam_prev their
        camera. Returns the new list of 2 layers.
    """
    color1 = sanitize_values(check_tensor(color1, "color1", 3, allow_batch=False))
    depth1 = check_tensor(depth1, "depth1", 1, allow_batch=False)
    H, W = depth1.shape[-2:]
    if layer1_scale not in (1, 2):
        raise ValueError(f"layer1_scale: expected 1 or 2, got {layer1_scale}")
    sc = float(layer1_scale)
    h2, w2 = _half(H, W) if layer1_scale == 2 else (H, W)
    dev = depth1.device
    d1 = torch.nan_to_num(depth1, nan=0.0)
    usable = (d1 > 0) & static
    guard = torch.zeros_like(usable)
    if edge_guard:
        guard = usable & _edge_pixels(d1, ~static, depth_tol)
        usable = usable & ~guard
    l0 = {"color": torch.where(usable, color1, torch.zeros_like(color1)),
          "depth": torch.where(usable, d1, torch.full_like(d1, math.inf)), "valid": usable.clone()}
    l1 = empty_layer(h2, w2, dev)
    if prev_layers is None or cam_prev is None:
        return [l0, l1]
    tol = 1.0 + float(depth_tol)
    # ---- level 0 of the previous buffer
    p0 = prev_layers[0]
    px, py, dn, ok = _layer_fragments(p0, cam_prev, cam1, (H, W), 1.0, geom)
    tx, ty = torch.floor(px), torch.floor(py)
    idx, inside = _sample_nearest_idx(px, py, H, W)
    inside = inside.view(H, W) & ok
    at_valid = gather_pixels(l0["valid"].float(), idx).view(H, W) > 0.5
    # "deeper" than the whole 3x3 neighbourhood of x': a fragment at a depth edge that only
    # rounding put behind the occluder's silhouette stays out of layer 1
    far0 = torch.nn.functional.max_pool2d(l0["depth"][None], 3, 1, 1)[0]
    at_depth = gather_pixels(far0, idx).view(H, W)
    at_d1 = gather_pixels(d1, idx).view(H, W)
    # a guarded pixel (silhouette) keeps the older fragment of the same surface
    at_guard = gather_pixels(guard.float(), idx).view(H, W) > 0.5
    case1 = inside & ~at_valid & ((dn > at_d1 * tol) | (at_d1 <= 0) |
                                  (at_guard & (dn * tol >= at_d1)))
    case2 = inside & at_valid & (dn > at_depth * tol)
    src, dep = _splat_min(tx, ty, dn, case1, H, W)
    fill = (src >= 0)[None] & ~l0["valid"]
    s = src.clamp_min(0).view(-1)
    l0["color"] = torch.where(fill, gather_pixels(p0["color"], s).view(3, H, W), l0["color"])
    l0["depth"] = torch.where(fill, dep[None], l0["depth"])
    l0["valid"] = l0["valid"] | fill
    src, dep = _splat_min(torch.floor(px / sc), torch.floor(py / sc), dn, case2, h2, w2)
    got = (src >= 0)[None]
    s = src.clamp_min(0).view(-1)
    l1["color"] = torch.where(got, gather_pixels(p0["color"], s).view(3, h2, w2), l1["color"])
    l1["depth"] = torch.where(got, dep[None], l1["depth"])
    l1["valid"] = got
    # ---- level 1 of the previous buffer: Case 1 into B_1 when it lies behind B_0
    p1 = prev_layers[1]
    sp = _layer_scale(p1, H, W)
    px, py, dn, ok = _layer_fragments(p1, cam_prev, cam1, (H, W), sp, geom)
    idx, inside = _sample_nearest_idx(px, py, H, W)
    inside = inside.view(*px.shape) & ok
    at_valid = gather_pixels(l0["valid"].float(), idx).view(*px.shape) > 0.5
    at_depth = gather_pixels(torch.where(l0["valid"], l0["depth"], d1), idx).view(*px.shape)
    behind = inside & (dn > at_depth * tol) & (at_valid | (at_depth > 0))
    tx2, ty2 = torch.floor(px / sc), torch.floor(py / sc)
    i2, _ = _sample_nearest_idx(px / sc, py / sc, h2, w2)
    free = gather_pixels((~l1["valid"]).float(), i2).view(*px.shape) > 0.5
    src, dep = _splat_min(tx2, ty2, dn, behind & free, h2, w2)
    fill = (src >= 0)[None] & ~l1["valid"]
    s = src.clamp_min(0).view(-1)
    l1["color"] = torch.where(fill, gather_pixels(p1["color"], s).view(3, h2, w2), l1["color"])
    l1["depth"] = torch.where(fill, dep[None], l1["depth"])
    l1["valid"] = l1["valid"] | fill
    return [l0, l1]


def _sample_layer(layer, src, px, py, want, depth_tol: float = 0.05):
    """Bilinear reading of a full-size layer: the target pixel q whose winning fragment is
    ``src`` (flat index into the layer grid; its exact projected position px, py) reads
    the layer at the fragment's cell centre plus q's offset from (px, py), weighting only
    valid layer cells within depth_tol (relative) of the fragment's depth. Where no such
    weight is left, the fragment's own color. Only the ``want`` (H, W) pixels are read (on
    the CPU only they are computed). Returns (3, H, W), the fragment's color elsewhere."""
    H, W = src.shape
    s = src.clamp_min(0).view(-1)
    out = gather_pixels(layer["color"], s).view(3, H, W)
    sel = _selection(want)
    if sel is not None and sel.numel() == 0:
        return out
    a = aux(H, W, src.device)
    ss = _pick(src, sel).clamp_min(0)
    qx = _pick(a["xh"].expand(H, W), sel)
    qy = _pick(a["yh"].expand(H, W), sel)
    # the fragment's cell centre plus q's offset from where the fragment landed, in tap
    # coordinates (pixel centres at integers: the centre's + 0.5 cancels the taps' - 0.5)
    x = (ss % W).float() + (qx - px.reshape(-1)[ss])
    y = torch.div(ss, W, rounding_mode="floor").float() + (qy - py.reshape(-1)[ss])
    x0, y0 = torch.floor(x), torch.floor(y)
    fx, fy = x - x0, y - y0
    valid = layer["valid"].reshape(-1)
    dep = layer["depth"].reshape(-1)
    col = layer["color"].reshape(3, -1)
    dref = dep[ss]
    acc = torch.zeros(3, ss.numel(), device=src.device)
    wsum = torch.zeros(ss.numel(), device=src.device)
    for oy, wy in ((0, 1.0 - fy), (1, fy)):
        for ox, wx in ((0, 1.0 - fx), (1, fx)):
            tx, ty = x0 + ox, y0 + oy
            inside = (tx >= 0) & (tx < W) & (ty >= 0) & (ty < H)
            j = (ty.clamp(0, H - 1) * W + tx.clamp(0, W - 1)).to(torch.int64)
            ok = inside & valid[j] & ((dep[j] - dref).abs() <= dref * depth_tol)
            wt = torch.where(ok, wx * wy, torch.zeros_like(wx))
            acc += col[:, j] * wt
            wsum += wt
    good = wsum > 0.5
    val = torch.where(good, acc / wsum.clamp_min(1e-12), col[:, ss])
    flat = out.view(3, -1)
    if sel is not None:
        flat[:, sel] = val
    else:
        flat.copy_(torch.where(want.reshape(1, -1), val, flat))
    return out


def project_background(layers: list, cam_bg, cam_x, holes: torch.Tensor, filter: str = "nearest",
                       geom: Geometry | None = None):
    """Background projection: the collected layers (registered to cam_bg) seen by the
    extrapolated camera; only the ``holes`` (1, H, W) bool of the warped frame are filled.
    A hole takes the nearest fragment of either layer (layer 1 lands on its half-size
    grid, each cell covering 2x2 pixels, unless it is full size: layer1_scale=1).
    filter 'bilinear' (fgen): a hole reads a full-size layer bilinearly at its exact
    sub-pixel place (_sample_layer) rather than the winning fragment's color (the paper's
    splat, 'nearest'; a half-size layer 1 always gives its fragment's color).

    Returns (color (3, H, W), depth (1, H, W), mv (2, H, W) toward frame 1, filled (1, H, W)
    bool); values outside ``filled`` are 0 / +inf."""
    H, W = holes.shape[-2:]
    h2, w2 = _half(H, W)
    dev = holes.device
    l0, l1 = layers
    px, py, dn, ok = _layer_fragments(l0, cam_bg, cam_x, (H, W), 1.0, geom)
    s0, d0 = _splat_min(torch.floor(px), torch.floor(py), dn, ok, H, W)
    sc = _layer_scale(l1, H, W)
    if sc == 1.0:
        h2, w2 = H, W
    px1, py1, dn1, ok1 = _layer_fragments(l1, cam_bg, cam_x, (H, W), sc, geom)
    s1, d1 = _splat_min(torch.floor(px1 / sc), torch.floor(py1 / sc), dn1, ok1, h2, w2)
    if sc == 2.0:
        s1 = s1.repeat_interleave(2, 0).repeat_interleave(2, 1)[:H, :W]
        d1 = d1.repeat_interleave(2, 0).repeat_interleave(2, 1)[:H, :W]
    h0, h1 = s0 >= 0, s1 >= 0
    take1 = h1 & (~h0 | (d1 < d0))
    take0 = h0 & ~take1
    hole = holes[0]
    if filter == "bilinear":
        c0 = _sample_layer(l0, s0, px, py, hole & take0)
    else:
        c0 = gather_pixels(l0["color"], s0.clamp_min(0).view(-1)).view(3, H, W)
    if filter == "bilinear" and sc == 1.0:
        c1 = _sample_layer(l1, s1, px1, py1, hole & take1)
    else:
        c1 = gather_pixels(l1["color"], s1.clamp_min(0).view(-1)).view(3, H, W)
    color = torch.where(take1[None], c1, c0)
    depth = torch.where(take1, d1, d0)[None]
    # motion toward frame 1: the fragment's pixel in the background grid (frame 1's view)
    a = aux(H, W, dev)
    sx0 = (s0.clamp_min(0) % W).float() + 0.5
    sy0 = torch.div(s0.clamp_min(0), W, rounding_mode="floor").float() + 0.5
    sx1 = ((s1.clamp_min(0) % w2).float() + 0.5) * sc
    sy1 = (torch.div(s1.clamp_min(0), w2, rounding_mode="floor").float() + 0.5) * sc
    mvx = torch.where(take1, sx1, sx0) - a["xh"]
    mvy = torch.where(take1, sy1, sy0) - a["yh"]
    filled = holes & (take0 | take1)[None]
    z = torch.zeros_like
    return (torch.where(filled, color, z(color)), torch.where(filled, depth, torch.full_like(depth, math.inf)),
            torch.where(filled, torch.stack([mvx, mvy]), z(torch.stack([mvx, mvy]))), filled)


def entering_surface(filled: torch.Tensor, depth: torch.Tensor, color1: torch.Tensor,
                     depth1: torch.Tensor, mv1: torch.Tensor, alpha: float,
                     behind: bool = False):
    """fgen: background-projected holes q where frame 1 shows a nearer surface whose vector
    leads off-screen (``q + alpha * mv1(q)`` outside the image: the surface came in across
    the border). Its unseen part, now at q, hides the layers' older fragment there (a near
    object entering the frame: the layers remember the floor it now covers); frame 1 at q,
    the surface's nearest seen pixel, stands in for it (Mob-FGSR's zero-motion case).
    behind: also where that point is on screen but frame 1 shows a nearer surface there
    (the surface at q came out from behind it: its hidden part now lies at q; blade's box
    emerging from behind the ball).

    Args: filled (1, H, W) bool (projected holes), depth (1, H, W) their projected depth;
    frame 1's color1 (3, H, W), depth1 (1, H, W), mv1 (2, H, W); alpha; behind (bool).
    Returns (color (3, H, W), depth (1, H, W), take (1, H, W) bool)."""
    H, W = filled.shape[-2:]
    a = aux(H, W, filled.device)
    m = torch.nan_to_num(mv1, nan=0.0).clamp(-OFF, OFF)
    sx, sy = a["xh"] + float(alpha) * m[0], a["yh"] + float(alpha) * m[1]
    off = ((sx < 0) | (sx >= W) | (sy < 0) | (sy >= H))[None]
    d1 = torch.nan_to_num(depth1, nan=math.inf)
    if behind:  # ... or from behind a nearer surface (the rule's sample is nearer)
        idx, inside = _sample_nearest_idx(sx, sy, H, W)
        ds = gather_pixels(d1, idx).view(1, H, W)
        off = off | (inside.view(1, H, W) & (ds < d1 * (1.0 - 1e-3)))
    take = filled & off & (d1 < depth) & (d1 > 0)
    return sanitize_values(color1), d1, take


def background_fill(color: torch.Tensor, depth: torch.Tensor, mv: torch.Tensor,
                    valid: torch.Tensor, layers: list, cam_bg, cam_x, filter: str = "nearest",
                    color1: torch.Tensor | None = None, depth1: torch.Tensor | None = None,
                    mv1: torch.Tensor | None = None, alpha: float = 0.5,
                    entering: bool = False, emerging: bool = False,
                    geom: Geometry | None = None, in_place: bool = False):
    """The background projection stage (gffe_bg_project) as one op: the layers seen by
    cam_x fill the holes (~valid) of the warped frame (project_background); with
    ``entering`` (and frame 1's color1, depth1, mv1), entering_surface's nearer surfaces
    (``emerging``: its ``behind`` case too) replace the layers' fragments there.

    Returns (color (3, H, W), depth (1, H, W), mv (2, H, W), valid (1, H, W) bool): the
    inputs with the filled holes replaced, valid | filled. in_place: the caller gives its
    scratch planes up (fgcli.ops._util.mark_scratch); this reference makes new tensors
    always (the numba op writes into them)."""
    c, d, m, filled = project_background(layers, cam_bg, cam_x, ~valid, filter, geom=geom)
    if entering and mv1 is not None:
        c1, d1, take = entering_surface(filled, d, color1, depth1, mv1, alpha, emerging)
        c, d = torch.where(take, c1, c), torch.where(take, d1, d)
        m = torch.where(take, torch.zeros_like(m), m)
    return (torch.where(filled, c, color), torch.where(filled, d, depth),
            torch.where(filled, m, mv), valid | filled)


def project_border(border: dict, cam1, cam_x, holes: torch.Tensor, geom: Geometry | None = None):
    """The overscan border of frame 1 (Frame.overscan: the rendered pixels outside the
    display window) seen by the extrapolated camera: GFFE's use of a larger rendering
    window (Sec. 4.3), the border's fragments splatted (static, nearest depth wins) into
    the ``holes`` (1, H, W) of the extrapolated frame. Pixels inside the display window
    are left out (the warp has them).

    Returns (color (3, H, W), depth (1, H, W), mv (2, H, W) toward frame 1, filled (1, H,
    W) bool), as project_background."""
    H, W = holes.shape[-2:]
    dev = holes.device
    ox, oy = border["origin"]
    c_ext, d_ext = border["color"], border["depth"]
    He, We = d_ext.shape[-2:]
    cx, cy = _centres(He, We, 1.0, dev)
    cx, cy = cx + float(ox), cy + float(oy)  # pixel centres in display coordinates
    ring = (cx < 0) | (cx >= W) | (cy < 0) | (cy >= H)
    d = d_ext[0]
    use = ring & torch.isfinite(d) & (d > 0)
    g = geom or TORCH_GEOM
    px, py, dn, ok = _reproject(g, torch.where(use, d, torch.zeros_like(d))[None], cam1, cam_x,
                                (H, W), cx, cy)
    src, dep = _splat_min(torch.floor(px), torch.floor(py), dn, ok & use, H, W)
    s = src.view(H, W)
    hit = s >= 0
    color = gather_pixels(sanitize_values(c_ext), s.clamp_min(0).view(-1)).view(3, H, W)
    a = aux(H, W, dev)
    sc = s.clamp_min(0)
    sx = (sc % We).float() + 0.5 + float(ox)
    sy = torch.div(sc, We, rounding_mode="floor").float() + 0.5 + float(oy)
    mv = torch.stack([sx - a["xh"], sy - a["yh"]])
    filled = holes & hit[None]
    z = torch.zeros_like
    return (torch.where(filled, color, z(color)),
            torch.where(filled, dep.view(1, H, W), torch.full_like(dep.view(1, H, W), math.inf)),
            torch.where(filled, mv, z(mv)), filled)


# ----------------------------------------------------------------------------- window

def median_depth(depth: torch.Tensor) -> float:
    """The (lower) median of the finite positive values of ``depth``, NaN when there are
    none: the adaptive window's default plane depth (the one value gffe reads back per
    frame on a GPU)."""
    ok = torch.isfinite(depth) & (depth > 0)
    return float(torch.where(ok, depth, float("nan")).nanmedian())


def render_window(cam, cam_x, plane_depth: float, limit: float = 4.0) -> tuple[float, ...]:
    """Appendix C, Eq. 5: the rendering window (u0, v0, u1, v1) in the current camera's NDC
    (the nominal window is (-1, -1, 1, 1)) that also covers what the extrapolated camera
    cam_x sees on a virtual plane at view depth ``plane_depth`` in front of the current
    camera. Entries are clamped to [-limit, limit] (a corner ray of cam_x that misses the
    plane gives the limit)."""
    v1, p1 = _mats(cam)
    vx, px_ = _mats(cam_x)
    d = float(plane_depth)
    if not (d > 0 and math.isfinite(d)):
        raise ValueError(f"plane_depth: expected > 0, got {plane_depth}")
    corners = np.array([[-1, -1], [1, -1], [-1, 1], [1, 1]], dtype=np.float64)

    def view_pts(p, zn):
        ip = np.linalg.inv(p)
        c = ip @ np.stack([corners[:, 0], corners[:, 1], np.full(4, zn), np.ones(4)])
        return c[:3] / c[3]

    # current camera: corners on the plane z = -d (its own view space)
    n, f = view_pts(p1, -1.0), view_pts(p1, 1.0)
    s = (-d - n[2]) / (f[2] - n[2])
    r = n + (f - n) * s
    xmin, xmax, ymin, ymax = r[0].min(), r[0].max(), r[1].min(), r[1].max()
    # extrapolated camera: corner rays, in the current view space, hit the same plane
    to_cur = v1 @ np.linalg.inv(vx)
    n2, f2 = view_pts(px_, -1.0), view_pts(px_, 1.0)
    n2 = (to_cur @ np.vstack([n2, np.ones(4)]))[:3]
    f2 = (to_cur @ np.vstack([f2, np.ones(4)]))[:3]
    dz = f2[2] - n2[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (-d - n2[2]) / dz
    hit = np.isfinite(t) & (t > 0)
    q = n2 + (f2 - n2) * np.where(hit, t, 0.0)
    big = limit * max(abs(xmax), abs(ymax), 1e-12) * 10
    qx = np.where(hit, q[0], np.sign(f2[0] - n2[0] + 1e-300) * big)
    qy = np.where(hit, q[1], np.sign(f2[1] - n2[1] + 1e-300) * big)
    u0 = min(-1.0, -qx.min() / xmin)
    v0 = min(-1.0, -qy.min() / ymin)
    u1 = max(1.0, qx.max() / xmax)
    v1_ = max(1.0, qy.max() / ymax)
    return tuple(float(np.clip(x, -limit, limit)) for x in (u0, v0, u1, v1_))


# ----------------------------------------------------------------------------- fill

def push_pull_fill(color: torch.Tensor, valid: torch.Tensor, depth: torch.Tensor | None = None,
                   far_bias: float = 0.1):
    """Fill invalid pixels by push-pull (a validity-weighted image pyramid: average the
    valid pixels 2x2 down to 1x1, then fill each level's holes from the next coarser one).
    With depth, each 2x2 average keeps only the pixels within ``far_bias`` (relative) of
    the block's farthest depth: holes are disocclusions, whose content is background.

    Args: color (C, H, W); valid (1, H, W) bool; depth (1, H, W) or None (filled from the
    finite depths alike; +inf where no finite depth exists).
    Returns (color (C, H, W), depth (1, H, W) or None); valid pixels are unchanged. With no
    valid pixel at all, colors are 0."""
    color = sanitize_values(check_tensor(color, "color", None, allow_batch=False))
    C = color.shape[0]
    stack = [color]
    if depth is not None:
        dfin = torch.isfinite(depth) & (depth > 0)
        stack.append(torch.where(dfin, depth, torch.zeros_like(depth)))
    x = torch.cat(stack)
    wv = valid.float()
    wd = (valid & dfin).float() if depth is not None else None
    levels = []
    cur_x, cur_w, cur_wd = x, wv, wd
    while True:
        levels.append((cur_x, cur_w, cur_wd))
        h, w = cur_x.shape[-2:]
        if h == 1 and w == 1:
            break
        pool = lambda t: torch.nn.functional.avg_pool2d(  # noqa: E731
            t[None], 2, ceil_mode=True, count_include_pad=False)[0]
        if depth is not None and far_bias >= 0:
            dd = torch.where(cur_w > 0, torch.where(cur_wd > 0, cur_x[C:], torch.full_like(
                cur_w, 1e30)), torch.zeros_like(cur_w))
            mx = torch.nn.functional.max_pool2d(dd[None], 2, ceil_mode=True)[0]
            mx = mx.repeat_interleave(2, -2).repeat_interleave(2, -1)[:, :h, :w]
            cur_w = cur_w * (dd >= mx * (1.0 - far_bias)).float()
        sw = pool(cur_w)
        sx = pool(cur_x[:C] * cur_w)
        nx = torch.where(sw > 0, sx / sw.clamp_min(1e-30), torch.zeros_like(sx))
        if depth is not None:
            swd = pool(cur_wd)
            sd = pool(cur_x[C:] * cur_wd)
            nd = torch.where(swd > 0, sd / swd.clamp_min(1e-30), torch.zeros_like(sd))
            cur_x, cur_wd = torch.cat([nx, nd]), (swd > 0).float()
        else:
            cur_x = nx
        cur_w = (sw > 0).float()
    filled_x, filled_w, filled_wd = levels[-1]
    for lx, lw, lwd in reversed(levels[:-1]):
        h, w = lx.shape[-2:]
        up = filled_x.repeat_interleave(2, -2).repeat_interleave(2, -1)[:, :h, :w]
        upw = filled_w.repeat_interleave(2, -2).repeat_interleave(2, -1)[:, :h, :w]
        nxc = torch.where(lw > 0, lx[:C], up[:C])
        nw = torch.maximum(lw, upw)
        if depth is not None:
            upwd = filled_wd.repeat_interleave(2, -2).repeat_interleave(2, -1)[:, :h, :w]
            nd = torch.where(lwd > 0, lx[C:], up[C:])
            filled_x, filled_wd = torch.cat([nxc, nd]), torch.maximum(lwd, upwd)
        else:
            filled_x = nxc
        filled_w = nw
    out = torch.where(valid, color, filled_x[:C])
    if depth is None:
        return out, None
    dd = torch.where(filled_wd > 0, filled_x[C:], torch.full_like(depth, math.inf))
    return out, torch.where(valid, depth, dd)


def vector_rule_fill(color: torch.Tensor, valid: torch.Tensor, depth: torch.Tensor,
                     mv: torch.Tensor, color1: torch.Tensor, depth1: torch.Tensor,
                     mv1: torch.Tensor, alpha: float, depth_threshold_rel: float = 1e-3,
                     in_place: bool = False):
    """Holes of the extrapolated frame filled by Mob-FGSR's extrapolation rule
    (fgcli.ops.fill.extrap_hole_fill, shared with mob-fgsr) where it finds background: hole
    q reads frame 1 at ``q + alpha * mv1(q)`` (behind the object that moved away from q)
    when frame 1's depth there is not nearer than at q. An fgen fill that runs before
    GFFE's background projection (stage gffe_vector_rule): frame 1's current shading
    where the rule finds background, the layers' older fragments (and the push-pull) for
    the rest. The rule's other case (zero motion: frame 1 at q, usually the occluder) is
    left to the next fill.

    Args: color (3, H, W), valid (1, H, W) bool, depth (1, H, W), mv (2, H, W) of the
    extrapolated frame; color1, depth1, mv1 frame 1's; alpha the extrapolation distance;
    in_place: as background_fill's (new tensors here always).
    Returns (color, depth, mv toward frame 1, took (1, H, W) bool)."""
    from fgcli.ops.fill import extrap_hole_fill

    H, W = color.shape[-2:]
    zero = torch.zeros(2, H, W, dtype=torch.float32, device=color.device)
    to1, dep, _ = extrap_hole_fill(mv1, depth1, zero, valid, depth, alpha, depth_threshold_rel)
    took = (~valid) & (to1 != 0).any(0, keepdim=True)  # the rule's background case
    flow = torch.where(took, to1, zero)
    smp, _ = backward_warp(sanitize_values(color1), flow, "bilinear")
    return (torch.where(took, smp, color), torch.where(took, dep, depth),
            torch.where(took, flow, mv), took)


def reproject_fill(color: torch.Tensor, valid: torch.Tensor, depth: torch.Tensor, color1: torch.Tensor,
                   depth1: torch.Tensor, cam1, cam_x, depth_tol: float = 0.05,
                   offscreen: str = "clamp", border: dict | None = None,
                   geom: Geometry | None = None):
    """Holes of the extrapolated frame read frame 1 through a proxy surface: the hole pixel's
    ray of cam_x at ``depth`` (the far-biased push-pull depth of its surroundings, i.e. the
    background) projected into frame 1, sampled bilinearly there, where frame 1 shows a
    surface at least that deep (not the occluder) and the point is on screen. An fgen cheap
    fill: real background texture instead of a blur, as Mob-FGSR's background-vector rule.

    Args: color (3, H, W), valid (1, H, W) bool, depth (1, H, W) filled depth of the
    extrapolated frame; color1, depth1 frame 1; cams. offscreen: 'clamp' reads a point that
    frame 1 does not show (out-of-screen disocclusion, no rendered border) at the nearest
    edge pixel (edge extension, as a backward warp with clamped addressing does), 'skip'
    leaves it to the push-pull. border: frame 1's overscan (Frame.overscan: origin, color,
    depth of the rendered region beyond the display window): points there read the
    rendered border instead (GFFE's adaptive window, Sec. 4.3: out-of-screen disocclusions
    filled from pixels the renderer drew); offscreen then applies at the border's edge.
    Returns (color, mv toward frame 1, took (1, H, W) bool: holes filled this way)."""
    check_choice(offscreen, "offscreen", ("clamp", "skip"))
    H, W = color.shape[-2:]
    a = aux(H, W, color.device)
    g = geom or TORCH_GEOM
    px, py, _, ok = _reproject(g, depth, cam_x, cam1, (H, W))
    if border is not None:
        return _reproject_border(color, valid, depth, border, px, py, ok, a, depth_tol,
                                 offscreen)
    if offscreen == "clamp":
        px = torch.where(ok, px.clamp(0.5, W - 0.5), px)
        py = torch.where(ok, py.clamp(0.5, H - 0.5), py)
    took = _proxy_took(valid, depth, depth1, px, py, ok, depth_tol)
    flow = _flow_where(took, px, py, a)
    smp, _ = backward_warp(sanitize_values(color1), flow, "bilinear")
    out = torch.where(took[None], smp, color)
    return out, flow, took[None]


def fill_holes(color: torch.Tensor, depth: torch.Tensor, mv: torch.Tensor,
               valid: torch.Tensor, far_bias: float = 0.1, mode: str = "reproject",
               offscreen: str = "clamp", border_splat: bool = True,
               color1: torch.Tensor | None = None, depth1: torch.Tensor | None = None,
               cam1=None, cam_x=None, border: dict | None = None,
               geom: Geometry | None = None, parts=None, in_place: bool = False):
    """The hole-fill stage (gffe_hole_fill) as one op: the overscan border's fragments
    first (border_splat, with both cameras), the far-biased push-pull, zero vectors in
    its pixels, then (mode 'reproject', with both cameras) reproject_fill.

    parts: (project_border, push_pull_fill, reproject_fill) to compose instead of this
    module's (with geom); the numba backend passes its kernel versions. in_place: as
    background_fill's (new tensors here always).

    Returns (color, depth, mv, holes: the number of pixels the push-pull filled, a 0-dim
    int64 tensor)."""
    import functools

    pb, pp, rf = parts or (functools.partial(project_border, geom=geom), push_pull_fill,
                           functools.partial(reproject_fill, geom=geom))
    v = valid
    cams = cam1 is not None and cam_x is not None
    if border is not None and cams and border_splat:
        bc, bd, bm, bf = pb(border, cam1, cam_x, ~v)
        color, depth = torch.where(bf, bc, color), torch.where(bf, bd, depth)
        mv, v = torch.where(bf, bm, mv), v | bf
    c, d = pp(color, v, depth, far_bias)
    out = torch.where(v, mv, torch.zeros_like(mv))
    if mode == "reproject" and cams:
        c, flow, took = rf(c, v, d, color1, depth1, cam1, cam_x, offscreen=offscreen,
                           border=border)
        out = torch.where(took, flow, out)
    return c, d, out, (~v).sum()


def _proxy_took(valid, depth, src_depth, sx, sy, ok, depth_tol):
    """(H, W) bool: the holes whose proxy point (sx, sy) (pixel coordinates in the source
    arrays, src_depth (1, Hs, Ws)) lies on them, in front of the camera, where the source
    shows a surface at least the proxy's depth (not the occluder)."""
    H, W = depth.shape[-2:]
    idx, inside = _sample_nearest_idx(sx, sy, *src_depth.shape[-2:])
    seen = gather_pixels(torch.nan_to_num(src_depth, nan=0.0), idx).view(H, W)
    dq = depth[0]
    deep = (seen >= dq * (1.0 - depth_tol)) | (torch.isinf(seen) & torch.isinf(dq))
    return (~valid[0]) & ok & inside.view(H, W) & deep


def _flow_where(took, px, py, a):
    """(2, H, W) offsets from each pixel to (px, py) where took, else 0."""
    return torch.stack([torch.where(took, px - a["xh"], torch.zeros_like(px)),
                        torch.where(took, py - a["yh"], torch.zeros_like(py))])


def _reproject_border(color, valid, depth, border, px, py, ok, a, depth_tol, offscreen):
    """reproject_fill's sampling in frame 1's rendered region including its overscan
    border: display coordinates (px, py) are (px - x0, py - y0) in the border arrays."""
    import torch.nn.functional as F

    ox, oy = border["origin"]
    c_ext, d_ext = border["color"], border["depth"]
    He, We = c_ext.shape[-2:]
    ex, ey = px - ox, py - oy
    if offscreen == "clamp":
        ex = torch.where(ok, ex.clamp(0.5, We - 0.5), ex)
        ey = torch.where(ok, ey.clamp(0.5, He - 0.5), ey)
    took = _proxy_took(valid, depth, d_ext, ex, ey, ok, depth_tol)
    # bilinear in the border arrays (pixel-centre coordinates, edge clamped)
    g = torch.stack([ex / We * 2.0 - 1.0, ey / He * 2.0 - 1.0], -1)[None]
    g = torch.nan_to_num(g, nan=-4.0).clamp(-4.0, 4.0)
    smp = F.grid_sample(sanitize_values(c_ext)[None], g, mode="bilinear",
                        padding_mode="border", align_corners=False)[0]
    flow = _flow_where(took, px, py, a)
    out = torch.where(took[None], smp, color)
    return out, flow, took[None]
