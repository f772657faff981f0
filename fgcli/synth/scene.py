"""Scene files (TOML) -> validated Scene objects. The schema is documented in docs/synth.md.

Every error names the file and the key (`objects[2].motion.velocity: expected 3 numbers`).
Unknown keys are errors, so a typo never silently renders a different scene.
All times in scene files are seconds; the renderer's time unit is the input frame (t / fps).
"""
from __future__ import annotations

import copy
import hashlib
import json
import math
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fgcli.errors import InputError, UsageError
from fgcli.synth.motion import CameraPath, Motion, euler_deg

EFFECTS = ("shadows", "specular", "reflection", "translucency", "particles", "hud",
           "texture_animation", "overscan", "jitter")
SHAPES = ("plane", "box", "sphere", "cylinder", "blade")
TEXTURES = ("solid", "checker", "stripes", "noise", "bricks")
MOTIONS = ("static", "linear", "ballistic", "rotate", "keyframes")
CAMERAS = ("static", "orbit", "pan", "dolly", "keyframes")

_REQ = object()


class _Table:
    """Typed, path-aware access to one TOML table; `done()` rejects unknown keys."""

    def __init__(self, d: Any, where: str, file: str):
        self.where, self.file = where, file
        if not isinstance(d, dict):
            raise InputError(f"key '{where}': expected a table", file=file)
        self.d = d
        self.used: set[str] = set()

    def path(self, k: str) -> str:
        return f"{self.where}.{k}" if self.where else k

    def fail(self, k: str, msg: str):
        raise InputError(f"key '{self.path(k)}': {msg}", file=self.file)

    def has(self, k: str) -> bool:
        return k in self.d

    def raw(self, k: str, default=_REQ):
        self.used.add(k)
        if k not in self.d:
            if default is _REQ:
                self.fail(k, "missing")
            return default
        return self.d[k]

    def num(self, k, default=_REQ, lo=None, hi=None, integer=False):
        v = self.raw(k, default)
        if v is default and default is not _REQ:
            return v
        if isinstance(v, bool) or not isinstance(v, (int, float)) or (
                integer and not isinstance(v, int)):
            self.fail(k, f"expected {'an integer' if integer else 'a number'}, got {v!r}")
        if not math.isfinite(v):
            self.fail(k, "must be finite")
        if lo is not None and v < lo:
            self.fail(k, f"must be >= {lo}, got {v}")
        if hi is not None and v > hi:
            self.fail(k, f"must be <= {hi}, got {v}")
        return int(v) if integer else float(v)

    def vec(self, k, n=3, default=_REQ, lo=None, nonzero=False):
        v = self.raw(k, default)
        if v is default and default is not _REQ:
            return None if v is None else np.asarray(v, dtype=np.float64)
        if (not isinstance(v, list) or len(v) != n or any(
                isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x)
                for x in v)):
            self.fail(k, f"expected {n} numbers, got {v!r}")
        a = np.asarray(v, dtype=np.float64)
        if lo is not None and (a < lo).any():
            self.fail(k, f"values must be >= {lo}")
        if nonzero and not np.any(a):
            self.fail(k, "must not be the zero vector")
        return a

    def str(self, k, default=_REQ, choices=None):
        v = self.raw(k, default)
        if v is default and default is not _REQ:
            return v
        if not isinstance(v, str):
            self.fail(k, f"expected a string, got {v!r}")
        if choices and v not in choices:
            self.fail(k, f"unknown value '{v}' (known: {', '.join(choices)})")
        return v

    def bool(self, k, default=_REQ):
        v = self.raw(k, default)
        if not isinstance(v, bool):
            self.fail(k, f"expected true or false, got {v!r}")
        return v

    def table(self, k, default=_REQ):
        v = self.raw(k, default)
        if v is None:
            return None
        return _Table(v, self.path(k), self.file)

    def tables(self, k, default=_REQ) -> list["_Table"]:
        v = self.raw(k, default)
        if v is None:
            return []
        if not isinstance(v, list):
            self.fail(k, "expected an array of tables")
        return [_Table(x, f"{self.path(k)}[{i}]", self.file) for i, x in enumerate(v)]

    def done(self):
        extra = sorted(set(self.d) - self.used)
        if extra:
            self.fail(extra[0], f"unknown key (known here: {', '.join(sorted(self.used))})")


@dataclass
class Texture:
    kind: str = "solid"
    colors: np.ndarray = field(default_factory=lambda: np.array([[0.7, 0.7, 0.7], [0.3, 0.3, 0.3]]))
    scale: float = 1.0  # tile / stripe / brick / noise cell size in object units
    angle: float = 0.0  # stripes: degrees
    softness: float = 0.06  # edge width as a fraction of the tile (band-limits the texture)
    mortar: float = 0.08  # bricks: mortar width as a fraction of the brick height
    variation: float = 0.15  # bricks: per-brick brightness variation
    octaves: int = 3  # noise
    seed: int = 0
    scroll: np.ndarray = field(default_factory=lambda: np.zeros(2))  # uv units per second


@dataclass
class Object:
    name: str
    shape: str  # plane | box | sphere | cylinder (blade is a thin box)
    motion: Motion
    texture: Texture
    half: np.ndarray  # box half extents / plane half size (x, z; inf = infinite)
    radius: float = 0.5
    half_height: float = 0.5
    roughness: float = 0.5
    specular: float = 0.5
    mirror: float = 0.0
    opacity: float = 1.0
    shadow: bool = True
    bound: float = math.inf  # bounding-sphere radius about the object origin


@dataclass
class Light:
    kind: str  # directional | point
    color: np.ndarray  # color * intensity
    direction: np.ndarray  # directional: direction the light travels (unit)
    motion: Motion  # point: position = T(s); directional: direction = R(s) @ direction


@dataclass
class Scene:
    name: str
    source: str
    width: int
    height: int
    fps: float
    frames: int
    spp: int
    effects: frozenset
    camera: CameraPath
    objects: list[Object]
    lights: list[Light]
    sky_zenith: np.ndarray
    sky_horizon: np.ndarray
    sky_ground: np.ndarray
    ambient: np.ndarray
    exposure: float
    seed: int
    particles: dict
    hud: dict
    overscan: int
    jitter_scale: float
    jitter_spp: int
    spec: dict  # the scene as a plain dict (overrides applied), for hashing and copies
    hash: str
    stats: dict = field(default_factory=dict)

    def has(self, effect: str) -> bool:
        return effect in self.effects

    def reset_stats(self) -> None:
        self.stats.clear()

    def seconds(self, t: float) -> float:
        """Scene time in seconds for a time in input-frame units."""
        return float(t) / self.fps

    @property
    def opaque(self) -> list[int]:
        if not self.has("translucency"):
            return list(range(len(self.objects)))
        return [i for i, o in enumerate(self.objects) if o.opacity >= 1.0]

    @property
    def translucent(self) -> list[int]:
        if not self.has("translucency"):
            return []
        return [i for i, o in enumerate(self.objects) if o.opacity < 1.0]

    def object_index(self, name: str) -> int:
        for i, o in enumerate(self.objects):
            if o.name == name:
                return i
        raise KeyError(name)

    def object_center(self, name: str, t: float) -> np.ndarray:
        """World position of an object's origin at time t (input-frame units)."""
        return self.objects[self.object_index(name)].motion.at(self.seconds(t))[1]

    def project(self, point, t: float, role: str = "gt") -> np.ndarray:
        """Pixel position (x right, y down) of a world point in the frame rendered at t."""
        from fgcli.io.cameras import project
        from fgcli.synth.tracer import frame_camera

        fc = frame_camera(self, t, role)
        return project(fc.camera, np.asarray(point, float)[None], fc.width, fc.height)[0, :2]


def _texture(tb: _Table | None) -> Texture:
    if tb is None:
        return Texture()
    kind = tb.str("type", "solid", TEXTURES)
    tex = Texture(kind=kind)
    if tb.has("color"):
        c = tb.vec("color", lo=0.0)
        tex.colors = np.stack([c, c])
    elif tb.has("colors"):
        v = tb.raw("colors")
        if not isinstance(v, list) or len(v) != 2:
            tb.fail("colors", "expected two colors [[r, g, b], [r, g, b]]")
        sub = _Table({"a": v[0], "b": v[1]}, tb.path("colors"), tb.file)
        tex.colors = np.stack([sub.vec("a", lo=0.0), sub.vec("b", lo=0.0)])
    tex.scale = tb.num("scale", 1.0, lo=1e-4)
    tex.angle = tb.num("angle", 0.0)
    tex.softness = tb.num("softness", 0.06, lo=0.0, hi=0.5)
    tex.mortar = tb.num("mortar", 0.08, lo=0.0, hi=0.5)
    tex.variation = tb.num("variation", 0.15, lo=0.0, hi=1.0)
    tex.octaves = tb.num("octaves", 3, lo=1, hi=8, integer=True)
    tex.seed = tb.num("seed", 0, lo=0, integer=True)
    tex.scroll = tb.vec("scroll", 2, np.zeros(2))
    tb.done()
    return tex


def _motion(tb: _Table | None, position, rotation, spin: _Table | None) -> Motion:
    m = Motion(kind="static", position=position, rotation=rotation)
    if tb is not None:
        m.kind = tb.str("type", "static", MOTIONS)
        m.start = tb.num("start", 0.0)
        if m.kind == "linear":
            m.velocity = tb.vec("velocity")
        elif m.kind == "ballistic":
            m.velocity = tb.vec("velocity")
            m.acceleration = tb.vec("acceleration", default=np.array([0.0, -9.81, 0.0]))
        elif m.kind == "rotate":
            m.axis = tb.vec("axis", default=np.array([0.0, 1.0, 0.0]), nonzero=True)
            m.speed = tb.num("speed")
            m.pivot = tb.vec("pivot", default=None)
        elif m.kind == "keyframes":
            keys = tb.tables("keys")
            if not keys:
                tb.fail("keys", "needs at least one key")
            times, pos, rots = [], [], []
            for k in keys:
                times.append(k.num("time"))
                pos.append(k.vec("position", default=position))
                rots.append(k.vec("rotation", default=np.zeros(3)))
                k.done()
            if any(b <= a for a, b in zip(times, times[1:])):
                tb.fail("keys", "key times must increase")
            m.key_times = np.asarray(times)
            m.key_positions = np.stack(pos)
            m.key_rotations = np.stack(rots) if any(np.any(r) for r in rots) else None
            m.smooth = tb.bool("smooth", False)
        tb.done()
    if spin is not None:
        m.spin_axis = spin.vec("axis", default=np.array([0.0, 1.0, 0.0]), nonzero=True)
        m.spin_speed = spin.num("speed", 0.0)
        m.spin_phase = spin.num("phase", 0.0)
        spin.done()
    return m


def _object(tb: _Table, i: int) -> Object:
    name = tb.str("name", f"object{i}")
    shape = tb.str("type", choices=SHAPES)
    position = tb.vec("position", default=np.zeros(3))
    rotation = euler_deg(tb.vec("rotation", default=np.zeros(3)))
    half = np.full(3, 0.5)
    radius, hh = 0.5, 0.5
    if shape == "plane":
        sz = tb.vec("size", 2, default=None, lo=1e-6)
        half = (np.array([math.inf, 0.0, math.inf]) if sz is None
                else np.array([sz[0] / 2, 0.0, sz[1] / 2]))
    elif shape in ("box", "blade"):
        default = np.array([1.0, 1.0, 1.0]) if shape == "box" else np.array([2.0, 0.12, 0.03])
        half = tb.vec("size", default=default, lo=1e-6) / 2
    elif shape == "sphere":
        radius = tb.num("radius", 0.5, lo=1e-6)
    elif shape == "cylinder":
        radius = tb.num("radius", 0.1, lo=1e-6)
        hh = tb.num("height", 1.0, lo=1e-6) / 2
    motion = _motion(tb.table("motion", None), position, rotation, tb.table("spin", None))
    ob = Object(name=name, shape="box" if shape == "blade" else shape, motion=motion,
                texture=_texture(tb.table("texture", None)), half=half, radius=radius,
                half_height=hh)
    ob.roughness = tb.num("roughness", 0.5, lo=0.02, hi=1.0)
    ob.specular = tb.num("specular", 0.5, lo=0.0)
    ob.mirror = tb.num("mirror", 0.0, lo=0.0, hi=1.0)
    ob.opacity = tb.num("opacity", 1.0, lo=0.0, hi=1.0)
    ob.shadow = tb.bool("shadow", True)
    tb.done()
    if ob.shape == "sphere":
        ob.bound = radius
    elif ob.shape == "cylinder":
        ob.bound = math.hypot(radius, hh)
    elif ob.shape == "box" or np.isfinite(half).all():
        ob.bound = float(np.linalg.norm(half))
    return ob


def _light(tb: _Table, i: int) -> Light:
    kind = tb.str("type", "directional", ("directional", "point"))
    color = tb.vec("color", default=np.ones(3), lo=0.0) * tb.num("intensity", 1.0, lo=0.0)
    if kind == "directional":
        d = tb.vec("direction", default=np.array([-0.4, -1.0, -0.3]), nonzero=True)
        d = d / np.linalg.norm(d)
        pos = np.zeros(3)
    else:
        d = np.array([0.0, -1.0, 0.0])
        pos = tb.vec("position")
    motion = _motion(tb.table("motion", None), pos, np.eye(3), None)
    tb.done()
    return Light(kind=kind, color=color, direction=d, motion=motion)


def _camera(tb: _Table, objects: list[Object]) -> CameraPath:
    kind = tb.str("type", "static", CAMERAS)
    cam = CameraPath(kind=kind, position=np.array([0.0, 1.5, 6.0]), target=np.zeros(3))
    cam.fov = tb.num("fov", 50.0, lo=1.0, hi=170.0)
    cam.near = tb.num("near", 0.05, lo=1e-6)
    cam.far = tb.num("far", 1000.0, lo=cam.near * 1.0001)
    if kind in ("static", "dolly"):
        cam.position = tb.vec("position")
        cam.target = tb.vec("target")
        if kind == "dolly":
            cam.velocity = tb.vec("velocity")
            cam.move_target = tb.bool("move_target", True)
    elif kind == "orbit":
        cam.center = tb.vec("center", default=np.zeros(3))
        cam.radius = tb.num("radius", 6.0, lo=1e-3)
        cam.height = tb.num("height", 1.5)
        cam.angle = tb.num("angle", 0.0)
        cam.speed = tb.num("speed", 20.0)
    elif kind == "pan":
        cam.position = tb.vec("position")
        cam.angle = tb.num("yaw", 0.0)
        cam.speed = tb.num("speed", 20.0)
        cam.pitch = tb.num("pitch", 0.0, lo=-89.0, hi=89.0)
    elif kind == "keyframes":
        keys = tb.tables("keys")
        if not keys:
            tb.fail("keys", "needs at least one key")
        times, pos, tgt = [], [], []
        for k in keys:
            times.append(k.num("time"))
            pos.append(k.vec("position"))
            tgt.append(k.vec("target"))
            k.done()
        if any(b <= a for a, b in zip(times, times[1:])):
            tb.fail("keys", "key times must increase")
        cam.key_times, cam.key_positions, cam.key_targets = map(np.asarray, (times, pos, tgt))
        cam.smooth = tb.bool("smooth", True)
    fo = tb.table("follow", None)
    if fo is not None:
        name = fo.str("object")
        match = [o for o in objects if o.name == name]
        if not match:
            fo.fail("object", f"no object named '{name}'")
        cam.follow = match[0].motion
        cam.follow_weight = fo.num("weight", 1.0, lo=0.0, hi=1.0)
        cam.follow_offset = fo.vec("offset", default=np.zeros(3))
        fo.done()
    tb.done()
    # a camera that looks straight at its own position is a scene error, caught once here
    for s in (0.0, 1.0):
        p, t = cam.at(s)
        if np.linalg.norm(t - p) < 1e-9:
            tb.fail("target", "camera position and target coincide")
    return cam


def _parse(d: dict, file: str, name: str, size, fps, frames, spp) -> Scene:
    root = _Table(d, "", file)
    name = root.str("name", name)
    # the file's values are checked even when overridden
    w, h = root.vec("size", 2, default=np.array([256.0, 144.0]), lo=1)
    if w != int(w) or h != int(h):
        root.fail("size", "expected integer width and height")
    fps_v = root.num("fps", 24.0, lo=1e-3)
    n = root.num("frames", 17, lo=1, integer=True)
    spp_v = root.num("spp", 3, lo=1, hi=16, integer=True)
    if size is not None:
        w, h = size
    fps_v = fps_v if fps is None else float(fps)
    n = n if frames is None else int(frames)
    spp_v = spp_v if spp is None else int(spp)
    if not (fps_v > 0 and n >= 1 and 1 <= spp_v <= 16 and w >= 1 and h >= 1):
        raise UsageError(f"bad override: size {w}x{h}, fps {fps_v}, frames {n}, spp {spp_v} "
                         "(all must be positive, spp at most 16)")
    eff = root.raw("effects", [])
    if not isinstance(eff, list) or not all(isinstance(e, str) for e in eff):
        root.fail("effects", "expected a list of effect names")
    for e in eff:
        if e not in EFFECTS:
            root.fail("effects", f"unknown effect '{e}' (known: {', '.join(EFFECTS)})")
    objects = [_object(t, i) for i, t in enumerate(root.tables("objects"))]
    if not objects:
        root.fail("objects", "a scene needs at least one object")
    names = [o.name for o in objects]
    dup = sorted({x for x in names if names.count(x) > 1})
    if dup:
        root.fail("objects", f"duplicate object name '{dup[0]}'")
    lights = [_light(t, i) for i, t in enumerate(root.tables("lights", []))]
    cam = _camera(root.table("camera"), objects)
    sky = root.table("sky", {})
    zen = sky.vec("zenith", default=np.array([0.18, 0.32, 0.7]), lo=0.0)
    hor = sky.vec("horizon", default=np.array([0.7, 0.75, 0.85]), lo=0.0)
    gnd = sky.vec("ground", default=np.array([0.25, 0.23, 0.2]), lo=0.0)
    sky.done()
    amb = root.vec("ambient", default=np.array([0.12, 0.13, 0.16]), lo=0.0)
    exposure = root.num("exposure", 1.0, lo=0.0)
    seed = root.num("seed", 0, lo=0, integer=True)
    pt = root.table("particles", {})
    particles = {"count": pt.num("count", 40, lo=0, hi=10000, integer=True),
                 "size": pt.num("size", 0.012, lo=1e-4),
                 "color": pt.vec("color", default=np.array([1.0, 0.75, 0.4]), lo=0.0),
                 "intensity": pt.num("intensity", 3.0, lo=0.0),
                 "velocity": pt.vec("velocity", 2, default=np.array([0.02, -0.08])),
                 "spread": pt.num("spread", 0.05, lo=0.0),
                 "seed": pt.num("seed", seed, lo=0, integer=True)}
    pt.done()
    ht = root.table("hud", {})
    elements = []
    for el in ht.tables("elements", []):
        r = el.vec("rect", 4, lo=0.0)
        elements.append((r, el.vec("color", default=np.array([0.9, 0.9, 0.9]), lo=0.0),
                         el.num("opacity", 0.8, lo=0.0, hi=1.0)))
        el.done()
    hud = {"elements": elements}
    ht.done()
    overscan = root.num("overscan_pixels", 16, lo=0, hi=4096, integer=True)
    jitter_scale = root.num("jitter_scale", 0.5, lo=0.05, hi=1.0)
    # a real-time renderer's jittered frame: one sample per pixel, at the jittered place
    jitter_spp = root.num("jitter_spp", 1, lo=1, hi=16, integer=True)
    root.done()
    spec = copy.deepcopy(d)
    spec.update({"name": name, "size": [int(w), int(h)], "fps": fps_v, "frames": n, "spp": spp_v})
    digest = hashlib.sha256(json.dumps(spec, sort_keys=True, default=str).encode()).hexdigest()[:16]
    return Scene(name=name, source=file, width=int(w), height=int(h), fps=float(fps_v), frames=n,
                 spp=spp_v, effects=frozenset(eff), camera=cam, objects=objects, lights=lights,
                 sky_zenith=zen, sky_horizon=hor, sky_ground=gnd, ambient=amb,
                 exposure=exposure, seed=seed, particles=particles, hud=hud,
                 overscan=overscan, jitter_scale=jitter_scale, jitter_spp=int(jitter_spp),
                 spec=spec, hash=digest)


def load_scene(path_or_dict, size=None, fps=None, frames=None, spp=None,
               add_effects=()) -> Scene:
    """Load and validate a scene from a TOML file or a dict (same schema).

    size (W, H), fps, frames, spp override the file's values. Raises InputError naming the
    file and the offending key.
    """
    import tomllib

    if isinstance(path_or_dict, dict):
        file = "<scene dict>"
        d = path_or_dict
        name = str(d.get("name", "scene"))
    else:
        file = os.fspath(path_or_dict)
        if not os.path.isfile(file):
            raise InputError("scene file not found", file=file)
        try:
            with open(file, "rb") as fh:
                d = tomllib.load(fh)
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
            raise InputError(f"not a valid TOML scene: {e}", file=file) from None
        name = os.path.splitext(os.path.basename(file))[0]
    if size is not None:
        if isinstance(size, str):
            size = parse_size(size)
        size = (int(size[0]), int(size[1]))
    if add_effects:  # e.g. `fgen synth --jitter`: part of the scene (and of its hash)
        d = dict(d)
        eff = d.get("effects", [])
        d["effects"] = list(eff) + [e for e in add_effects if e not in eff] \
            if isinstance(eff, list) else eff
    return _parse(d, file, name, size, fps, frames, spp)


def parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = text.lower().split("x")
        w, h = int(w), int(h)
    except ValueError:
        raise UsageError(f"bad size '{text}' (expected WxH, e.g. 256x144)") from None
    if w < 1 or h < 1:
        raise UsageError(f"bad size '{text}' (width and height must be positive)")
    return w, h
