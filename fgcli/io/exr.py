"""Low-level OpenEXR access through OpenImageIO, numpy only (no torch import here).

Channels are always looked up by name (OpenEXR re-sorts them). Every part of a multi-part
file is listed; data windows smaller than the display window are padded to the display
window (with 0, or a per-channel fill value); half and float channels in one file, scanline
or tiled, all read as float32.

Header attributes keep their OpenImageIO type names (`Part.attr_types`) so that metadata
carried from a source frame into an output is written back with the same type (a `float2`
`screenWindowCenter` stays a float2, a `timecode` stays a timecode).
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field

import numpy as np

from fgcli.errors import InputError, OutputError
from fgcli.io import atomic

# attributes that describe the file's structure, not its content: never carried over
STRUCTURAL_ATTRIBUTES = {"compression", "type", "chunkCount", "version", "tiles",
                         "DateTime", "dataWindow", "displayWindow", "lineOrder", "channels"}
COMPRESSIONS = ("zip", "zips", "piz", "none", "rle", "pxr24", "b44", "b44a", "dwaa", "dwab")


def _oiio():
    import OpenImageIO as oiio  # imported lazily: keeps `fgen --help` fast

    return oiio


@dataclass
class Part:
    index: int
    name: str | None
    view: str | None
    channels: list[str]
    formats: list[str]
    width: int  # display window
    height: int
    x: int  # data window origin relative to display origin
    y: int
    data_width: int
    data_height: int
    tiled: bool
    attributes: dict = field(default_factory=dict)
    attr_types: dict = field(default_factory=dict)  # attribute name -> OIIO type name

    @property
    def full_data_window(self) -> bool:
        """True when the data window is exactly the display window."""
        return (self.x, self.y, self.data_width, self.data_height) == (
            0, 0, self.width, self.height)

    def data_mask(self) -> np.ndarray:
        """(H, W) bool on the display window: True where the part has pixel data."""
        m = np.zeros((self.height, self.width), bool)
        x0, y0 = max(self.x, 0), max(self.y, 0)
        x1, y1 = min(self.x + self.data_width, self.width), min(self.y + self.data_height,
                                                                  self.height)
        if x1 > x0 and y1 > y0:
            m[y0:y1, x0:x1] = True
        return m

    def format_of(self, channel: str) -> str:
        return self.formats[self.channels.index(channel)]


@dataclass
class Header:
    path: str
    parts: list[Part]

    @property
    def width(self) -> int:
        return self.parts[0].width

    @property
    def height(self) -> int:
        return self.parts[0].height

    @property
    def attributes(self) -> dict:
        return self.parts[0].attributes

    @property
    def attribute_types(self) -> dict:
        return self.parts[0].attr_types

    def all_channels(self) -> list[tuple[int, str, str]]:
        """(part index, channel name, format) for every channel of every part."""
        return [(p.index, c, f) for p in self.parts for c, f in zip(p.channels, p.formats)]


def _attr_value(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (tuple, list)):
        return [_attr_value(x) for x in v]
    return v


def _spec_attributes(spec) -> tuple[dict, dict]:
    out, types = {}, {}
    for p in spec.extra_attribs:
        try:
            out[p.name] = _attr_value(p.value)
            types[p.name] = str(p.type)
        except Exception:  # pragma: no cover - exotic attribute types
            continue
    return out, types


def _check_file(path: str) -> None:
    if not os.path.isfile(path):
        raise InputError("file not found", file=path)
    with open(path, "rb") as fh:
        magic = fh.read(4)
    if magic != b"\x76\x2f\x31\x01":
        raise InputError("not an OpenEXR file (bad magic number)", file=path)


def _oiio_error(oiio, inp=None) -> str:
    msg = ""
    if inp is not None:
        msg = (inp.geterror() or "").strip()
    msg = msg or (oiio.geterror() or "").strip()
    return " ".join(msg.split())


def read_header(path: str) -> Header:
    oiio = _oiio()
    path = str(path)
    _check_file(path)
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise InputError(f"cannot open EXR (truncated or corrupt header): "
                         f"{_oiio_error(oiio) or 'unknown error'}", file=path)
    try:
        parts = []
        idx = 0
        while inp.seek_subimage(idx, 0):
            s = inp.spec()
            names = list(s.channelnames)
            if s.channelformats:
                fmts = [str(f) for f in s.channelformats]
            else:
                fmts = [str(s.format)] * len(names)
            attrs, types = _spec_attributes(s)
            parts.append(Part(
                index=idx, name=attrs.get("name") or attrs.get("oiio:subimagename"),
                view=attrs.get("view"), channels=names, formats=fmts,
                width=s.full_width, height=s.full_height, x=s.x - s.full_x, y=s.y - s.full_y,
                data_width=s.width, data_height=s.height, tiled=s.tile_width > 0,
                attributes=attrs, attr_types=types))
            idx += 1
        inp.geterror()  # clear the "no such subimage" message of the last seek
    finally:
        inp.close()
    if not parts:
        raise InputError("EXR has no readable parts", file=path)
    return Header(path=path, parts=parts)


def read_channels(path: str, wanted: list[tuple[int, str]], header: Header | None = None,
                  fill: dict | None = None) -> dict[tuple[int, str], np.ndarray]:
    """Read the named channels ((part, name) pairs) as float32 (H, W) arrays on the display
    window. Only the parts and the channel range needed are decoded.

    fill: (part, name) -> value for display-window pixels outside the data window (default 0).
    """
    oiio = _oiio()
    path = str(path)
    header = header or read_header(path)
    fill = fill or {}
    by_part: dict[int, list[str]] = {}
    for part, name in wanted:
        if name not in by_part.setdefault(part, []):
            by_part[part].append(name)
    out: dict[tuple[int, str], np.ndarray] = {}
    if not by_part:
        return out
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise InputError(f"cannot open EXR: {_oiio_error(oiio)}", file=path)
    try:
        for part_idx, names in by_part.items():
            if part_idx >= len(header.parts):
                raise InputError(f"no part {part_idx}", file=path)
            p = header.parts[part_idx]
            if not inp.seek_subimage(part_idx, 0):
                raise InputError(f"cannot seek to part {part_idx}", file=path)
            idxs = []
            for n in names:
                if n not in p.channels:
                    raise InputError(f"missing channel (found: {', '.join(p.channels)})",
                                     file=path, channel=n)
                idxs.append(p.channels.index(n))
            lo, hi = min(idxs), max(idxs) + 1
            # one decode of the channel range covering what is needed
            data = inp.read_image(part_idx, 0, lo, hi, "float")
            if data is None or (isinstance(data, np.ndarray) and data.size == 0):
                raise InputError(f"truncated or corrupt pixel data: "
                                 f"{_oiio_error(oiio, inp) or 'read failed'}", file=path)
            data = np.asarray(data, dtype=np.float32)
            if data.ndim == 2:
                data = data[:, :, None]
            for n, i in zip(names, idxs):
                plane = data[:, :, i - lo]
                if not p.full_data_window:
                    full = np.full((p.height, p.width), fill.get((part_idx, n), 0.0),
                                   np.float32)
                    x0, y0 = max(p.x, 0), max(p.y, 0)
                    x1 = min(p.x + p.data_width, p.width)
                    y1 = min(p.y + p.data_height, p.height)
                    if x1 > x0 and y1 > y0:
                        full[y0:y1, x0:x1] = plane[y0 - p.y:y1 - p.y, x0 - p.x:x1 - p.x]
                    plane = full
                out[(part_idx, n)] = np.ascontiguousarray(plane)
        err = inp.geterror()
        if err:
            raise InputError(f"truncated or corrupt pixel data: {' '.join(err.split())}",
                             file=path)
    finally:
        inp.close()
    return out


# OpenEXR standard attributes whose type cannot be told from a plain value
STANDARD_TYPES = {"chromaticities": "float[8]", "smpte:TimeCode": "timecode",
                  "smpte:KeyCode": "keycode", "framesPerSecond": "rational2i",
                  "worldToCamera": "matrix", "worldToNDC": "matrix",
                  "screenWindowCenter": "float2", "adoptedNeutral": "float2",
                  "screenWindowWidth": "float", "PixelAspectRatio": "float",
                  "whiteLuminance": "float", "xDensity": "float", "utcOffset": "float",
                  "expTime": "float", "aperture": "float", "isoSpeed": "float",
                  "focus": "float", "longitude": "float", "latitude": "float",
                  "altitude": "float"}


def _infer_type(value) -> str | None:
    if isinstance(value, bool):
        return "int"
    if isinstance(value, int):
        return "int"
    if isinstance(value, float):
        return "float"
    if isinstance(value, str):
        return "string"
    if isinstance(value, (list, tuple)) and value:
        if all(isinstance(v, str) for v in value):
            return f"string[{len(value)}]"
        flat = value
        if all(isinstance(v, (list, tuple)) for v in value):  # nested 4x4 / 3x3
            flat = [x for row in value for x in row]
        if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in flat):
            n = len(flat)
            if n == 16:
                return "matrix"
            if n == 9:
                return "matrix33"
            if n == 2:
                return "int2" if all(isinstance(v, int) for v in flat) else "float2"
            if n == 3:
                return "vector"
    return None


def _set_attr(spec, key: str, value, typename: str | None = None) -> None:
    oiio = _oiio()
    if value is None:
        return
    if isinstance(value, np.ndarray):
        value = value.tolist()
    t = typename or STANDARD_TYPES.get(key) or _infer_type(value)
    if t is None:  # anything else travels as JSON text
        try:
            spec.attribute(key, json.dumps(value))
        except (TypeError, ValueError):
            pass
        return
    if isinstance(value, (list, tuple)) and value and all(isinstance(v, (list, tuple))
                                                          for v in value):
        value = [x for row in value for x in row]
    if isinstance(value, bool):
        value = int(value)
    try:
        if t in ("int", "float", "string") and not isinstance(value, (list, tuple)):
            value = {"int": int, "float": float, "string": str}[t](value)
            spec.attribute(key, value)
        else:
            td = oiio.TypeDesc(t)
            if td.basetype in (oiio.FLOAT, oiio.DOUBLE, oiio.HALF):
                value = [float(v) for v in value] if isinstance(value, (list, tuple)) \
                    else float(value)
            spec.attribute(key, td, value)
    except Exception:  # a value that does not fit its type: keep it as text
        spec.attribute(key, str(value))


def _make_spec(channels: dict, types: dict | None, attributes: dict | None,
               attribute_types: dict | None, compression: str, tile: int | None = None,
               data_window: tuple[int, int, int, int] | None = None,
               display: tuple[int, int] | None = None):
    """data_window: (x, y, w, h) relative to the display window; channel arrays then have
    shape (h, w). display: (width, height) of the display window (default: array size)."""
    oiio = _oiio()
    names = list(channels)
    h, w = np.asarray(channels[names[0]]).shape
    types = types or {}
    fmts = [oiio.FLOAT if types.get(n, "half") == "float" else oiio.HALF for n in names]
    spec = oiio.ImageSpec(w, h, len(names),
                          oiio.FLOAT if all(f == oiio.FLOAT for f in fmts) else oiio.HALF)
    spec.channelnames = tuple(names)
    spec.channelformats = tuple(fmts)
    if data_window is not None or display is not None:
        dw, dh = display if display is not None else (w, h)
        x, y = (data_window[0], data_window[1]) if data_window is not None else (0, 0)
        spec.x, spec.y = x, y
        spec.full_x, spec.full_y, spec.full_width, spec.full_height = 0, 0, dw, dh
    if tile:
        spec.tile_width = spec.tile_height = int(tile)
    spec.attribute("compression", compression)
    # no write-time stamp (OpenImageIO would add the current time as capDate): the same
    # frame written twice gives the same bytes; a source frame's own DateTime is carried
    spec.attribute("DateTime", "")
    attribute_types = attribute_types or {}
    for k, v in (attributes or {}).items():
        if k in STRUCTURAL_ATTRIBUTES or k.startswith("oiio:") or k.startswith("openexr:"):
            continue
        _set_attr(spec, k, v, attribute_types.get(k))
    data = np.stack([np.asarray(channels[n], dtype=np.float32) for n in names], axis=-1)
    return spec, data


def _temp_in(folder: str, path: str) -> str:
    try:
        tmp = atomic.make_temp(folder, suffix=".exr")  # names its writer (stale-file cleanup)
    except OSError as e:
        raise OutputError(f"cannot write to output folder: {e.strerror}", file=path) from None
    return tmp


def _finish(tmp: str, path: str) -> None:
    # mkstemp makes 0600 files; give the output the permissions a plain open() would
    umask = os.umask(0)
    os.umask(umask)
    try:
        os.chmod(tmp, 0o666 & ~umask)
    except OSError:
        pass
    try:
        atomic.replace(tmp, path)  # data on disk, then the rename
    except OSError as e:
        raise OutputError(f"cannot rename into place: {e.strerror}", file=path) from None


def write_exr(path: str, channels: dict[str, np.ndarray], types: dict[str, str] | None = None,
              attributes: dict | None = None, compression: str = "zip", *,
              attribute_types: dict | None = None, tile: int | None = None,
              data_window: tuple[int, int, int, int] | None = None,
              display: tuple[int, int] | None = None) -> None:
    """Write one single-part EXR atomically (temporary file in the target folder + rename).

    channels: name -> (H, W) array; types: name -> 'half' | 'float' (default half).
    attributes: header metadata; attribute_types: name -> OIIO type name (optional).
    tile: tile size for a tiled file (default scanline).
    """
    write_parts(path, [dict(channels=channels, types=types, attributes=attributes,
                            attribute_types=attribute_types, data_window=data_window,
                            display=display)], compression=compression, tile=tile)


def write_parts(path: str, parts: list[dict], compression: str = "zip",
                tile: int | None = None) -> None:
    """Write a (multi-part) EXR atomically. Each part is a dict with `channels`, and optional
    `types`, `attributes`, `attribute_types`, `name`, `view`, `data_window` (x, y, w, h) and
    `display` (width, height). All parts are tiled (tile=N) or all scanline."""
    oiio = _oiio()
    path = str(path)
    if not parts or not all(p.get("channels") for p in parts):
        raise OutputError("nothing to write", file=path)
    specs, datas = [], []
    for p in parts:
        spec, data = _make_spec(p["channels"], p.get("types"), p.get("attributes"),
                                p.get("attribute_types"), compression, tile,
                                p.get("data_window"), p.get("display"))
        for k in ("name", "view"):  # part structure: from the part dict, not attributes
            spec.erase_attribute(k)
        if p.get("name") is not None:
            spec.attribute("name", p["name"])
        elif len(parts) > 1:
            spec.attribute("name", f"part{len(specs)}")
        if p.get("view") is not None:
            spec.attribute("view", p["view"])
        specs.append(spec)
        datas.append(data)
    folder = os.path.dirname(os.path.abspath(path))
    tmp = _temp_in(folder, path)
    try:
        out = oiio.ImageOutput.create(tmp)
        if out is None:
            raise OutputError(f"cannot create EXR writer: {_oiio_error(oiio)}", file=path)
        ok = out.open(tmp, tuple(specs)) if len(specs) > 1 else out.open(tmp, specs[0])
        if not ok:
            raise OutputError(f"cannot open for writing: {_oiio_error(oiio, out)}", file=path)
        for i, (spec, data) in enumerate(zip(specs, datas)):
            if i > 0 and not out.open(tmp, spec, "AppendSubimage"):
                raise OutputError(f"cannot write part {i}: {_oiio_error(oiio, out)}",
                                  file=path)
            if not out.write_image(data):
                raise OutputError(f"write failed: {_oiio_error(oiio, out)}", file=path)
        if not out.close():
            raise OutputError(f"write failed: {_oiio_error(oiio, out)}", file=path)
        _finish(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
