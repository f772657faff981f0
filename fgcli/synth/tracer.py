"""Vectorised ray casting against analytic primitives (torch, CPU), exact buffers at any time.

Work layout: the frame is cut into row chunks of at most MAX_RAYS rays; within a chunk every
sample of every pixel is one ray, and each stage (primary visibility, surface attributes,
lights, shadow rays, reflection rays, translucent layer) is a handful of elementwise tensor
ops per primitive. Vectors are tuples of three (N,) tensors (or Python floats for values
shared by every ray, such as the camera position), so constant operands cost nothing.

Only elementwise ops, gathers and scatters with unique indices, and min/max (exact in any
order) are used: no matmul, no sums across rays. The output does not depend on the thread
count: the same scene gives the same bytes.

Work counters (scene.stats, cumulative; `scene.reset_stats()`): primary_rays, shadow_rays,
reflection_rays, translucent_rays, primitive_tests (ray-primitive intersection tests),
bound_tests (bounding-sphere tests of shadow rays), disocclusion_rays and analysis_rays
(extras only).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from fgcli.frame import Camera, Frame
from fgcli.synth import textures
from fgcli.synth.motion import look_at, perspective
from fgcli.synth.scene import Scene

INF = math.inf
FILTER = 1.0  # texture filter width, in pixels
MAX_RAYS = 1 << 16  # rays per chunk: keeps the working set in cache and memory bounded
CULL = True  # skip primitives whose bounding sphere no ray of a batch can meet (exact)


# ----------------------------------------------------------------------------- cameras

@dataclass
class FrameCamera:
    """The camera of one rendered frame: size (overscan border included), matrices."""

    width: int
    height: int
    border: int
    jitter: tuple[float, float]  # sample offset from the pixel centre, pixels
    position: np.ndarray
    world_to_camera: np.ndarray
    projection: np.ndarray  # without jitter
    tan_x: float
    tan_y: float

    @property
    def camera(self) -> Camera:
        """The camera of the rendered frame (overscan border included)."""
        return Camera(self.world_to_camera.copy(), self.projection.copy())

    @property
    def display_camera(self) -> Camera:
        """The camera of the display window (the frame without its overscan border)."""
        if not self.border:
            return self.camera
        P = self.projection.copy()
        P[0, 0] *= self.width / (self.width - 2 * self.border)
        P[1, 1] *= self.height / (self.height - 2 * self.border)
        return Camera(self.world_to_camera.copy(), P)


def _halton(i: int, base: int) -> float:
    f, r = 1.0, 0.0
    while i > 0:
        f /= base
        r += f * (i % base)
        i //= base
    return r


def frame_camera(scene: Scene, t: float, role: str = "gt") -> FrameCamera:
    """Camera of the frame rendered at time t (input-frame units).

    role 'input' applies the `jitter` effect (lower resolution, Halton(2,3) sub-pixel offset
    per input frame) and the `overscan` border; role 'gt' renders the nominal frame.
    """
    W, H = scene.width, scene.height
    jit, border = (0.0, 0.0), 0
    if role == "input":
        if scene.has("jitter"):
            W = max(1, int(round(W * scene.jitter_scale)))
            H = max(1, int(round(H * scene.jitter_scale)))
            k = int(math.floor(t + 0.5)) % 16 + 1
            jit = (_halton(k, 2) - 0.5, _halton(k, 3) - 0.5)
        if scene.has("overscan"):
            border = scene.overscan
    pos, tgt = scene.camera.at(scene.seconds(t))
    ty = math.tan(math.radians(scene.camera.fov) / 2)
    tx = ty * W / H
    tx *= (W + 2 * border) / W
    ty *= (H + 2 * border) / H
    proj = perspective(tx, ty, scene.camera.near, scene.camera.far)
    return FrameCamera(W + 2 * border, H + 2 * border, border, jit, pos, look_at(pos, tgt),
                       proj, tx, ty)


# ----------------------------------------------------------------------------- vectors

def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _add_scaled(a, b, s):
    return (a[0] + b[0] * s, a[1] + b[1] * s, a[2] + b[2] * s)


def _rot(R, v):
    """R (3x3 nested list) @ v."""
    return tuple(R[i][0] * v[0] + R[i][1] * v[1] + R[i][2] * v[2] for i in range(3))


def _rot_t(R, v):
    """R^T @ v."""
    return tuple(R[0][i] * v[0] + R[1][i] * v[1] + R[2][i] * v[2] for i in range(3))


def _normalize(v):
    inv = torch.rsqrt(torch.clamp(_dot(v, v), min=1e-30))
    return (v[0] * inv, v[1] * inv, v[2] * inv)


def _take(v, sel):
    return tuple(c[sel] if isinstance(c, torch.Tensor) else c for c in v)


class _Xf:
    """An object's transform at one time: x_world = R @ x_local + T."""

    __slots__ = ("R", "T")

    def __init__(self, R: np.ndarray, T: np.ndarray):
        self.R = [[float(x) for x in row] for row in R]
        self.T = tuple(float(x) for x in T)

    def to_local(self, o, d):
        return _rot_t(self.R, _sub(o, self.T)), _rot_t(self.R, d)

    def to_world(self, p):
        q = _rot(self.R, p)
        return (q[0] + self.T[0], q[1] + self.T[1], q[2] + self.T[2])


def _transforms(scene: Scene, t: float) -> list[_Xf]:
    s = scene.seconds(t)
    return [_Xf(*o.motion.at(s)) for o in scene.objects]


# ----------------------------------------------------------------------------- primitives

def _isect(ob, o, d, tmin: float) -> torch.Tensor:
    """Ray parameter of the first hit > tmin in local space (inf for a miss). d: tensors."""
    if ob.shape == "sphere":
        r = ob.radius
        a = _dot(d, d)
        b = _dot(o, d)
        c = _dot(o, o) - r * r
        disc = b * b - a * c
        sq = torch.sqrt(torch.clamp(disc, min=0.0))
        inv_a = 1.0 / a
        t0 = (-b - sq) * inv_a
        t1 = (-b + sq) * inv_a
        t = torch.where(t0 > tmin, t0, t1)
        return torch.where((disc >= 0) & (t > tmin), t, INF)
    if ob.shape == "plane":
        t = -o[1] / d[1]
        ok = t > tmin
        hx, hz = float(ob.half[0]), float(ob.half[2])
        if math.isfinite(hx):
            ok = ok & (torch.abs(o[0] + t * d[0]) <= hx) & (torch.abs(o[2] + t * d[2]) <= hz)
        return torch.where(ok, t, INF)
    if ob.shape == "box":
        tn = tf = None
        for i in range(3):
            h = float(ob.half[i])
            inv = 1.0 / d[i]
            t1 = (-h - o[i]) * inv
            t2 = (h - o[i]) * inv
            lo, hi = torch.fmin(t1, t2), torch.fmax(t1, t2)
            tn = lo if tn is None else torch.fmax(tn, lo)
            tf = hi if tf is None else torch.fmin(tf, hi)
        t = torch.where(tn > tmin, tn, tf)
        return torch.where((tf >= tn) & (tf > tmin), t, INF)
    if ob.shape == "cylinder":
        r, hh = ob.radius, ob.half_height
        a = d[0] * d[0] + d[2] * d[2]
        b = o[0] * d[0] + o[2] * d[2]
        c = o[0] * o[0] + o[2] * o[2] - r * r
        disc = b * b - a * c
        sq = torch.sqrt(torch.clamp(disc, min=0.0))
        inv_a = 1.0 / torch.clamp(a, min=1e-30)
        best = None
        for sgn in (-1.0, 1.0):
            ts = (-b + sgn * sq) * inv_a
            y = o[1] + ts * d[1]
            ok = (disc >= 0) & (a > 1e-30) & (ts > tmin) & (torch.abs(y) <= hh)
            ts = torch.where(ok, ts, INF)
            best = ts if best is None else torch.fmin(best, ts)
        for cap in (-hh, hh):
            tc = (cap - o[1]) / d[1]
            x, z = o[0] + tc * d[0], o[2] + tc * d[2]
            ok = (tc > tmin) & (x * x + z * z <= r * r)
            best = torch.fmin(best, torch.where(ok, tc, INF))
        return best
    raise ValueError(ob.shape)  # pragma: no cover


def _surface_local(ob, p):
    """Local normal (3 tensors) and surface coordinates (u, v) at local hit points p."""
    x, y, z = p
    one, zero = torch.ones_like(x), torch.zeros_like(x)
    if ob.shape == "plane":
        return (zero, one, zero), (x, z)
    if ob.shape == "sphere":
        r = ob.radius
        n = _normalize(p)  # not p / r: grazing hits land slightly off the sphere in float32
        u = torch.atan2(x, z) * r
        v = torch.asin(torch.clamp(n[1], -1.0, 1.0)) * r
        return n, (u, v)
    if ob.shape == "box":
        hx, hy, hz = (float(h) for h in ob.half)
        ax, ay, az = torch.abs(x) / hx, torch.abs(y) / hy, torch.abs(z) / hz
        fx = (ax >= ay) & (ax >= az)
        fy = ~fx & (ay >= az)
        fz = ~fx & ~fy
        n = (torch.where(fx, torch.sign(x), zero), torch.where(fy, torch.sign(y), zero),
             torch.where(fz, torch.sign(z), zero))
        u = torch.where(fx, z, x)
        v = torch.where(fy, z, y)
        return n, (u, v)
    if ob.shape == "cylinder":
        r, hh = ob.radius, ob.half_height
        rho = torch.sqrt(x * x + z * z)
        cap = torch.abs(torch.abs(y) - hh) < torch.abs(rho - r)
        inv = 1.0 / torch.clamp(rho, min=1e-12)
        n = (torch.where(cap, zero, x * inv), torch.where(cap, torch.sign(y), zero),
             torch.where(cap, zero, z * inv))
        u = torch.where(cap, x, torch.atan2(x, z) * r)
        v = torch.where(cap, z, y)
        return n, (u, v)
    raise ValueError(ob.shape)  # pragma: no cover


# ----------------------------------------------------------------------------- tracing

def _count(scene: Scene, key: str, n: int) -> None:
    scene.stats[key] = scene.stats.get(key, 0) + int(n)


def _nearest(scene: Scene, ids: list[int], xf: list[_Xf], o, d, n: int, tmin: float = 0.0):
    """Nearest hit among objects `ids`: (t, object id; -1 = none)."""
    best = torch.full((n,), INF)
    who = torch.full((n,), -1, dtype=torch.int64)
    for k in ids:
        ol, dl = xf[k].to_local(o, d)
        t = _isect(scene.objects[k], ol, dl, tmin)
        closer = t < best
        best = torch.where(closer, t, best)
        who = torch.where(closer, k, who)
        _count(scene, "primitive_tests", n)
    return best, who


def _occluded(scene: Scene, ids: list[int], xf: list[_Xf], o, d, tmax, n: int):
    """Any hit in (tmin, tmax) among objects `ids` (bool (n,)).

    Rays that pass farther from an object's bounding sphere than its radius (or are blocked
    already) skip its primitive test: a conservative test with a margin, so the answer is
    the same as testing every ray (counted as bound_tests)."""
    blocked = torch.zeros(n, dtype=torch.bool)
    dd = None
    for k in ids:
        ob = scene.objects[k]
        sel = None
        if CULL and math.isfinite(ob.bound):
            if dd is None:
                dd = _dot(d, d)
            oc = _sub(xf[k].T, o)
            b = _dot(oc, d)
            r2 = (ob.bound * 1.001 + 1e-4) ** 2
            near = (_dot(oc, oc) * dd - b * b <= r2 * dd) & ~blocked
            _count(scene, "bound_tests", n)
            sel = torch.nonzero(near).squeeze(1)
            if sel.numel() == 0:
                continue
            if sel.numel() > n // 2:  # most rays pass: gathering them costs more than it saves
                sel = None
        if sel is None:
            ol, dl = xf[k].to_local(o, d)
            blocked |= _isect(ob, ol, dl, 1e-5) < tmax
            _count(scene, "primitive_tests", n)
        else:
            ol, dl = xf[k].to_local(_take(o, sel), _take(d, sel))
            tm = tmax[sel] if isinstance(tmax, torch.Tensor) else tmax
            hit = _isect(ob, ol, dl, 1e-5) < tm
            blocked.index_put_((sel,), blocked[sel] | hit)
            _count(scene, "primitive_tests", sel.numel())
    return blocked


def _band_objects(scene: Scene, ids: list[int], xf: list[_Xf], fc: FrameCamera,
                  y0: int, y1: int) -> list[int]:
    """Objects whose bounding sphere can meet a camera ray through pixel rows [y0, y1).

    Each test is exact for the sphere against the four planes (through the eye) that bound
    the band of rays, so culling never changes the image, only the work.
    """
    if not CULL:
        return ids
    V = fc.world_to_camera
    b_hi = (1.0 - 2.0 * (y0 - 1.0) / fc.height) * fc.tan_y  # one pixel margin for jitter
    b_lo = (1.0 - 2.0 * (y1 + 1.0) / fc.height) * fc.tan_y
    a_hi = fc.tan_x * (1.0 + 2.0 / fc.width)
    out = []
    for k in ids:
        r = scene.objects[k].bound
        if not math.isfinite(r):
            out.append(k)
            continue
        cx, cy, cz = V[:3, :3] @ np.asarray(xf[k].T) + V[:3, 3]
        if ((cy + b_hi * cz) / math.hypot(1.0, b_hi) > r
                or (-cy - b_lo * cz) / math.hypot(1.0, b_lo) > r
                or (cx + a_hi * cz) / math.hypot(1.0, a_hi) > r
                or (-cx + a_hi * cz) / math.hypot(1.0, a_hi) > r
                or cz > r):
            continue
        out.append(k)
    return out


def _segment_objects(scene: Scene, ids: list[int], xf: list[_Xf], org, Ld, light) -> list[int]:
    """Objects whose bounding sphere can block some of the shadow rays from points `org`:
    toward the point light at `light`, or along the direction Ld (directional: light None)."""
    if not CULL:
        return ids
    cand = [k for k in ids if math.isfinite(scene.objects[k].bound)]
    out = [k for k in ids if k not in cand]
    if not cand:
        return out
    if light is not None:  # every segment lies in the box around the points and the light
        lo = [min(float(org[i].min()), light[i]) for i in range(3)]
        hi = [max(float(org[i].max()), light[i]) for i in range(3)]
        for k in cand:
            c, r = xf[k].T, scene.objects[k].bound
            d2 = sum(max(lo[i] - c[i], 0.0, c[i] - hi[i]) ** 2 for i in range(3))
            if d2 <= r * r:
                out.append(k)
        return sorted(out)
    L = np.asarray([float(Ld[i][0]) for i in range(3)])
    e1 = np.cross(L, [0.0, 1.0, 0.0] if abs(L[1]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(L, e1)
    proj = [_dot(org, tuple(float(x) for x in e)) for e in (e1, e2, L)]
    lo = [float(p.min()) for p in proj]
    hi = [float(p.max()) for p in proj]
    for k in cand:
        c, r = np.asarray(xf[k].T), scene.objects[k].bound
        cu, cv, cs = c @ e1, c @ e2, c @ L
        # the rays leave the points along +L: the sphere must overlap their footprint
        # across L and not lie wholly behind all of them
        if (cu + r >= lo[0] and cu - r <= hi[0] and cv + r >= lo[1] and cv - r <= hi[1]
                and cs + r >= lo[2]):
            out.append(k)
    return sorted(out)


@dataclass
class _Hits:
    """Surface attributes of a set of rays (zeros where nothing was hit)."""

    P: tuple  # world position
    n: tuple  # world normal, facing the ray
    albedo: tuple
    rough: torch.Tensor
    spec: torch.Tensor
    mirror: torch.Tensor
    opacity: torch.Tensor
    plocal: tuple  # hit point in object space (for motion vectors)


def _surfaces(scene: Scene, xf: list[_Xf], o, d, t, who, seconds: float, n: int,
              pix: float, t0=None) -> _Hits:
    """pix: pixel size at unit distance (texture filter width); t0: distance already
    travelled by the ray before its origin (secondary rays)."""
    z = lambda: torch.zeros(n)  # noqa: E731
    P = [z(), z(), z()]
    N = [z(), z(), z()]
    A = [z(), z(), z()]
    L = [z(), z(), z()]
    rough, spec, mirror, opac = z(), z(), z(), torch.ones(n)
    scroll = scene.has("texture_animation")
    for k, ob in enumerate(scene.objects):
        sel = torch.nonzero(who == k).squeeze(1)
        if sel.numel() == 0:
            continue
        ok, dk = _take(o, sel), _take(d, sel)
        tk = t[sel]
        ol, dl = xf[k].to_local(ok, dk)
        pl = _add_scaled(ol, dl, tk)
        nl, (u, v) = _surface_local(ob, pl)
        nw = _rot(xf[k].R, nl)
        # the pixel's footprint on the surface: distance x pixel angle / cos(incidence)
        dd = _dot(dk, dk)
        cos = torch.abs(_dot(nl, dl)) * torch.rsqrt(dd)
        dist = tk * torch.sqrt(dd)
        if t0 is not None:
            dist = dist + t0[sel]
        fp = dist * (FILTER * pix) / torch.clamp(cos, min=0.3)
        alb = textures.evaluate(ob.texture, u, v, seconds, scroll, fp)
        pw = _add_scaled(ok, dk, tk)
        for i in range(3):
            P[i][sel] = pw[i] if isinstance(pw[i], torch.Tensor) else torch.full_like(tk, pw[i])
            N[i][sel] = nw[i]
            A[i][sel] = alb[i]
            L[i][sel] = pl[i]
        rough[sel] = ob.roughness
        spec[sel] = ob.specular
        mirror[sel] = ob.mirror
        opac[sel] = ob.opacity
    # face the viewer (planes are two-sided; the inside of a closed shape faces in)
    back = _dot(N, d) > 0
    N = tuple(torch.where(back, -c, c) for c in N)
    return _Hits(tuple(P), N, tuple(A), rough, spec, mirror, opac, tuple(L))


def _sky(scene: Scene, d):
    dn = _normalize(d)
    y = dn[1]
    up = torch.clamp(y, 0.0, 1.0) ** 0.6
    dn_ = torch.clamp(-y, 0.0, 1.0) ** 0.4
    out = []
    for i in range(3):
        h, zt, g = (float(scene.sky_horizon[i]), float(scene.sky_zenith[i]),
                    float(scene.sky_ground[i]))
        out.append(h + (zt - h) * up + (g - h) * dn_)
    return out


def _lights_at(scene: Scene, t: float):
    s = scene.seconds(t)
    out = []
    for L in scene.lights:
        R, T = L.motion.at(s)
        col = [float(c) for c in L.color]
        if L.kind == "directional":
            toward = -(R @ L.direction)
            out.append(("directional", col, tuple(float(x) for x in toward)))
        else:
            out.append(("point", col, tuple(float(x) for x in T)))
    return out


def _toward(kind: str, v, P, m: int):
    """Unit direction toward a light, distance (None: directional), 1/d^2 falloff (or None)."""
    if kind == "directional":
        return tuple(torch.full((m,), c) for c in v), None, None
    Lv = _sub(v, P)
    d2 = torch.clamp(_dot(Lv, Lv), min=1e-12)
    dist = torch.sqrt(d2)
    return (Lv[0] / dist, Lv[1] / dist, Lv[2] / dist), dist, 1.0 / d2


def _blocked(scene: Scene, xf, P, n, Ld, dist, sel, light, counter: str = "shadow_rays"):
    """Shadow rays from the points P[sel] (offset along n) toward Ld: bool per ray of sel.
    light: the point light's position (None: directional)."""
    casters = [k for k in scene.opaque if scene.objects[k].shadow]
    Ps, ns = _take(P, sel), _take(n, sel)
    # offset the origin along the normal, relative to the distance from the world origin
    eps = 2e-4 * (1.0 + torch.sqrt(_dot(Ps, Ps)))
    org = _add_scaled(Ps, ns, eps)
    Ls = _take(Ld, sel)
    tmax = INF if dist is None else dist[sel]
    _count(scene, counter, sel.numel())
    casters = _segment_objects(scene, casters, xf, org, Ls, light)
    return _occluded(scene, casters, xf, org, Ls, tmax, sel.numel())


def _shade(scene: Scene, lights, xf, h: _Hits, d, m: int, shadows: bool, specular: bool):
    """Direct lighting of m hit points: ambient + diffuse (+ shadows) (+ specular)."""
    amb = 0.65 + 0.35 * h.n[1]
    col = [h.albedo[i] * (float(scene.ambient[i]) * amb) for i in range(3)]
    V = None
    for kind, lcol, v in lights:
        Ld, dist, fall = _toward(kind, v, h.P, m)
        ndl = torch.clamp(_dot(h.n, Ld), min=0.0)
        w = ndl if fall is None else ndl * fall
        if shadows:
            sel = torch.nonzero(ndl > 0).squeeze(1)
            if sel.numel():
                blocked = _blocked(scene, xf, h.P, h.n, Ld, dist, sel,
                                   None if kind == "directional" else v)
                w = w.index_put((sel,), torch.where(blocked, 0.0, w[sel]))
        for i in range(3):
            col[i] = col[i] + h.albedo[i] * (w * lcol[i])
        if specular:
            if V is None:
                V = _normalize((-d[0], -d[1], -d[2]))
                shin = torch.clamp(2.0 / (h.rough * h.rough) - 2.0, min=1.0)
                norm = (shin + 8.0) * (1.0 / (8.0 * math.pi)) * h.spec
            Hv = _normalize(_add_scaled(Ld, V, 1.0))
            sp = torch.clamp(_dot(h.n, Hv), min=0.0) ** shin * norm * w
            for i in range(3):
                col[i] = col[i] + sp * lcol[i]
    return col


def _lit(scene: Scene, lights, xf, P, n, m: int) -> list[torch.Tensor]:
    """Per light: does it reach the points P (facing it, and not shadowed when the scene
    has shadows)? Analysis only (counted as analysis_rays)."""
    out = []
    for kind, _, v in lights:
        Ld, dist, _ = _toward(kind, v, P, m)
        vis = _dot(n, Ld) > 0
        if scene.has("shadows"):
            sel = torch.nonzero(vis).squeeze(1)
            if sel.numel():
                lp = None if kind == "directional" else v
                vis = vis.index_put((sel,), ~_blocked(scene, xf, P, n, Ld, dist, sel, lp,
                                                      "analysis_rays"))
        out.append(vis)
    return out


def _trace_shade(scene, lights, xf, o, d, n: int, seconds: float, ids: list[int], pix, t0):
    """A secondary ray: nearest hit among ids, shaded with ambient + diffuse; sky if none."""
    t, who = _nearest(scene, ids, xf, o, d, n, tmin=1e-5)
    hit = who >= 0
    sky = _sky(scene, d)
    if not bool(hit.any()):
        return sky
    h = _surfaces(scene, xf, o, d, t, who, seconds, n, pix, t0)
    col = _shade(scene, lights, xf, h, d, n, shadows=False, specular=False)
    return [torch.where(hit, col[i], sky[i]) for i in range(3)]


# ----------------------------------------------------------------------------- render

def _sample_offsets(spp: int):
    """Regular spp x spp grid of sub-pixel offsets; index of the pixel-centre sample
    (appended, with no weight in the color, when spp is even)."""
    g = [(i + 0.5) / spp - 0.5 for i in range(spp)]
    offs = [(gx, gy) for gy in g for gx in g]
    if spp % 2 == 1:
        return offs, len(offs), (spp // 2) * spp + spp // 2
    return offs + [(0.0, 0.0)], len(offs), len(offs)


def _camera_rays(fc: FrameCamera, px: torch.Tensor, py: torch.Tensor):
    """World ray directions through pixel positions (px, py) (not unit: view depth = t)."""
    a = (px * (2.0 / fc.width) - 1.0) * fc.tan_x
    b = (1.0 - py * (2.0 / fc.height)) * fc.tan_y
    C = fc.world_to_camera[:3, :3].T.tolist()  # camera-to-world rotation
    return tuple(C[i][0] * a + C[i][1] * b - C[i][2] for i in range(3))


def _project(M, p, w_in: float = 1.0):
    """Clip-space x, y, w of world points p under the 4x4 M (nested list)."""
    cx = M[0][0] * p[0] + M[0][1] * p[1] + M[0][2] * p[2] + M[0][3] * w_in
    cy = M[1][0] * p[0] + M[1][1] * p[1] + M[1][2] * p[2] + M[1][3] * w_in
    cw = M[3][0] * p[0] + M[3][1] * p[1] + M[3][2] * p[2] + M[3][3] * w_in
    return cx, cy, cw


def render(scene: Scene, t: float, prev_t: float | None = None, spp: int | None = None,
           role: str = "gt", number: int | None = None, extras: dict | None = None) -> Frame:
    """Render the buffers of `scene` at time t (input-frame units; may be fractional).

    prev_t: the time the motion vectors point to (None: zero vectors). role: 'input'
    applies jitter/overscan (see frame_camera), 'gt' renders the nominal frame.
    extras: when a dict is given it receives (H, W) tensors object_id (int, -1 sky), edge
    (bool: the pixel's samples see more than one object), and when prev_t is given
    prev_depth (view depth of the pixel's surface point at prev_t), disoccluded (bool:
    that point is hidden or off-screen at prev_t) and light_changed (bool: a light started
    or stopped reaching that point: a shadow or the terminator moved over it). Computed at
    the pixel-centre sample; costs about one extra ray per pixel and light.
    Work done is added to scene.stats.
    """
    spp = spp or scene.spp
    if role == "input" and scene.has("jitter"):
        spp = scene.jitter_spp  # the jittered low-resolution frame of a real-time renderer
    with torch.inference_mode():
        return _render(scene, float(t), None if prev_t is None else float(prev_t),
                       spp, role, number, extras)


@dataclass
class _At:
    """Everything evaluated at one time: camera, object transforms, lights."""

    t: float
    fc: FrameCamera
    xf: list
    lights: list
    clip: list  # projection @ world_to_camera (nested list)

    @classmethod
    def of(cls, scene: Scene, t: float, role: str) -> "_At":
        fc = frame_camera(scene, t, role)
        return cls(t, fc, _transforms(scene, t), _lights_at(scene, t),
                   (fc.projection @ fc.world_to_camera).tolist())

    @property
    def origin(self):
        return tuple(float(x) for x in self.fc.position)


def _box_filter(x: torch.Tensor, M: int, n: int) -> torch.Tensor:
    """Mean of the first n blocks of M values (fixed order, so the same bits every time)."""
    acc = x[0:M].clone()
    for s in range(1, n):
        acc += x[s * M:(s + 1) * M]
    return acc * (1.0 / n)


def _color(scene: Scene, now: _At, d, tt, who, h: _Hits, pix: float, y0: int, y1: int):
    """Shaded color of every camera ray: surfaces (+ one mirror bounce), sky, then the
    translucent layer on top."""
    n = tt.numel()
    hit = who >= 0
    col = _sky(scene, d)
    hsel = torch.nonzero(hit).squeeze(1)
    if hsel.numel():
        hh = _Hits(*(_take(v, hsel) if isinstance(v, tuple) else v[hsel]
                     for v in (getattr(h, f) for f in _Hits.__dataclass_fields__)))
        dh = _take(d, hsel)
        c = _shade(scene, now.lights, now.xf, hh, dh, hsel.numel(), scene.has("shadows"),
                   scene.has("specular"))
        if scene.has("reflection"):
            msel = torch.nonzero(hh.mirror > 0).squeeze(1)
            if msel.numel():
                dm = _take(dh, msel)
                travelled = tt[hsel][msel] * torch.sqrt(_dot(dm, dm))
                dm = _normalize(dm)
                nm, Pm = _take(hh.n, msel), _take(hh.P, msel)
                r = _add_scaled(dm, nm, -2.0 * _dot(dm, nm))
                org = _add_scaled(Pm, nm, 2e-4 * (1.0 + torch.sqrt(_dot(Pm, Pm))))
                _count(scene, "reflection_rays", msel.numel())
                rc = _trace_shade(scene, now.lights, now.xf, org, r, msel.numel(),
                                  scene.seconds(now.t), scene.opaque, pix, travelled)
                mm = hh.mirror[msel]
                for i in range(3):
                    c[i] = c[i].index_put((msel,), c[i][msel] * (1.0 - mm) + rc[i] * mm)
        for i in range(3):
            col[i] = col[i].index_put((hsel,), c[i])
    transl = scene.translucent
    if transl:
        _count(scene, "translucent_rays", n)
        t2, who2 = _nearest(scene, _band_objects(scene, transl, now.xf, now.fc, y0, y1),
                            now.xf, now.origin, d, n)
        tsel = torch.nonzero(t2 < tt).squeeze(1)
        if tsel.numel():
            d2 = _take(d, tsel)
            h2 = _surfaces(scene, now.xf, now.origin, d2, t2[tsel], who2[tsel],
                           scene.seconds(now.t), tsel.numel(), pix)
            c2 = _shade(scene, now.lights, now.xf, h2, d2, tsel.numel(), False,
                        scene.has("specular"))
            a = h2.opacity
            for i in range(3):
                col[i] = col[i].index_put((tsel,), col[i][tsel] * (1.0 - a) + c2[i] * a)
    return col


def _reproject(scene: Scene, now: _At, then: _At, d, wc, h: _Hits, cs, M: int):
    """Where the surface points seen by the pixel-centre rays were at the previous time:
    clip-space x, y, w in the previous camera, their view depth there, and (for analysis)
    their world position and normal then. Sky rays are directions: camera rotation only."""
    qx, qy, qw = torch.zeros(M), torch.zeros(M), torch.ones(M)
    pd = torch.full((M,), INF)
    Pp = [torch.zeros(M) for _ in range(3)]
    Np = [torch.zeros(M) for _ in range(3)]
    pl, nc = _take(h.plocal, cs), _take(h.n, cs)
    zrow = then.fc.world_to_camera[2].tolist()
    for k in range(len(scene.objects)):
        sel = torch.nonzero(wc == k).squeeze(1)
        if sel.numel() == 0:
            continue
        P = then.xf[k].to_world(_take(pl, sel))
        qx[sel], qy[sel], qw[sel] = _project(then.clip, P)
        pd[sel] = -(zrow[0] * P[0] + zrow[1] * P[1] + zrow[2] * P[2] + zrow[3])
        nk = _rot(then.xf[k].R, _rot_t(now.xf[k].R, _take(nc, sel)))
        for i in range(3):
            Pp[i][sel], Np[i][sel] = P[i], nk[i]
    ssel = torch.nonzero(wc < 0).squeeze(1)
    if ssel.numel():
        qx[ssel], qy[ssel], qw[ssel] = _project(then.clip, _take(_take(d, cs), ssel), 0.0)
    return qx, qy, qw, pd, Pp, Np


def _analysis(scene: Scene, now: _At, then: _At, h: _Hits, cs, wc, qx, qy, front, pd, Pp, Np,
              M: int):
    """disoccluded: the surface point is hidden or off-screen at the previous time (traced
    from the previous camera through its position there); light_changed: a light started
    or stopped reaching it."""
    fcp = then.fc
    dp = _camera_rays(fcp, qx, qy)
    _count(scene, "disocclusion_rays", M)
    tp, wp = _nearest(scene, scene.opaque, then.xf, then.origin, dp, M)
    same = (wp == wc) & ((wc < 0) | (torch.abs(tp - pd) <= 1e-3 * pd + 1e-4))
    onscreen = front & (qx >= 0) & (qx < fcp.width) & (qy >= 0) & (qy < fcp.height)
    changed = torch.zeros(M, dtype=torch.bool)
    hs = torch.nonzero(wc >= 0).squeeze(1)
    if hs.numel() and now.lights:
        m = hs.numel()
        lit_now = _lit(scene, now.lights, now.xf, _take(_take(h.P, cs), hs),
                       _take(_take(h.n, cs), hs), m)
        lit_then = _lit(scene, then.lights, then.xf, _take(Pp, hs), _take(Np, hs), m)
        ch = torch.zeros(m, dtype=torch.bool)
        for a, b in zip(lit_now, lit_then):
            ch |= a != b
        changed[hs] = ch
    return ~(same & onscreen), changed


def _render(scene, t, prev_t, spp, role, number, extras):
    now = _At.of(scene, t, role)
    then = None if prev_t is None else _At.of(scene, prev_t, role)
    fc = now.fc
    W, H = fc.width, fc.height
    offs, n_color, centre = _sample_offsets(spp)
    S, HW = len(offs), H * W
    buf = {"color": torch.zeros(3, HW), "alpha": torch.zeros(1, HW),
           "depth": torch.full((1, HW), INF), "mv": torch.zeros(2, HW),
           "normal": torch.zeros(3, HW), "albedo": torch.zeros(3, HW),
           "roughness": torch.ones(1, HW)}
    want = extras is not None
    ex = {"object_id": torch.full((HW,), -1, dtype=torch.int64),
          "edge": torch.zeros(HW, dtype=torch.bool), "prev_depth": torch.full((HW,), INF),
          "disoccluded": torch.zeros(HW, dtype=torch.bool),
          "light_changed": torch.zeros(HW, dtype=torch.bool)} if want else {}
    rows = max(1, MAX_RAYS // (S * W))
    xs = torch.arange(W, dtype=torch.float32) + (0.5 + fc.jitter[0])
    pix = 2.0 * fc.tan_y / fc.height  # pixel size at unit distance
    for y0 in range(0, H, rows):
        y1 = min(H, y0 + rows)
        M = (y1 - y0) * W
        n = S * M
        ys = torch.arange(y0, y1, dtype=torch.float32) + (0.5 + fc.jitter[1])
        px = torch.cat([(xs[None, :] + ox).expand(y1 - y0, W).reshape(-1) for ox, _ in offs])
        py = torch.cat([(ys[:, None] + oy).expand(y1 - y0, W).reshape(-1) for _, oy in offs])
        d = _camera_rays(fc, px, py)
        _count(scene, "primary_rays", n)
        tt, who = _nearest(scene, _band_objects(scene, scene.opaque, now.xf, fc, y0, y1),
                           now.xf, now.origin, d, n)
        h = _surfaces(scene, now.xf, now.origin, d, tt, who, scene.seconds(t), n, pix)
        col = _color(scene, now, d, tt, who, h, pix, y0, y1)
        # resolve: box filter over the color samples, G-buffer from the pixel-centre sample
        sl = slice(y0 * W, y1 * W)
        cs = slice(centre * M, (centre + 1) * M)
        for i in range(3):
            buf["color"][i, sl] = _box_filter(col[i], M, n_color) * float(scene.exposure)
        buf["alpha"][0, sl] = _box_filter((who >= 0).to(torch.float32), M, n_color)
        tc, wc = tt[cs], who[cs]
        buf["depth"][0, sl] = tc
        for i in range(3):
            buf["normal"][i, sl] = h.n[i][cs]
            buf["albedo"][i, sl] = h.albedo[i][cs]
        buf["roughness"][0, sl] = torch.where(wc >= 0, h.rough[cs], 1.0)
        if then is not None:
            qx, qy, qw, pd, Pp, Np = _reproject(scene, now, then, d, wc, h, cs, M)
            front = qw > 1e-9
            inv = 1.0 / torch.clamp(qw, min=1e-9)
            qx = (qx * inv + 1.0) * (0.5 * then.fc.width)
            qy = (1.0 - qy * inv) * (0.5 * then.fc.height)
            lim = 4.0 * (W + H)  # points behind the previous camera: far off-screen, finite
            buf["mv"][0, sl] = torch.clamp(qx - px[cs], -lim, lim)
            buf["mv"][1, sl] = torch.clamp(qy - py[cs], -lim, lim)
            if want:
                ex["prev_depth"][sl] = pd
                ex["disoccluded"][sl], ex["light_changed"][sl] = _analysis(
                    scene, now, then, h, cs, wc, qx, qy, front, pd, Pp, Np, M)
        if want:
            ex["object_id"][sl] = wc
            e = torch.zeros(M, dtype=torch.bool)
            for s in range(n_color):
                e |= who[s * M:(s + 1) * M] != wc
            ex["edge"][sl] = e
    out = {k: v.reshape(v.shape[0], H, W) for k, v in buf.items()}
    if scene.has("particles"):
        _particles(scene, out["color"], fc, scene.seconds(t))
    if scene.has("hud"):
        _hud(scene, out["color"], fc)
    frame = Frame(number=int(math.floor(t + 0.5)) if number is None else number,
                  camera=fc.camera, header={}, time=t, **out)
    if want:
        extras.update({k: v.reshape(H, W) for k, v in ex.items()
                       if then is not None or k in ("object_id", "edge")})
        extras["camera"] = fc
    return frame


# ----------------------------------------------------------------------------- overlays

def _particles(scene: Scene, color: torch.Tensor, fc: FrameCamera, seconds: float) -> None:
    """Additive screen-space sprites (no depth, no motion vectors): sparks, snow, dust."""
    p = scene.particles
    cnt = p["count"]
    if cnt == 0:
        return
    rng = np.random.default_rng(p["seed"])
    start = rng.random((cnt, 2))
    vel = np.asarray(p["velocity"])[None, :] + p["spread"] * rng.standard_normal((cnt, 2))
    gain = 0.5 + 0.5 * rng.random(cnt)
    _, H, W = color.shape
    sig = max(p["size"] * H, 0.3)
    rad = int(math.ceil(3 * sig))
    for i in range(cnt):
        x = (start[i, 0] * W + vel[i, 0] * H * seconds) % W
        y = (start[i, 1] * H + vel[i, 1] * H * seconds) % H
        for ox in (-W, 0, W):
            for oy in (-H, 0, H):
                cx, cy = x + ox, y + oy
                x0, x1 = max(0, int(cx) - rad), min(W, int(cx) + rad + 1)
                y0, y1 = max(0, int(cy) - rad), min(H, int(cy) + rad + 1)
                if x0 >= x1 or y0 >= y1:
                    continue
                gx = torch.arange(x0, x1, dtype=torch.float32) + 0.5 - float(cx)
                gy = torch.arange(y0, y1, dtype=torch.float32) + 0.5 - float(cy)
                g = torch.exp(-(gy[:, None] ** 2 + gx[None, :] ** 2) * (0.5 / (sig * sig)))
                for c in range(3):
                    k = float(p["color"][c] * p["intensity"] * gain[i])
                    color[c, y0:y1, x0:x1] += g * k


DEFAULT_HUD = [  # (x, y, w, h) as fractions of the frame, color, opacity
    ((0.04, 0.88, 0.30, 0.05), (0.05, 0.05, 0.05), 0.6),
    ((0.045, 0.895, 0.21, 0.03), (0.2, 0.9, 0.25), 0.9),
    ((0.78, 0.05, 0.18, 0.25), (0.02, 0.03, 0.05), 0.55),
    ((0.49, 0.495, 0.02, 0.01), (1.0, 1.0, 1.0), 0.8),
    ((0.4975, 0.48, 0.005, 0.04), (1.0, 1.0, 1.0), 0.8),
]


def _hud(scene: Scene, color: torch.Tensor, fc: FrameCamera) -> None:
    """Static overlay composited over the nominal frame (no depth, no motion vectors);
    coverage is the exact area of each rectangle inside each pixel."""
    _, H, W = color.shape
    b = fc.border
    Wn, Hn = W - 2 * b, H - 2 * b
    els = scene.hud["elements"] or DEFAULT_HUD
    xs = torch.arange(W, dtype=torch.float32)
    ys = torch.arange(H, dtype=torch.float32)
    for rect, col, op in els:
        x0, y0 = b + rect[0] * Wn, b + rect[1] * Hn
        x1, y1 = x0 + rect[2] * Wn, y0 + rect[3] * Hn
        cx = torch.clamp(torch.clamp(xs + 1, max=x1) - torch.clamp(xs, min=x0), 0.0, 1.0)
        cy = torch.clamp(torch.clamp(ys + 1, max=y1) - torch.clamp(ys, min=y0), 0.0, 1.0)
        a = cy[:, None] * cx[None, :] * float(op)
        for c in range(3):
            color[c] = color[c] * (1.0 - a) + float(col[c]) * a
