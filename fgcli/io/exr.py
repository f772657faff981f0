"""Low-level OpenEXR access through OpenImageIO, numpy only (no torch import here).

Channels are always looked up by name (OpenEXR re-sorts them). Every part of a multi-part
file is listed; data windows smaller than the display window are padded (with 0) to the
display window; half and float channels in one file, scanline or tiled, all read as float32.
"""
from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field

import numpy as np

from fgcli.errors import InputError, OutputError


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

    def all_channels(self) -> list[tuple[int, str, str]]:
        """(part index, channel name, format) for every channel of every part."""
        return [(p.index, c, f) for p in self.parts for c, f in zip(p.channels, p.formats)]


def _attr_value(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (tuple, list)):
        return [_attr_value(x) for x in v]
    return v


def _spec_attributes(spec) -> dict:
    out = {}
    for p in spec.extra_attribs:
        try:
            out[p.name] = _attr_value(p.value)
        except Exception:  # pragma: no cover - exotic attribute types
            continue
    return out


def _check_file(path: str) -> None:
    if not os.path.isfile(path):
        raise InputError("file not found", file=path)
    with open(path, "rb") as fh:
        magic = fh.read(4)
    if magic != b"\x76\x2f\x31\x01":
        raise InputError("not an OpenEXR file (bad magic number)", file=path)


def read_header(path: str) -> Header:
    oiio = _oiio()
    path = str(path)
    _check_file(path)
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise InputError(f"cannot open EXR: {oiio.geterror().strip() or 'corrupt header'}", file=path)
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
            attrs = _spec_attributes(s)
            parts.append(Part(
                index=idx, name=attrs.get("name") or attrs.get("oiio:subimagename"),
                view=attrs.get("view"), channels=names, formats=fmts,
                width=s.full_width, height=s.full_height, x=s.x - s.full_x, y=s.y - s.full_y,
                data_width=s.width, data_height=s.height, tiled=s.tile_width > 0,
                attributes=attrs))
            idx += 1
    finally:
        inp.close()
    if not parts:
        raise InputError("EXR has no readable parts", file=path)
    return Header(path=path, parts=parts)


def read_channels(path: str, wanted: list[tuple[int, str]], header: Header | None = None
                  ) -> dict[tuple[int, str], np.ndarray]:
    """Read the named channels ((part, name) pairs) as float32 (H, W) arrays on the display
    window. Only the parts and contiguous channel runs needed are decoded."""
    oiio = _oiio()
    path = str(path)
    header = header or read_header(path)
    by_part: dict[int, list[str]] = {}
    for part, name in wanted:
        by_part.setdefault(part, []).append(name)
    out: dict[tuple[int, str], np.ndarray] = {}
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise InputError(f"cannot open EXR: {oiio.geterror().strip()}", file=path)
    try:
        for part_idx, names in by_part.items():
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
            # one contiguous decode of the channel range covering what is needed
            data = inp.read_image(part_idx, 0, lo, hi, "float")
            if data is None or (isinstance(data, np.ndarray) and data.size == 0):
                raise InputError(f"truncated or corrupt pixel data: {inp.geterror().strip()}",
                                 file=path)
            data = np.asarray(data, dtype=np.float32)
            if data.ndim == 2:
                data = data[:, :, None]
            for n, i in zip(names, idxs):
                plane = data[:, :, i - lo]
                if (p.x, p.y, p.data_width, p.data_height) != (0, 0, p.width, p.height):
                    full = np.zeros((p.height, p.width), np.float32)
                    x0, y0 = max(p.x, 0), max(p.y, 0)
                    x1 = min(p.x + p.data_width, p.width)
                    y1 = min(p.y + p.data_height, p.height)
                    if x1 > x0 and y1 > y0:
                        full[y0:y1, x0:x1] = plane[y0 - p.y:y1 - p.y, x0 - p.x:x1 - p.x]
                    plane = full
                out[(part_idx, n)] = np.ascontiguousarray(plane)
        err = inp.geterror()
        if err:
            raise InputError(f"truncated or corrupt pixel data: {err.strip()}", file=path)
    finally:
        inp.close()
    return out


def _set_attr(spec, key: str, value) -> None:
    if isinstance(value, bool):
        spec.attribute(key, int(value))
    elif isinstance(value, (int, float, str)):
        spec.attribute(key, value)
    elif isinstance(value, (list, tuple)) and len(value) == 16 and all(
            isinstance(v, (int, float)) for v in value):
        oiio = _oiio()
        spec.attribute(key, oiio.TypeDesc("matrix"), [float(v) for v in value])
    elif isinstance(value, (list, tuple)) and all(isinstance(v, (int, float)) for v in value):
        spec.attribute(key, str(list(value)))
    # other types (nested, None) are not carried over


def write_exr(path: str, channels: dict[str, np.ndarray], types: dict[str, str] | None = None,
              attributes: dict | None = None, compression: str = "zip") -> None:
    """Write one single-part EXR atomically (temporary file in the target folder + rename).

    channels: name -> (H, W) array; types: name -> 'half' | 'float' (default half).
    """
    oiio = _oiio()
    path = str(path)
    names = list(channels)
    if not names:
        raise OutputError("nothing to write", file=path)
    h, w = channels[names[0]].shape
    types = types or {}
    fmts = [oiio.FLOAT if types.get(n, "half") == "float" else oiio.HALF for n in names]
    spec = oiio.ImageSpec(w, h, len(names), oiio.FLOAT if all(f == oiio.FLOAT for f in fmts) else oiio.HALF)
    spec.channelnames = tuple(names)
    spec.channelformats = tuple(fmts)
    spec.attribute("compression", compression)
    for k, v in (attributes or {}).items():
        if k in ("compression", "oiio:ColorSpace") or k.startswith("oiio:") or k in (
                "name", "view", "type", "chunkCount", "version", "tiles"):
            continue
        _set_attr(spec, k, v)
    data = np.stack([np.asarray(channels[n], dtype=np.float32) for n in names], axis=-1)
    folder = os.path.dirname(os.path.abspath(path))
    try:
        fd, tmp = tempfile.mkstemp(prefix=".fgen-tmp-", suffix=".exr", dir=folder)
        os.close(fd)
    except OSError as e:
        raise OutputError(f"cannot write to output folder: {e.strerror}", file=path) from None
    try:
        out = oiio.ImageOutput.create(tmp)
        if out is None or not out.open(tmp, spec):
            raise OutputError(f"cannot open for writing: {oiio.geterror().strip()}", file=path)
        ok = out.write_image(data)
        out.close()
        if not ok:
            raise OutputError(f"write failed: {out.geterror().strip()}", file=path)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
