"""Layouts: map a file's channel names and conventions onto the internal convention.

Each layout is an object with
  name, detect(header) -> score (0 = no),
  describe(header, view) -> LayoutInfo (which channels hold what; header only, no pixels),
  read(header, number, view, fields, nonfinite, optional) -> Frame,
  encode(frame, half) -> (channels, types).

Built in: `fgen` (canonical), `blender` (Cycles multilayer), `nuke` (forward/backward u/v,
v up); user layouts come from TOML files (`--layout my.toml`, see docs/conventions.md).
Views (stereo) are resolved before a layout sees channel names: single-part files name the
non-default views' channels `left.R` / `forward.left.u`, multi-part files carry one part per
view (`view` attribute); `channel_space` turns either into plain logical names for one view.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field

import numpy as np

from fgcli.errors import InputError, OutputError, UsageError
from fgcli.frame import Camera, Frame
from fgcli.io import cameras, exr

# every field a layout can provide, in reading order
FIELDS = ("color", "alpha", "depth", "mv", "mv_fwd", "normal", "albedo", "roughness")
FIELD_SIZES = {"color": 3, "alpha": 1, "depth": 1, "mv": 2, "mv_fwd": 2, "normal": 3,
               "albedo": 3, "roughness": 1,
               "mv_valid": 1}  # a channel: > 0.5 where the backward vectors are trusted
# fields never required: a request for them is satisfied by their absence
ALWAYS_OPTIONAL = {"alpha", "mv_fwd"}
# fields read whenever present (alpha travels with color)
ALWAYS_READ = {"alpha"}
VECTOR_FIELDS = ("mv", "mv_fwd")
SKY_DEPTH_BLENDER = 1e10


def _torch():
    import torch

    return torch


# ---------------------------------------------------------------------------------- views

def _names(v) -> list[str]:
    """A string or string-list attribute as a list of strings; anything else (a corrupt
    header can give an attribute any type) as []."""
    if isinstance(v, str):
        return [v] if v else []
    if isinstance(v, (list, tuple)):
        return [x for x in v if isinstance(x, str)]
    return []


def views(header: exr.Header) -> list[str]:
    """The file's view names, default (first) view first; [] for a single-view file."""
    out: list[str] = []
    for v in _names(header.parts[0].attributes.get("multiView")):
        if v not in out:
            out.append(v)
    for p in header.parts:
        if p.view and p.view not in out:
            out.append(p.view)
    return out


def channel_space(header: exr.Header, view: str | None = None
                  ) -> tuple[str | None, dict[str, tuple[int, str]]]:
    """(view used, {logical channel name: (part index, channel name in file)}) for one view.

    The default view is the file's first. Single-part multi-view: channels whose next-to-last
    name component is a view name belong to that view (`left.R`, `forward.left.u`); the
    others belong to the default view. Multi-part: parts with a `view` attribute belong to
    that view, parts without one to every view.
    """
    vs = views(header)
    if view is not None and view not in vs:
        if vs:
            raise InputError(f"no view '{view}' in the file (views: {', '.join(vs)})",
                             file=header.path)
        raise InputError(f"no view '{view}': the file has a single view", file=header.path)
    v = view if view is not None else (vs[0] if vs else None)
    space: dict[str, tuple[int, str]] = {}
    for p in header.parts:
        if p.view is not None and p.view != v:
            continue
        pviews = _names(p.attributes.get("multiView")) or (vs if len(header.parts) == 1
                                                             else [])
        default = pviews[0] if pviews else None
        for ch in p.channels:
            comps = ch.split(".")
            if len(comps) >= 2 and comps[-2] in pviews:
                chview = comps[-2]
                logical = ".".join(comps[:-2] + comps[-1:])
            else:
                chview, logical = default, ch
            if p.view is None and chview is not None and v is not None and chview != v:
                continue
            space.setdefault(logical, (p.index, ch))
    return v, space


# ---------------------------------------------------------------------------- conventions

@dataclass
class Conventions:
    """How a layout's values map onto the internal convention (docs/conventions.md)."""

    # internal = file * scale * units, per axis (y flip and sign folded into the scale)
    mv_scale: tuple[float, float] = (1.0, 1.0)
    fwd_scale: tuple[float, float] = (1.0, 1.0)
    mv_units: str = "pixels"  # pixels | uv (0..1 of the image) | ndc (-1..1)
    depth_kind: str = "linear"  # linear (view z) | inverse (1/z) | distance (along the ray)
    depth_scale: float = 1.0
    sky_depth: float | None = None  # file depth >= this is sky (+inf)
    sky_value: float | None = None  # what +inf is written as (default: sky_depth or inf)
    sky_vectors_invalid: bool = False  # vectors of sky pixels are not to be trusted
    normal_space: str = "world"  # world | camera (OpenGL camera space)
    float_fields: frozenset = frozenset({"depth", "mv", "mv_fwd"})

    def units(self, width: int, height: int) -> np.ndarray:
        if self.mv_units == "pixels":
            return np.array([1.0, 1.0])
        if self.mv_units == "uv":
            return np.array([float(width), float(height)])
        if self.mv_units == "ndc":
            return np.array([width / 2.0, height / 2.0])
        raise UsageError(f"unknown mv_units '{self.mv_units}' (pixels, uv, ndc)")

    def vec_factor(self, fld: str, width: int, height: int) -> np.ndarray:
        s = self.mv_scale if fld == "mv" else self.fwd_scale
        return np.asarray(s, dtype=np.float64) * self.units(width, height)


@dataclass
class LayoutInfo:
    """What a layout found in one file for one view (header only)."""

    layout: str
    view: str | None
    views: list[str]
    space: dict[str, tuple[int, str]]
    names: dict[str, list[str]]  # field -> logical channel names present in the file
    notes: list[str] = field(default_factory=list)

    @property
    def fields(self) -> set[str]:
        return set(self.names)

    @property
    def mv_source(self) -> str | None:
        """'backward' (vectors toward t-1 in the file), 'forward' (only toward t+1: derive),
        or None."""
        if "mv" in self.names:
            return "backward"
        if "mv_fwd" in self.names:
            return "forward"
        return None

    def refs(self, fld: str) -> list[tuple[int, str]]:
        return [self.space[n] for n in self.names[fld]]

    def part_of(self, fld: str) -> int:
        return self.space[self.names[fld][0]][0]


@dataclass
class RawFrame:
    """A frame read into the internal convention as numpy arrays (no torch)."""

    number: int
    arrays: dict[str, np.ndarray]  # field -> (C, H, W) float32
    valid: dict[str, np.ndarray]  # 'mv' / 'mv_fwd' -> (1, H, W) bool, only where some invalid
    camera: Camera | None
    attributes: dict
    attribute_types: dict
    path: str
    helpers: set = field(default_factory=set)  # fields read only for internal use
    overscan: dict | None = None  # Frame.overscan, as numpy arrays

    def to_frame(self) -> Frame:
        torch = _torch()
        kw = {k: torch.from_numpy(np.ascontiguousarray(v, dtype=np.float32))
              for k, v in self.arrays.items() if k not in self.helpers}
        if "mv" in kw and "mv" in self.valid:
            kw["mv_valid"] = torch.from_numpy(np.ascontiguousarray(self.valid["mv"]))
        if self.overscan is not None:
            kw["overscan"] = {"origin": self.overscan["origin"],
                              **{k: torch.from_numpy(np.ascontiguousarray(
                                  self.overscan[k], dtype=np.float32))
                                 for k in ("color", "depth")}}
        return Frame(number=self.number, camera=self.camera, header=dict(self.attributes),
                     source=self.path, header_types=dict(self.attribute_types), **kw)


def _as_list(v) -> list[str]:
    return [v] if isinstance(v, str) else list(v)


class MappedLayout:
    """A layout defined by channel names per field (alternatives tried in order) and
    conventions. fgen, nuke and TOML user layouts are instances; blender subclasses it."""

    def __init__(self, name: str, channels: dict[str, list], conventions: Conventions | None = None,
                 description: str = "", encode_channels: dict[str, list[str]] | None = None):
        self.name = name
        self.description = description
        self.conv = conventions or Conventions()
        # field -> list of alternatives, each a list of logical channel names
        self.channels: dict[str, list[list[str]]] = {}
        for fld, alts in channels.items():
            if fld not in FIELD_SIZES:
                raise UsageError(f"layout '{name}': unknown field '{fld}' "
                                 f"(known: {', '.join(FIELDS)})")
            alts = [alts] if isinstance(alts, str) else list(alts)
            if alts and isinstance(alts[0], str):
                alts = [alts]
            norm = []
            for a in alts:
                a = _as_list(a)
                if len(a) != FIELD_SIZES[fld]:
                    raise UsageError(f"layout '{name}': field '{fld}' needs "
                                     f"{FIELD_SIZES[fld]} channel name(s), got {a}")
                norm.append(a)
            self.channels[fld] = norm
        if "color" not in self.channels:
            raise UsageError(f"layout '{name}': the color channels are required")
        self.encode_channels = encode_channels or {f: a[0] for f, a in self.channels.items()}

    def __repr__(self) -> str:
        return f"<layout {self.name}>"

    # -- header-level ---------------------------------------------------------------------
    def find_names(self, space: dict) -> tuple[dict[str, list[str]], list[str]]:
        names = {}
        for fld, alts in self.channels.items():
            for a in alts:
                if all(n in space for n in a):
                    names[fld] = a
                    break
        return names, []

    def describe(self, header: exr.Header, view: str | None = None) -> LayoutInfo:
        v, space = channel_space(header, view)
        names, notes = self.find_names(space)
        info = LayoutInfo(self.name, v, views(header), space, names, notes)
        if info.mv_source == "forward":
            info.notes.append("backward vectors derived from forward vectors (frame t-1's "
                              "forward vectors splatted into frame t with a depth test; "
                              "holes take the nearest valid vector and are flagged invalid)")
        if self.conv.sky_vectors_invalid and "mv" in names:
            info.notes.append("motion vectors of sky pixels are flagged invalid (the file "
                              "stores 0 there even when the camera moves)")
        if info.views:
            info.notes.append(f"view '{v}' (views: {', '.join(info.views)})")
        return info

    def detect(self, header: exr.Header) -> int:
        try:
            _, space = channel_space(header)
        except InputError:
            return 0
        names, _ = self.find_names(space)
        return self.score(names, space)

    def score(self, names: dict, space: dict) -> int:
        return 0  # user layouts are never auto-detected

    # -- pixels ---------------------------------------------------------------------------
    def read(self, header: exr.Header, number: int, view: str | None = None,
             fields: set[str] | None = None, nonfinite: dict | None = None,
             optional: set[str] | None = None) -> Frame:
        """Read one frame. fields: Frame fields the caller needs (None = all present);
        color (and alpha, when present) is always read; a requested field the file lacks is
        an InputError naming the channels found and the layout tried, unless it is alpha,
        mv_fwd or in `optional` (fields read when present, never required). A requested
        `mv` is satisfied by forward vectors (`mv_fwd`), which the SequenceReader turns into
        backward vectors; read() alone leaves `mv` None then."""
        return self.read_raw(header, number, view, fields, nonfinite, optional).to_frame()

    def read_raw(self, header: exr.Header, number: int, view: str | None = None,
                 fields: set[str] | None = None, nonfinite: dict | None = None,
                 optional: set[str] | None = None) -> "RawFrame":
        """Like read(), but numpy arrays (internal convention) and per-vector validity."""
        info = self.describe(header, view)
        want, helpers = self._want(info, fields, optional, header, number)
        extra = ["mv_valid"] if "mv" in want and "mv_valid" in info.names else []
        refs = [r for f in want + extra for r in info.refs(f)]
        borders = None
        if any(p.overscan for p in header.parts):  # keep the rendered border too
            borders = {}
            arrays = exr.read_channels(header.path, refs, header, borders=borders)
        else:
            arrays = exr.read_channels(header.path, refs, header)
        w, h = header.width, header.height
        # the camera and attributes come with the colour (a G-buffer-only frame: with the
        # first field read)
        main = "color" if "color" in info.names else next(iter(want), None)
        cpart = header.parts[info.part_of(main) if main else 0]
        cam, _ = cameras.from_header_attributes(cpart.attributes)
        out: dict[str, np.ndarray] = {}
        valid: dict[str, np.ndarray] = {}
        taken: set = set()  # channels a field already holds (never shared by two fields)
        for fld in want:
            frefs = info.refs(fld)
            a = planes([arrays[r] for r in frefs], copy=bool(taken & set(frefs)))
            taken.update(frefs)
            p = header.parts[info.part_of(fld)]
            mask = None if p.full_data_window else p.data_mask()[None]
            if fld == "depth":
                a = self._depth_in(a, cam, w, h, header.path, number, nonfinite)
                if mask is not None:
                    a = np.where(mask, a, np.inf).astype(np.float32)
            elif fld in VECTOR_FIELDS:
                ok = np.isfinite(a).all(0, keepdims=True)
                a = _clean(a, number, fld, nonfinite)
                a = _scaled(a, self.conv.vec_factor(fld, w, h))
                if mask is not None:
                    ok = ok & mask
                    a = np.where(mask, a, 0.0).astype(np.float32)
                valid[fld] = ok
            elif fld == "normal":
                a = _clean(a, number, fld, nonfinite)
                if self.conv.normal_space == "camera" and cam is not None:
                    r = np.asarray(cam.world_to_camera, np.float64)[:3, :3]
                    a = np.einsum("ji,jhw->ihw", r, a)
                    n = np.linalg.norm(a, axis=0, keepdims=True)
                    a = np.where(n > 0, a / np.maximum(n, 1e-12), 0.0).astype(np.float32)
            else:
                a = _clean(a, number, fld, nonfinite)
            out[fld] = a
        if extra:
            r = info.refs("mv_valid")[0]
            valid["mv"] = valid["mv"] & (arrays[r][None] > 0.5)
        if self.conv.sky_vectors_invalid and "depth" in out:
            sky = ~np.isfinite(out["depth"])
            for k in valid:
                valid[k] = valid[k] & ~sky
        valid = {k: v for k, v in valid.items() if not v.all()}
        raw = RawFrame(number, out, valid, cam, dict(cpart.attributes),
                       dict(cpart.attr_types), header.path, set(helpers))
        if borders and "depth" in out:
            raw.overscan = self._overscan(info, borders, cam, header.path, number,
                                          (w, h))
        return raw

    def _overscan(self, info: LayoutInfo, borders: dict, cam, path, number,
                  display: tuple[int, int]) -> dict | None:
        """The rendered region beyond the display window (an overscan border), colour and
        depth: {"origin": (x, y) relative to the display window, "color": (3, He, We),
        "depth": (1, He, We)}; None unless both fields have it with one extent that
        contains the whole display window (a data window shifted off it is no border), or
        when depth is stored as distance along the ray (its conversion is per display
        pixel)."""
        refs = info.refs("color") + info.refs("depth")
        if self.conv.depth_kind == "distance" or not all(r in borders for r in refs):
            return None
        if len({(b[0].shape, b[1], b[2]) for b in (borders[r] for r in refs)}) != 1:
            return None
        plane, x, y = borders[refs[0]]
        (he, we), (w, h) = plane.shape, display
        if not (x <= 0 and y <= 0 and x + we >= w and y + he >= h):
            return None
        color = _clean(planes([borders[r][0] for r in info.refs("color")], copy=True),
                       number, "color", None)
        depth = planes([borders[r][0] for r in info.refs("depth")], copy=True)
        depth = self._depth_in(depth, cam, depth.shape[-1], depth.shape[-2], path, number,
                               None)
        return {"origin": (int(x), int(y)), "color": color, "depth": depth}

    def _want(self, info: LayoutInfo, fields, optional, header, number
              ) -> tuple[list[str], set[str]]:
        read_if_present = set(optional or ()) | ALWAYS_READ
        optional = set(optional or ()) | ALWAYS_OPTIONAL
        helpers: set[str] = set()
        if fields is None:
            need = (set(info.names) & set(FIELDS)) | {"color"}
        else:
            need = set(fields) | {"color"}
            unknown = need - set(FIELDS) - {"mv_valid", "camera"}
            if unknown:
                raise UsageError(f"unknown frame field(s) {sorted(unknown)} "
                                 f"(known: {', '.join(FIELDS)})")
            need &= set(FIELDS)
            if "mv" in need and "mv" not in info.names and "mv_fwd" in info.names:
                need.add("mv_fwd")  # the reader derives backward vectors from these
            need |= {f for f in read_if_present if f in info.names and f in FIELDS}
        if ("mv" in need or "mv_fwd" in need) and self.conv.sky_vectors_invalid \
                and "depth" in info.names and "depth" not in need:
            need.add("depth")
            helpers.add("depth")
        for fld in sorted(need - set(info.names)):
            if fld in optional:
                continue
            if fld == "mv" and "mv_fwd" in info.names:
                continue
            alts = self.channels.get(fld)
            wanted = " or ".join(", ".join(a) for a in alts) if alts else "(none in this layout)"
            found = ", ".join(sorted(info.space)) or "(none)"
            vw = f", view '{info.view}'" if info.view else ""
            raise InputError(f"missing channels for {fld}: layout '{self.name}'{vw} needs "
                             f"{wanted}; channels found: {found}", file=header.path,
                             frame=number)
        return [f for f in FIELDS if f in need and f in info.names], helpers

    def _depth_in(self, a, cam, w, h, path, number, nonfinite) -> np.ndarray:
        c = self.conv
        bad = np.isnan(a) | np.isneginf(a)
        if bad.any():
            if nonfinite is not None:
                nonfinite.setdefault("depth", []).append((number, int(bad.sum())))
            a = np.where(bad, np.inf, a)
        with np.errstate(divide="ignore", invalid="ignore"):
            if c.sky_depth is not None:
                a = np.where(a >= c.sky_depth, np.inf, a)
            if c.depth_kind == "inverse":
                a = np.where(a > 0, c.depth_scale / a, np.inf)
            elif c.depth_kind in ("linear", "distance"):
                if c.depth_scale != 1.0:  # x 1.0 changes no value: skip the pass
                    a = a * c.depth_scale
            else:
                raise UsageError(f"unknown depth_kind '{c.depth_kind}' "
                                 "(linear, inverse, distance)")
            if c.depth_kind == "distance":
                if cam is None:
                    raise InputError(f"layout '{self.name}' stores depth as distance along "
                                     "the ray, which needs a camera (none in the header)",
                                     file=path, frame=number)
                a = a * ray_cos(cam, w, h)[None]
        return a.astype(np.float32, copy=False)

    # -- writing --------------------------------------------------------------------------
    def can_encode(self, fld: str) -> bool:
        return fld in self.encode_channels

    def encode(self, frame: Frame, half: bool = True) -> tuple[dict, dict]:
        """Channels and types ('half'/'float') for one frame in this layout."""
        chans: dict[str, np.ndarray] = {}
        types: dict[str, str] = {}
        w, h = frame.width, frame.height
        for fld in FIELDS:
            t = getattr(frame, fld, None)
            if t is None or fld not in self.encode_channels:
                continue
            # no copy: the writer copies every channel once, into its interleaved buffer
            a = _np(t).astype(np.float32, copy=False)
            if fld == "depth":
                a = self._depth_out(a, frame.camera, w, h)
            elif fld in VECTOR_FIELDS:
                a = _divided(a, self.conv.vec_factor(fld, w, h))
            elif fld == "normal" and self.conv.normal_space == "camera":
                if frame.camera is None:
                    raise OutputError(f"layout '{self.name}' stores camera-space normals, "
                                      "which needs a camera", frame=frame.number)
                r = np.asarray(frame.camera.world_to_camera, np.float64)[:3, :3]
                a = np.einsum("ij,jhw->ihw", r, a).astype(np.float32)
            kind = "float" if (not half or fld in self.conv.float_fields) else "half"
            for i, n in enumerate(self.encode_channels[fld]):
                chans[n] = a[i]
                types[n] = kind
        if frame.mv is not None and frame.mv_valid is not None and "mv_valid" in \
                self.encode_channels:
            v = _np(frame.mv_valid).astype(bool).reshape(h, w)
            if not v.all():
                n = self.encode_channels["mv_valid"][0]
                chans[n] = v.astype(np.float32)
                types[n] = "half"
        return chans, types

    def _depth_out(self, a, cam, w, h) -> np.ndarray:
        c = self.conv
        with np.errstate(divide="ignore", invalid="ignore"):
            if c.depth_kind == "distance":
                if cam is None:
                    raise OutputError(f"layout '{self.name}' stores depth as distance along "
                                      "the ray, which needs a camera")
                a = a / ray_cos(cam, w, h)[None]
            if c.depth_kind == "inverse":
                a = np.where(np.isfinite(a) & (a > 0), c.depth_scale / a, 0.0)
            else:
                if c.depth_scale != 1.0:  # / 1.0 changes no value: skip the pass
                    a = a / c.depth_scale
                sky = c.sky_value if c.sky_value is not None else c.sky_depth
                if sky is not None:
                    a = np.where(np.isinf(a), sky, a)
        return a.astype(np.float32, copy=False)


def _np(t) -> np.ndarray:
    return t.detach().cpu().numpy() if hasattr(t, "detach") else np.asarray(t)


def planes(arrays: list, copy: bool = False) -> np.ndarray:
    """(C, H, W) float32 of C (H, W) planes. Planes that are consecutive slices of one
    (N, H, W) float32 block, in order (exr.read_channels gives a span's channels so), come
    back as a view of it (no copy) unless `copy`; others are stacked (one copy)."""
    first = arrays[0]
    base = first.base
    if (not copy and isinstance(base, np.ndarray) and base.ndim == 3
            and base.dtype == np.float32 and base.flags.c_contiguous
            and all(a.base is base and a.shape == base.shape[1:] for a in arrays)):
        step = base.strides[0]
        start = base.__array_interface__["data"][0]
        offs = [a.__array_interface__["data"][0] - start for a in arrays]
        j0 = offs[0] // step
        if offs[0] % step == 0 and offs == [(j0 + i) * step for i in range(len(arrays))]:
            return base[j0:j0 + len(arrays)]
    out = np.empty((len(arrays),) + first.shape, np.float32)
    for i, a in enumerate(arrays):
        out[i] = a
    return out


def _f32_exact(factor: np.ndarray) -> bool:
    """True when every factor is a float32 value: a float32 product then equals the float64
    product rounded to float32 (both are the correctly rounded exact product)."""
    return bool((factor.astype(np.float32).astype(np.float64) == factor).all())


def _scaled(a: np.ndarray, factor: np.ndarray) -> np.ndarray:
    """a (C, H, W) float32 times a per-channel float64 factor, as float32: the same values
    as (a * factor).astype(float32), without the float64 temporary where it cannot change
    a value (factors of 1 skip the pass; factors exact in float32 multiply in float32)."""
    factor = np.asarray(factor, np.float64)
    if (factor == 1.0).all():
        return a.astype(np.float32, copy=False)
    if _f32_exact(factor):
        return a * factor.astype(np.float32)[:, None, None]
    return (a * factor[:, None, None]).astype(np.float32)


def _divided(a: np.ndarray, factor: np.ndarray) -> np.ndarray:
    """a / factor (per channel) in float32, as encode() always did; factors of 1 skip it."""
    if (np.asarray(factor) == 1.0).all():
        return a
    return a / np.asarray(factor)[:, None, None].astype(np.float32)


def _clean(arr: np.ndarray, number: int, name: str, stats: dict | None) -> np.ndarray:
    """Replace NaN/Inf with 0, counting them per field in `stats` (field -> [(frame, n)])."""
    bad = ~np.isfinite(arr)
    if bad.any():
        if stats is not None:
            stats.setdefault(name, []).append((number, int(bad.sum())))
        arr = np.where(bad, 0.0, arr).astype(np.float32)
    return arr


def ray_cos(cam: Camera, w: int, h: int) -> np.ndarray:
    """(H, W) cosine between each pixel's view ray and the camera's forward axis
    (planar depth = distance along the ray * this)."""
    inv = np.linalg.inv(np.asarray(cam.projection, np.float64))
    xs = (np.arange(w) + 0.5) / w * 2 - 1
    ys = 1 - (np.arange(h) + 0.5) / h * 2
    nx, ny = np.meshgrid(xs, ys)
    pts = np.stack([nx, ny, np.ones_like(nx), np.ones_like(nx)]).reshape(4, -1)
    v = inv @ pts
    v = v[:3] / v[3]
    n = np.linalg.norm(v, axis=0)
    return (np.abs(v[2]) / np.maximum(n, 1e-30)).reshape(h, w).astype(np.float32)


# ------------------------------------------------------------------------------- built in

class FgenLayout(MappedLayout):
    """The canonical layout fgen writes (see docs/conventions.md). An optional `mv.valid`
    channel (1 = trusted, 0 = not) carries Frame.mv_valid when some vectors are flagged."""

    VALID_CHANNEL = "mv.valid"

    def __init__(self):
        from fgcli.io.frames import FGEN_CHANNELS

        super().__init__("fgen", {**FGEN_CHANNELS, "mv_valid": [self.VALID_CHANNEL]},
                         description="canonical: R,G,B[,A], Z, mv.x/mv.y (pixels toward t-1, "
                                     "y down), N.*, albedo.*, roughness")

    def score(self, names, space) -> int:
        if "color" not in names:
            return 0
        if "mv" in names:
            return 10
        if any(k.startswith(("forward.", "backward.")) for k in space):
            return 0
        return 3 if "depth" in names else 2


class NukeLayout(MappedLayout):
    def __init__(self):
        super().__init__(
            "nuke",
            {"color": ["R", "G", "B"], "alpha": ["A"],
             "depth": [["depth.Z"], ["Z"]],
             "mv": [["backward.u", "backward.v"]],
             "mv_fwd": [["forward.u", "forward.v"]],
             "normal": [["N.x", "N.y", "N.z"], ["N.X", "N.Y", "N.Z"],
                        ["N.red", "N.green", "N.blue"]],
             "albedo": [["albedo.R", "albedo.G", "albedo.B"],
                        ["albedo.red", "albedo.green", "albedo.blue"]],
             "roughness": [["roughness"], ["roughness.X"]]},
            Conventions(mv_scale=(1.0, -1.0), fwd_scale=(1.0, -1.0)),
            description="compositing: R,G,B[,A], Z or depth.Z, backward.u/v and/or "
                        "forward.u/v (pixels, v up)")

    def score(self, names, space) -> int:
        return 10 if "color" in names and ("mv" in names or "mv_fwd" in names) else 0


class BlenderLayout(MappedLayout):
    """Blender Cycles multilayer EXR: <ViewLayer>.Combined.RGBA, .Depth.Z, .Vector.XYZW
    (pixels, Y up; backward = (X, -Y), forward = (-Z, W) y down), .Normal.XYZ (world),
    .DiffCol.RGB, AOVs .<name>.X. Sky: depth 1e10 -> +inf, its vectors flagged invalid."""

    DEFAULT_LAYER = "ViewLayer"
    _COMBINED = re.compile(r"^(?P<prefix>(?:.*\.)?)Combined\.R$")

    def __init__(self):
        chans = {"color": ["Combined.R", "Combined.G", "Combined.B"],
                 "alpha": ["Combined.A"], "depth": ["Depth.Z"],
                 "mv": ["Vector.X", "Vector.Y"], "mv_fwd": ["Vector.Z", "Vector.W"],
                 "normal": ["Normal.X", "Normal.Y", "Normal.Z"],
                 "albedo": ["DiffCol.R", "DiffCol.G", "DiffCol.B"],
                 "roughness": ["Roughness.X"]}
        super().__init__(
            "blender", chans,
            Conventions(mv_scale=(1.0, -1.0), fwd_scale=(-1.0, 1.0),
                        sky_depth=1e9, sky_value=SKY_DEPTH_BLENDER, sky_vectors_invalid=True,
                        float_fields=frozenset({"depth", "mv", "mv_fwd", "normal"})),
            description="Blender Cycles multilayer: <ViewLayer>.Combined.*, .Depth.Z, "
                        ".Vector.X/Y/Z/W (Y up), .Normal.*, .DiffCol.*, AOVs")
        prefix = self.DEFAULT_LAYER + "."
        self.encode_channels = {f: [prefix + n for n in a[0]] for f, a in self.channels.items()}

    def layers(self, space: dict) -> list[str]:
        out = []
        for k in space:
            m = self._COMBINED.match(k)
            if m and m.group("prefix") not in out:
                out.append(m.group("prefix"))
        return out

    def find_names(self, space):
        layers = self.layers(space)
        if not layers:
            return {}, []
        prefix = layers[0]
        names = {}
        for fld, alts in self.channels.items():
            full = [prefix + n for n in alts[0]]
            if all(n in space for n in full):
                names[fld] = full
        if "roughness" not in names:  # AOV named roughness, any case, .X or .V
            for k in space:
                rest = k[len(prefix):] if k.startswith(prefix) else None
                if rest and re.fullmatch(r"(?i)roughness\.(X|V|R)", rest):
                    names["roughness"] = [k]
                    break
        notes = []
        if len(layers) > 1:
            notes.append(f"view layer '{prefix.rstrip('.')}' (also in the file: "
                         f"{', '.join(p.rstrip('.') for p in layers[1:])})")
        return names, notes

    def score(self, names, space) -> int:
        if "color" not in names:
            return 0
        return 11 if "mv" in names else 10

    def encode(self, frame: Frame, half: bool = True):
        if frame.mv is not None and frame.mv_fwd is None:
            # the Vector pass always has four channels; no forward vectors -> 0
            torch = _torch()
            frame = frame.replace(mv_fwd=torch.zeros_like(frame.mv))
        chans, types = super().encode(frame, half)
        a = self.encode_channels["alpha"][0]
        if a not in chans:
            chans[a] = np.ones((frame.height, frame.width), np.float32)
            types[a] = "half" if half else "float"
        return chans, types


# ------------------------------------------------------------------------------ user TOML

_TOML_TOP = {"name", "description", "channels", "conventions"}
_TOML_CHANNELS = {"color", "alpha", "depth", "mv", "mv_forward", "normal", "albedo",
                  "roughness", "mv_valid"}
_TOML_CONV = {"mv_y", "mv_units", "mv_sign", "mv_forward_sign", "depth_kind", "depth_scale",
              "sky_depth", "sky_value", "sky_vectors_invalid", "normal_space",
              "float_channels"}


def load_toml(path: str) -> MappedLayout:
    """A user layout from a TOML file (format in docs/conventions.md)."""
    import tomllib

    path = str(path)
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except OSError as e:
        raise UsageError(f"cannot read layout file: {e.strerror}", file=path) from None
    except tomllib.TOMLDecodeError as e:
        raise UsageError(f"bad layout TOML: {e}", file=path) from None

    def unknown(keys, known, where):
        bad = sorted(set(keys) - known)
        if bad:
            raise UsageError(f"unknown key(s) {bad} in {where} (known: {sorted(known)})",
                             file=path)

    unknown(data, _TOML_TOP, "the layout file")
    ch = data.get("channels")
    if not isinstance(ch, dict) or "color" not in ch:
        raise UsageError("a layout needs a [channels] table with at least `color`", file=path)
    unknown(ch, _TOML_CHANNELS, "[channels]")
    conv = data.get("conventions", {})
    if not isinstance(conv, dict):
        raise UsageError("[conventions] must be a table", file=path)
    unknown(conv, _TOML_CONV, "[conventions]")
    ystr = conv.get("mv_y", "down")
    if ystr not in ("down", "up"):
        raise UsageError(f"mv_y must be 'down' or 'up', not {ystr!r}", file=path)
    yf = -1.0 if ystr == "up" else 1.0
    sign = float(conv.get("mv_sign", 1))
    fsign = float(conv.get("mv_forward_sign", sign))
    if sign not in (1.0, -1.0) or fsign not in (1.0, -1.0):
        raise UsageError("mv_sign / mv_forward_sign must be 1 or -1", file=path)
    choices = {"mv_units": ("pixels", "uv", "ndc"),
               "depth_kind": ("linear", "inverse", "distance"),
               "normal_space": ("world", "camera")}
    for k, allowed in choices.items():
        if k in conv and conv[k] not in allowed:
            raise UsageError(f"{k} must be one of {', '.join(allowed)}, not {conv[k]!r}",
                             file=path)
    floats = {"depth", "mv", "mv_fwd"}
    for n in conv.get("float_channels", []):
        floats.add("mv_fwd" if n == "mv_forward" else n)
    c = Conventions(
        mv_scale=(sign, sign * yf), fwd_scale=(fsign, fsign * yf),
        mv_units=conv.get("mv_units", "pixels"), depth_kind=conv.get("depth_kind", "linear"),
        depth_scale=float(conv.get("depth_scale", 1.0)),
        sky_depth=None if conv.get("sky_depth") is None else float(conv["sky_depth"]),
        sky_value=None if conv.get("sky_value") is None else float(conv["sky_value"]),
        sky_vectors_invalid=bool(conv.get("sky_vectors_invalid", False)),
        normal_space=conv.get("normal_space", "world"), float_fields=frozenset(floats))
    chans = {("mv_fwd" if k == "mv_forward" else k): v for k, v in ch.items()}
    name = data.get("name") or os.path.splitext(os.path.basename(path))[0]
    try:
        return MappedLayout(str(name), chans, c, description=data.get("description", path))
    except UsageError as e:
        raise UsageError(f"{e.message}", file=path) from None


# ------------------------------------------------------------------------------ registry

LAYOUTS = {"fgen": FgenLayout(), "blender": BlenderLayout(), "nuke": NukeLayout()}


def camera_from_header(header: exr.Header) -> Camera | None:
    """The camera in the first part's header (fgen JSON or OpenEXR standard), or None."""
    return cameras.from_header_attributes(header.attributes)[0]


def get(name):
    if not isinstance(name, str):
        return name
    if name in LAYOUTS:
        return LAYOUTS[name]
    if name.lower().endswith(".toml") or os.path.isfile(name):
        return load_toml(name)
    raise UsageError(f"unknown layout '{name}' (known: {', '.join(LAYOUTS)}, or a .toml file)")


def detect(header: exr.Header):
    scored = sorted(((l.detect(header), i, n) for i, (n, l) in enumerate(LAYOUTS.items())),
                    key=lambda t: (-t[0], t[1]))
    if not scored or scored[0][0] <= 0:
        try:
            v, space = channel_space(header)
            chans = list(space)
        except InputError:
            chans = [c for _, c, _ in header.all_channels()]
        raise InputError(f"cannot detect the layout from channels {', '.join(chans)} "
                         f"(tried: {', '.join(LAYOUTS)}); pass --layout NAME or --layout "
                         f"my.toml", file=header.path)
    return LAYOUTS[scored[0][2]]


def resolve(layout, header: exr.Header):
    if layout is None or layout == "auto":
        return detect(header)
    return get(layout)


def encode(frame: Frame, layout="fgen", half: bool = True):
    return get(layout).encode(frame, half)
