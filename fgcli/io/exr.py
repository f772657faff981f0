"""Low-level OpenEXR access through the OpenEXR library's own binding where it carries a
file exactly (one decode pass per read, no mixed-type conversion per write: see
_read_openexr, _write_openexr) and OpenImageIO for everything else; numpy only (no torch
import here).

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
import mmap
import os
import re
import stat
import struct
import sys
import tempfile
import threading
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from fgcli.errors import InputError, OutputError
from fgcli.io import atomic

# attributes that describe the file's structure, not its content: never carried over
STRUCTURAL_ATTRIBUTES = {"compression", "type", "chunkCount", "version", "tiles",
                         "DateTime", "dataWindow", "displayWindow", "lineOrder", "channels"}
COMPRESSIONS = ("zip", "zips", "piz", "none", "rle", "pxr24", "b44", "b44a", "dwaa", "dwab",
                "zstd")
# zstd (lossless; OpenEXR 3.4 and later, so older readers cannot open it): about half the
# bytes and 0.6x the time of zip on float depth and vectors (docs/performance.md)


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
    def overscan(self) -> bool:
        """True when the data window reaches outside the display window."""
        return (self.x < 0 or self.y < 0 or self.x + self.data_width > self.width
                or self.y + self.data_height > self.height)

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
    data_bytes: int = 0  # bytes after the header (offset table and chunks)
    least_bytes: int = 0  # the fewest bytes the header's chunks can take (exr.py rule 3)

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


def _text(s: str) -> str:
    """A name or string value from a header as printable, writable text.

    OpenImageIO hands over bytes that are not UTF-8 as lone surrogates ('\udcff'); those
    cannot be printed or written back into an EXR (OpenImageIO raises on them), so they
    become U+FFFD here."""
    try:
        s.encode("utf-8")
        return s
    except UnicodeEncodeError:
        try:
            return s.encode("utf-8", "surrogateescape").decode("utf-8", "replace")
        except UnicodeEncodeError:
            return s.encode("utf-8", "replace").decode("utf-8")


def _attr_value(v):
    if isinstance(v, str):
        return _text(v)
    if isinstance(v, np.ndarray):
        return _attr_value(v.tolist()) if v.dtype.kind in "OUS" else v.tolist()
    if isinstance(v, (tuple, list)):
        return [_attr_value(x) for x in v]
    return v


def _spec_attributes(spec) -> tuple[dict, dict]:
    out, types = {}, {}
    for p in spec.extra_attribs:
        try:
            name = _text(p.name)
            out[name] = _attr_value(p.value)
            types[name] = str(p.type)
        except Exception:  # pragma: no cover - exotic attribute types
            continue
    return out, types


# -- hostile input ----------------------------------------------------------------------
# Every read starts with cheap checks on the header alone, so that a corrupt or hostile file
# ends in an InputError naming it, never in a crash, a hang or a huge allocation. No pixel is
# read for them, and a valid file's reading costs one extra 64 KiB read of its start.
#
# 1. Attributes: the header is walked in Python (its first 64 KiB are read; a longer header
#    is mapped, so only its pages are touched): more than MAX_ATTRIBUTES attributes in all
#    parts are refused, because OpenEXR's header parsing time grows with the square of the
#    count (20000 attributes: 4 s per open, 100000: minutes) and every attribute would be
#    carried into the outputs. Real renders carry tens to a few hundred.
# 2. OpenImageIO itself refuses windows over 2^20 pixels a side ("limits:resolution"), over
#    1024 channels ("limits:channels"), tiles or data windows too big for memory or absurd
#    for the file's size; OpenEXR refuses inconsistent windows, channel lists, tile
#    descriptions, chunk counts and chunk headers (it rebuilds a damaged offset table from
#    the chunks themselves when it can: such a file reads completely and correctly).
# 3. File size (read_channels; parts summed): the offset table holds 8 bytes per chunk,
#    every chunk starts with its coordinates and size (8 bytes scanline, 20 tiled), and no
#    codec packs pixels tighter than its bound in _MAX_RATIO (deflate (zip, zips): 1032:1;
#    PXR24 cuts floats to 24 bits first: 1376:1; RLE: 127 bytes in 2; PIZ: a Huffman run
#    code of >= 10 bits stands for at most 256 16-bit values; B44A: 3 bytes per flat 4x4
#    block of halves, floats stored raw; none: 1:1; DWAA/DWAB and HTJ2K: no bound, a
#    constant DWAB frame reaches 20000:1, so only the table counts). A file shorter than
#    header + chunks x (8 + chunk header) + raw pixel bytes / bound is truncated or its
#    header lies: its pixels are refused before OpenImageIO allocates for them. Raw bytes:
#    data window x bytes per sample of every channel (level 0 of a mipmap: a lower bound).
# 4. Memory: fgen decodes to float32 and pads every channel it reads to the display window,
#    so a part whose float32 data- or display-window plane alone is larger than this
#    machine's physical memory is refused when its header is read, and a read whose planes
#    together (data window x channels read, plus display window x channels when padded)
#    exceed physical memory is refused before decoding.
# 5. Tiles: OpenEXR decodes whole tiles (16x1048576 tiles on a 32x24 image: 1 GB and 2 s
#    before it fails), so the data window rounded up to whole tiles may be at most twice
#    the data window, or 1024, on each axis. Real files use tiles of 16 to 512.
# Non-finite pixel values are data, not corruption: they are read as they are. Text that is
# not UTF-8 (names, string attributes) becomes U+FFFD (_text). No crash of OpenImageIO 3.2
# itself was found in 110,000 mutated files (every compression, tiled, mipmapped and
# multi-part), so reads stay in-process.
MAX_ATTRIBUTES = 10000
MAX_TILE_PAD = 1024  # rule 5
_MAGIC = b"\x76\x2f\x31\x01"
# scanlines per chunk of each compression (OpenEXR); a tiled part has one tile per chunk
_ROWS_PER_CHUNK = {"none": 1, "rle": 1, "zips": 1, "zip": 16, "pxr24": 16, "piz": 32,
                   "b44": 32, "b44a": 32, "dwaa": 32, "dwab": 256, "htj2k": 32}
# most raw bytes one compressed byte can stand for (rule 3; with a margin over the bounds)
_MAX_RATIO = {"none": 1, "rle": 64, "zips": 1100, "zip": 1100, "pxr24": 1400, "piz": 512,
              "b44": 11, "b44a": 11}
_SAMPLE_BYTES = {"half": 2, "float": 4, "uint": 4, "uint32": 4}


def _memory_bytes() -> int:
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, OSError, ValueError):  # pragma: no cover - non-POSIX
        return 1 << 40


MEMORY_BYTES = _memory_bytes()


def _gib(n: int) -> str:
    return f"{n / (1 << 30):.1f} GiB"


_INT = struct.Struct("<i")
_HEAD_READ = 1 << 16  # bytes read to walk a header (rule 1); a longer one is mapped


def _walk_header(buf, path: str) -> int:
    """Offset of the first byte after the header(s) in `buf` (the file's first bytes), -1
    when the header goes on past `buf`, 0 when it is too damaged to walk (OpenImageIO
    reports that better). Counts attributes: InputError past MAX_ATTRIBUTES; decides on
    nothing else."""
    multipart = bool(_INT.unpack_from(buf, 4)[0] & 0x1000)
    find, unpack, size = buf.find, _INT.unpack_from, len(buf)
    pos, count = 8, 0
    while True:  # one header per part; a multi-part file ends its list with an empty header
        while True:
            end = find(b"\0", pos)
            if end == pos:  # the empty name ending this header
                pos += 1
                break
            tend = find(b"\0", end + 1) if end > 0 else -1
            if tend < 0 or tend + 5 > size:  # runs past `buf` (or past the file)
                return -1
            (n,) = unpack(buf, tend + 1)
            if n < 0:
                return 0
            pos = tend + 5 + n
            count += 1
            if count > MAX_ATTRIBUTES:
                raise InputError(f"corrupt or hostile header: more than {MAX_ATTRIBUTES} "
                                 f"attributes", file=path)
        if not multipart:
            return pos
        if pos >= size:
            return -1
        if buf[pos] == 0:  # the empty header ending the list
            return pos + 1


def _check_file(path: str) -> tuple[int, int]:
    """(file size, offset of the end of the header or 0 when unknown); InputError when the
    file is missing, not an EXR or has absurdly many attributes (rule 1 above)."""
    try:
        st = os.stat(path)
    except OSError:
        st = None
    if st is None or not stat.S_ISREG(st.st_mode):
        raise InputError("file not found", file=path)
    size = st.st_size
    try:
        with open(path, "rb", buffering=0) as fh:
            buf = fh.read(_HEAD_READ)
            if buf[:4] != _MAGIC:
                raise InputError("not an OpenEXR file (bad magic number)", file=path)
            if len(buf) < 8:
                raise InputError("truncated file (no complete header)", file=path)
            end = _walk_header(buf, path)
            if end < 0 and len(buf) < size:  # a long header: walk it in place
                try:
                    with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as mm:
                        end = _walk_header(mm, path)
                except (OSError, ValueError):  # no mmap on this file system
                    fh.seek(0)
                    end = _walk_header(fh.read(1 << 24), path)
            return size, max(end, 0)
    except OSError as e:
        raise InputError(f"cannot read: {e.strerror or e}", file=path) from None


def _geterror(obj) -> str:
    """obj.geterror() (an ImageInput, or the OpenImageIO module for the global error) as one
    line; never raises (a corrupt file can put bytes that are not UTF-8 into the message,
    and OpenImageIO then raises while decoding it; the message is cleared either way)."""
    try:
        msg = obj.geterror() or ""
    except UnicodeDecodeError:
        msg = "(OpenImageIO's error message is not valid text)"
    except Exception as e:  # pragma: no cover - defensive
        msg = f"({type(e).__name__} while fetching OpenImageIO's error)"
    # OpenEXR names the file in every message; fgen's message names it already
    msg = re.sub(r"EXR Error \([^)]*\): ", "", _text(msg))
    return " ".join(msg.split())


def _oiio_error(oiio, inp=None) -> str:
    msg = _geterror(inp) if inp is not None else ""
    glob = _geterror(oiio)  # always fetched: a pending global error would be printed at exit
    return msg or glob


def _min_bytes(spec) -> int:
    """The fewest bytes a part's chunks (offset table included) can take (rule 3 above)."""
    w, h = max(int(spec.width), 1), max(int(spec.height), 1)
    comp = spec.get_string_attribute("compression", "").split(":")[0]
    if spec.tile_width > 0 and spec.tile_height > 0:
        chunks = -(-w // int(spec.tile_width)) * -(-h // int(spec.tile_height))
        chunk_bytes = 8 + 20
    else:
        rows = spec.get_int_attribute("oiio:RowsPerChunk", 0)
        if rows <= 0:
            rows = _ROWS_PER_CHUNK.get(comp, 256)
        chunks = -(-h // rows)
        chunk_bytes = 8 + 8
    fmts = spec.channelformats or [spec.format] * spec.nchannels
    raw = w * h * sum(_SAMPLE_BYTES.get(str(f), 1) for f in fmts)
    ratio = _MAX_RATIO.get(comp)
    return chunks * chunk_bytes + (raw // ratio if ratio else 0)


def _check_part(spec, index: int, path: str) -> int:
    """Header-only checks of one part (rules 4 and 5 above); returns its _min_bytes."""
    where = f"part {index}: " if index else ""
    if getattr(spec, "deep", False):
        raise InputError(f"{where}deep (multi-sample) EXR parts are not supported", file=path)
    for what, w, h in (("data", spec.width, spec.height),
                       ("display", spec.full_width, spec.full_height)):
        if w < 1 or h < 1:
            raise InputError(f"{where}corrupt header: empty {what} window {w}x{h}",
                             file=path)
        if 4 * w * h > MEMORY_BYTES:
            raise InputError(f"{where}corrupt header? {what} window {w}x{h}: one float "
                             f"channel of it needs {_gib(4 * w * h)}, more than this "
                             f"machine's {_gib(MEMORY_BYTES)} of memory", file=path)
    tw, th = int(spec.tile_width), int(spec.tile_height)
    if tw > 0 or th > 0:
        w, h = int(spec.width), int(spec.height)
        rw = -(-w // tw) * tw if tw > 0 else 0
        rh = -(-h // th) * th if th > 0 else 0
        if not (0 < rw <= max(2 * w, MAX_TILE_PAD) and 0 < rh <= max(2 * h, MAX_TILE_PAD)):
            raise InputError(f"{where}corrupt header: tiles of {tw}x{th} for a {w}x{h} data "
                             f"window", file=path)
    return _min_bytes(spec)


def read_header(path: str) -> Header:
    oiio = _oiio()
    path = str(path)
    size, header_end = _check_file(path)
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise InputError(f"cannot open EXR (truncated or corrupt header): "
                         f"{_oiio_error(oiio) or 'unknown error'}", file=path)
    try:
        # OpenEXR can skip a damaged attribute and open the file anyway, leaving only an
        # error message (on the ImageInput): the header is corrupt all the same
        err = _geterror(inp)
        if err:
            raise InputError(f"corrupt header: {err}", file=path)
        parts = []
        idx = 0
        least = 0
        while inp.seek_subimage(idx, 0):
            s = inp.spec()
            least += _check_part(s, idx, path)
            names = [_text(n) for n in s.channelnames]
            if s.channelformats:
                fmts = [str(f) for f in s.channelformats]
            else:
                fmts = [str(s.format)] * len(names)
            if len(fmts) != len(names):
                raise InputError("corrupt header: channel list and channel types differ "
                                 "in length", file=path)
            attrs, types = _spec_attributes(s)
            name = attrs.get("name") or attrs.get("oiio:subimagename")
            view = attrs.get("view")
            parts.append(Part(  # a name or view of another type than text is corrupt
                index=idx, name=name if isinstance(name, str) else None,
                view=view if isinstance(view, str) else None, channels=names, formats=fmts,
                width=s.full_width, height=s.full_height, x=s.x - s.full_x, y=s.y - s.full_y,
                data_width=s.width, data_height=s.height, tiled=s.tile_width > 0,
                attributes=attrs, attr_types=types))
            idx += 1
    finally:
        _oiio_error(oiio, inp)  # clear the "no such subimage" message of the last seek
        inp.close()
    if not parts:
        raise InputError("EXR has no readable parts", file=path)
    return Header(path=path, parts=parts, data_bytes=size - header_end, least_bytes=least)


# Channel spans (read_channels): every OpenImageIO read_image call inflates every chunk it
# touches whole (all channels of its scanlines), so one call per needed channel costs about
# a whole-file decode each; but one call over all channels converts, copies and returns
# every channel (a 1080p frame with 14 channels: 116 MB of float32 where 7 were needed).
# Measured on 1080p zip files (14 channels, OpenImageIO 3.2, one thread): a call costs
# ~80 ms plus ~5-25 ms per channel it returns. So the needed channels are read in spans of
# consecutive channels, two spans merging when fewer than _SPAN_GAP unneeded channels lie
# between them; a span of half channels is read as half (no conversion, half the bytes).
_SPAN_GAP = 3


def _spans(idxs: list[int], formats: list[str]) -> list[tuple[int, int, str]]:
    """(begin, end, read format) of the channel ranges covering the channel indices."""
    spans: list[list[int]] = []
    for i in sorted(set(idxs)):
        if spans and i - spans[-1][1] < _SPAN_GAP:
            spans[-1][1] = i + 1
        else:
            spans.append([i, i + 1])
    return [(lo, hi, "half" if all(f == "half" for f in formats[lo:hi]) else "float")
            for lo, hi in spans]


def read_channels(path: str, wanted: list[tuple[int, str]], header: Header | None = None,
                  fill: dict | None = None,
                  borders: dict | None = None) -> dict[tuple[int, str], np.ndarray]:
    """Read the named channels ((part, name) pairs) as float32 (H, W) arrays on the display
    window. Only the parts and the channel spans needed are decoded.

    The planes of one span's channels (full data window) are consecutive slices of one
    (C, H, W) float32 block, in channel order (layouts.planes() takes a field's channels
    from it without copying them again).
    fill: (part, name) -> value for display-window pixels outside the data window (default 0).
    borders: when given, a part whose data window reaches outside the display window (an
    overscan render) also leaves its uncropped planes there: (part, name) -> (plane
    (data_height, data_width), x, y), x and y the data window's origin relative to the
    display window's (negative for a border).
    InputError (naming the file, and the channel where one is at fault) for anything that
    does not decode completely: OpenImageIO's result is checked against the header.
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
    # what this read will allocate (rule 4 above), before anything is decoded
    need = 0
    for part_idx, names in by_part.items():
        if part_idx >= len(header.parts):
            raise InputError(f"no part {part_idx}", file=path)
        p = header.parts[part_idx]
        for n in names:
            if n not in p.channels:
                raise InputError(f"missing channel (found: {', '.join(p.channels)})",
                                 file=path, channel=n)
        idxs = [p.channels.index(n) for n in names]
        need += 4 * p.data_width * p.data_height * (max(idxs) - min(idxs) + 1)
        if not p.full_data_window:
            need += 4 * p.width * p.height * len(names)
    if header.data_bytes < header.least_bytes:  # rule 3 above
        p = header.parts[0]
        n = len(header.parts)
        raise InputError(f"truncated or corrupt file: the header describes "
                         f"{p.data_width}x{p.data_height} pixels x {len(p.channels)} channels"
                         f"{f' in {n} parts' if n > 1 else ''}, which cannot take less than "
                         f"{header.least_bytes} bytes after the header; the file has "
                         f"{header.data_bytes}", file=path)
    if need > MEMORY_BYTES:
        raise InputError(f"corrupt header? reading {len(wanted)} channels needs "
                         f"{_gib(need)}, more than this machine's {_gib(MEMORY_BYTES)} of "
                         f"memory", file=path)
    fast = _read_openexr(path, header, by_part)
    if fast is not None:
        for part_idx, names in by_part.items():
            p = header.parts[part_idx]
            for n in names:
                out[(part_idx, n)] = _place(fast[(part_idx, n)], p, part_idx, n, fill,
                                            borders)
        return out
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise InputError(f"cannot open EXR: {_oiio_error(oiio) or 'unknown error'}", file=path)
    try:
        for part_idx, names in by_part.items():
            p = header.parts[part_idx]
            if not inp.seek_subimage(part_idx, 0):
                raise InputError(f"cannot seek to part {part_idx}: "
                                 f"{_oiio_error(oiio, inp) or 'no such part'}", file=path)
            s = inp.spec()
            if (s.width, s.height, s.nchannels) != (p.data_width, p.data_height,
                                                    len(p.channels)):
                raise InputError("file changed while being read (header differs)", file=path)
            idxs = [p.channels.index(n) for n in names]
            what = names[0] if len(names) == 1 else None
            decoded = {}
            for lo, hi, fmt in _spans(idxs, p.formats):
                data = inp.read_image(part_idx, 0, lo, hi, fmt)
                err = _oiio_error(oiio, inp)
                if err or not isinstance(data, np.ndarray) or data.size == 0:
                    raise InputError(f"truncated or corrupt pixel data: "
                                     f"{err or 'read failed'}", file=path, channel=what)
                if data.ndim == 2:
                    data = data[:, :, None]
                if data.shape != (p.data_height, p.data_width, hi - lo):
                    raise InputError(f"corrupt pixel data: decoded {data.shape} values, the "
                                     f"header says {(p.data_height, p.data_width, hi - lo)}",
                                     file=path, channel=what)
                # the needed channels, channel-first float32: one converting copy
                here = sorted({i for i in idxs if lo <= i < hi})
                block = np.empty((len(here), p.data_height, p.data_width), np.float32)
                for j, i in enumerate(here):
                    block[j] = data[:, :, i - lo]
                    decoded[i] = block[j]
                del data
            for n, i in zip(names, idxs):
                out[(part_idx, n)] = _place(decoded[i], p, part_idx, n, fill, borders)
    finally:
        inp.close()
    return out


def _place(plane: np.ndarray, p: Part, part_idx: int, n: str, fill: dict,
           borders: dict | None) -> np.ndarray:
    """A decoded data-window plane on the display window (read_channels' fill and
    borders rules)."""
    if borders is not None and p.overscan:
        borders[(part_idx, n)] = (plane, p.x, p.y)
    if p.full_data_window:
        return plane
    full = np.full((p.height, p.width), fill.get((part_idx, n), 0.0), np.float32)
    x0, y0 = max(p.x, 0), max(p.y, 0)
    x1 = min(p.x + p.data_width, p.width)
    y1 = min(p.y + p.data_height, p.height)
    if x1 > x0 and y1 > y0:
        full[y0:y1, x0:x1] = plane[y0 - p.y:y1 - p.y, x0 - p.x:x1 - p.x]
    return full


# ------------------------------------------------------------------ the OpenEXR reader
# The OpenEXR binding decodes every channel of every part in one pass over the chunks,
# each channel in its own type. OpenImageIO's read_image inflates every chunk it touches
# whole, once per call, so fgen's spans of channels (2-3 for a renderer's layout: colour,
# depth, vectors) decode the file 2-3 times: ~2.5x the CPU at 1080p. The binding is used
# for files whose decoded pixels stay below FAST_READ_BYTES (a frame with dozens of layers
# goes span by span through OpenImageIO instead), and only when it returns exactly what
# the header describes; anything else (a corrupt chunk, subsampled or deep channels) is
# read again by OpenImageIO, which names the fault.
FAST_READ_BYTES = 512 << 20
# what the OpenEXR library prints on a damaged file (its C core on stderr, the binding on
# stdout) before fgen reports the file itself
_EXR_NOISE = re.compile(rb"^(Warning: Exception raised reading pixel data.*|"
                        rb".*\(EXR_ERR_[A-Z0-9_]+\).*)\r?\n?$")
_CAPTURE_LOCK = threading.Lock()


def _flush_all() -> None:
    """Python's and the C library's stdio buffers (the binding prints through the latter)."""
    for st in (sys.stdout, sys.stderr):
        try:
            if st is not None:
                st.flush()
        except (OSError, ValueError):
            pass
    try:
        import ctypes

        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError, TypeError):
        pass


class _DropLibraryLines:
    """sys.stdout while the binding reads: every write goes straight to the stream it
    wraps, except the binding's own warning line (it prints through Python)."""

    def __init__(self, stream):
        self._stream = stream
        self._drop_newline = False

    def write(self, text):
        if self._drop_newline:
            # the rest of the warning line: the binding prints it in pieces (print(a, b,
            # ...): "part", " ", "0", " ", "-", " ", message, "\n"), all dropped
            if "\n" not in text:
                return len(text)
            self._drop_newline = False
            rest = text.split("\n", 1)[1]
            if rest:
                self._stream.write(rest)
            return len(text)
        if _EXR_NOISE.match(text.encode("utf-8", "replace")):
            self._drop_newline = not text.endswith("\n")
            return len(text)
        return self._stream.write(text)

    def __getattr__(self, name):
        return getattr(self._stream, name)


@contextmanager
def _library_output_captured():
    """Hold back the OpenEXR library's messages on a damaged file while the block runs:
    its C core writes to file descriptor 2, which goes to a temporary file and afterwards,
    less those lines, to where it was going (another thread's output there is delayed by
    one file read, never lost); the binding prints through sys.stdout, which drops its
    warning line and passes everything else through at once. One block at a time."""
    with _CAPTURE_LOCK:
        try:
            _flush_all()
            tmp = tempfile.TemporaryFile()
        except (OSError, ValueError, AttributeError):
            yield  # nowhere to hold the lines (no writable temporary folder): as is
            return
        try:
            saved = os.dup(2)
        except (OSError, ValueError, AttributeError):
            tmp.close()
            yield  # no file descriptor to capture (an embedding host): as is
            return
        out = sys.stdout
        try:
            os.dup2(tmp.fileno(), 2)
            if out is not None:
                sys.stdout = _DropLibraryLines(out)
            yield
        finally:
            if out is not None:
                sys.stdout = out
            _flush_all()
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            keep = [ln for ln in tmp.read().splitlines(keepends=True)
                    if not _EXR_NOISE.match(ln)]
            tmp.close()
            if keep:
                try:
                    os.write(2, b"".join(keep))
                except OSError:
                    pass


def _read_openexr(path: str, header: Header, by_part: dict) -> dict | None:
    """The wanted channels ((part, name) -> float32 plane on the data window) decoded by
    the OpenEXR binding, or None (binding missing, file large, or not exactly what the
    header describes: then OpenImageIO reads it)."""
    ex = _openexr()
    if ex is None:
        return None
    total = sum(p.data_width * p.data_height * sum(2 if f == "half" else 4
                                                   for f in p.formats)
                for p in header.parts)
    if total > FAST_READ_BYTES:
        return None
    try:
        with _library_output_captured():
            fparts = ex.File(path, separate_channels=True).parts
    except Exception:  # noqa: BLE001 - OpenImageIO reads it again and names the fault
        return None
    if len(fparts) != len(header.parts):
        return None
    got = {}
    for part_idx, names in by_part.items():
        p = header.parts[part_idx]
        chans = fparts[part_idx].channels
        if sorted(chans) != sorted(p.channels):
            return None
        for n in names:
            a = chans[n].pixels
            if not isinstance(a, np.ndarray) or a.shape != (p.data_height, p.data_width) \
                    or a.dtype not in (np.float16, np.float32):
                return None  # subsampled or integer channels: OpenImageIO's path
            got[(part_idx, n)] = a.astype(np.float32)  # half widens exactly; an own copy
    return got


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


def _attr_plan(key: str, value, typename: str | None, *alt_keys: str):
    """(type name, value) of an attribute as both writers write it: the given type, a
    standard attribute's (under key or one of alt_keys), or one told from the value; nested
    lists flattened, bools as ints. Type None: the value travels as JSON text (value is
    then that text, or None when it has none)."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    t = typename or next((STANDARD_TYPES[k] for k in (key, *alt_keys) if k in STANDARD_TYPES),
                         None) or _infer_type(value)
    if t is None:
        try:
            return None, json.dumps(value)
        except (TypeError, ValueError):
            return None, None
    if isinstance(value, (list, tuple)) and value and all(isinstance(v, (list, tuple))
                                                          for v in value):
        value = [x for row in value for x in row]
    if isinstance(value, bool):
        value = int(value)
    return t, value


def _set_attr(spec, key: str, value, typename: str | None = None) -> None:
    oiio = _oiio()
    if value is None:
        return
    t, value = _attr_plan(key, value, typename)
    if t is None:  # anything else travels as JSON text
        if value is not None:
            spec.attribute(key, value)
        return
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


# ------------------------------------------------------------------ the OpenEXR writer
# OpenImageIO's Python write of a file whose channels mix half and float converts the
# float32 buffer channel by channel through a generic path: a 1080p 6-channel frame
# costs ~320 ms of CPU before compression (~410 ms with zip). The OpenEXR library's own
# binding takes each channel as a numpy array of its file type and writes the same
# pixels in ~200 ms with zip (docs/performance.md). fgen writes with it whenever every
# attribute has a type it carries exactly, and with OpenImageIO otherwise.

# OpenImageIO's names for standard OpenEXR attributes (as OpenImageIO's reader reports
# them) -> the OpenEXR names; derived OpenImageIO fields are dropped as it drops them
_EXR_NAMES = {"DateTime": "capDate", "ImageDescription": "comments", "Copyright": "owner",
              "PixelAspectRatio": "pixelAspectRatio", "XResolution": "xDensity",
              "ExposureTime": "expTime", "FNumber": "aperture"}
_OIIO_DERIVED = {"YResolution", "ResolutionUnit"}
_EXR_COMPRESSION = {"none": "NO_COMPRESSION", "rle": "RLE_COMPRESSION",
                    "zips": "ZIPS_COMPRESSION", "zip": "ZIP_COMPRESSION",
                    "piz": "PIZ_COMPRESSION", "pxr24": "PXR24_COMPRESSION",
                    "b44": "B44_COMPRESSION", "b44a": "B44A_COMPRESSION",
                    "dwaa": "DWAA_COMPRESSION", "dwab": "DWAB_COMPRESSION",
                    "zstd": "ZSTD_COMPRESSION"}
_VEC = {"float2": (np.float32, 2), "vector2": (np.float32, 2), "int2": (np.int32, 2),
        "vector2i": (np.int32, 2), "vector": (np.float32, 3), "float3": (np.float32, 3),
        "point": (np.float32, 3), "normal": (np.float32, 3), "matrix": (np.float32, 16),
        "matrix44": (np.float32, 16), "matrix33": (np.float32, 9),
        "matrixd": (np.float64, 16)}


_EXR_THREADS_SET = False


def _openexr():
    """The OpenEXR binding (PyPI `OpenEXR`, 3.3 or later), or None. Its global thread pool
    starts at one thread per core (OpenImageIO's default; the library's own is none) unless
    set_exr_threads() chose otherwise."""
    global _EXR_THREADS_SET
    try:
        import OpenEXR
    except ImportError:
        return None
    if not hasattr(OpenEXR, "File") or not hasattr(OpenEXR, "Part"):
        return None  # the pre-3.3 binding
    if not _EXR_THREADS_SET:
        _EXR_THREADS_SET = True
        if OpenEXR.global_thread_count() == 0:
            OpenEXR.set_global_thread_count(os.cpu_count() or 1)
    return OpenEXR


def exr_threads() -> int | None:
    """Threads the OpenEXR binding uses per file, reading or writing (None without it)."""
    exr = _openexr()
    return None if exr is None else max(1, exr.global_thread_count())


def set_exr_threads(n: int) -> None:
    """n threads per file for the OpenEXR binding (1: the calling thread alone)."""
    exr = _openexr()
    if exr is not None:
        exr.set_global_thread_count(0 if n <= 1 else int(n))


class _Unsupported(Exception):
    """An attribute (or layout) the OpenEXR writer does not carry exactly."""


def _exr_attr(key: str, value, typename: str | None):
    """(OpenEXR name, binding value) of one attribute, as _set_attr writes it through
    OpenImageIO; None to leave it out; _Unsupported for any other type."""
    if value is None or key in _OIIO_DERIVED:
        return None
    exr_key = _EXR_NAMES.get(key, key)
    t, value = _attr_plan(key, value, typename, exr_key)
    key = exr_key
    if t is None:
        return None if value is None else (key, value)
    try:
        if t == "int" and not isinstance(value, (list, tuple)):
            return key, int(value)
        if t == "float" and not isinstance(value, (list, tuple)):
            return key, float(value)
        if t == "string" and not isinstance(value, (list, tuple)):
            return key, str(value)
        if t.startswith("string[") and isinstance(value, (list, tuple)) and \
                all(isinstance(v, str) for v in value):
            return key, [str(v) for v in value]
        if t in _VEC and isinstance(value, (list, tuple)):
            dt, n = _VEC[t]
            a = np.asarray(value, dtype=dt)
            if a.size != n:
                raise _Unsupported(key)
            return key, a.reshape({16: (4, 4), 9: (3, 3)}.get(n, (n,)))
    except (TypeError, ValueError):
        pass
    raise _Unsupported(key)


def _write_openexr(tmp: str, parts: list[dict], compression: str) -> bool:
    """Write scanline parts with the OpenEXR binding (write_parts has checked that it is
    installed and knows the compression's name); False (nothing written) when this binding
    lacks the compression or something is not carried exactly (then OpenImageIO writes
    the file)."""
    exr = _openexr()
    comp = _EXR_COMPRESSION[compression]
    if not hasattr(exr, comp):
        return False
    if len({tuple(p.get("display") or np.asarray(next(iter(p["channels"].values()))).shape[::-1])
            for p in parts}) > 1:
        return False  # parts of different display windows: the library refuses them
    try:
        out = []
        for i, p in enumerate(parts):
            chans = p["channels"]
            names = list(chans)
            types = p.get("types") or {}
            h, w = np.asarray(chans[names[0]]).shape
            dw, dh = p.get("display") or (w, h)
            x, y = (p["data_window"][0], p["data_window"][1]) if p.get("data_window") \
                else (0, 0)
            hdr = {"compression": getattr(exr, comp), "type": exr.scanlineimage,
                   "dataWindow": (np.array([x, y], np.int32),
                                  np.array([x + w - 1, y + h - 1], np.int32)),
                   "displayWindow": (np.array([0, 0], np.int32),
                                     np.array([dw - 1, dh - 1], np.int32))}
            atypes = p.get("attribute_types") or {}
            for k, v in (p.get("attributes") or {}).items():
                if k in STRUCTURAL_ATTRIBUTES or k.startswith(("oiio:", "openexr:")) or \
                        k in ("name", "view"):
                    continue
                kv = _exr_attr(k, v, atypes.get(k))
                if kv is not None:
                    hdr[kv[0]] = kv[1]
            if p.get("view") is not None:
                hdr["view"] = str(p["view"])
            name = p.get("name")
            if name is None and len(parts) > 1:
                name = f"part{i}"
            data = {}
            for n in names:
                a = np.asarray(chans[n])
                if a.shape != (h, w):
                    raise _Unsupported(n)
                dt = np.float32 if types.get(n, "half") == "float" else np.float16
                with np.errstate(over="ignore", invalid="ignore"):  # beyond half: inf
                    data[n] = np.ascontiguousarray(a, dtype=dt)
            out.append((hdr, data, name))
    except _Unsupported:
        return False
    if len(out) == 1 and out[0][2] is None:
        f = exr.File(out[0][0], out[0][1])
    else:
        for hdr, _, name in out:
            hdr["name"] = name
        f = exr.File([exr.Part(hdr, data, name) for hdr, data, name in out])
    f.write(tmp)
    return True


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
    path = str(path)
    if not parts or not all(p.get("channels") for p in parts):
        raise OutputError("nothing to write", file=path)
    if _openexr() is not None and not tile and compression in _EXR_COMPRESSION:
        folder = os.path.dirname(os.path.abspath(path))
        tmp = _temp_in(folder, path)
        try:
            # not under _library_output_captured: its lock would make a write wait for a
            # read (the library reports write failures as exceptions, printing nothing)
            written = _write_openexr(tmp, parts, compression)
        except Exception:  # noqa: BLE001 - OpenImageIO writes it (or reports why not)
            written = False
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise
        if written:
            try:
                _finish(tmp, path)
            except BaseException:
                if os.path.exists(tmp):
                    os.unlink(tmp)
                raise
            return
        if os.path.exists(tmp):
            os.unlink(tmp)
    oiio = _oiio()
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
