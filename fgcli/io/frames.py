"""Frame-level read/write (any layout, `fgen` by default) and sidecar cameras.

Other layouts (blender, nuke, multi-view, user TOML) plug in through fgcli.io.layouts.
"""
from __future__ import annotations

import json
import os

import numpy as np

from fgcli import __version__
from fgcli.errors import InputError, OutputError
from fgcli.frame import Camera, Frame
from fgcli.io import atomic, cameras, exr

# canonical fgen layout channel names
FGEN_CHANNELS = {
    "color": ["R", "G", "B"],
    "alpha": ["A"],
    "depth": ["Z"],
    "mv": ["mv.x", "mv.y"],
    "normal": ["N.x", "N.y", "N.z"],
    "albedo": ["albedo.R", "albedo.G", "albedo.B"],
    "roughness": ["roughness"],
}
# fields stored as float32 even when color is half: depth and vectors need the precision
FLOAT_FIELDS = {"depth", "mv"}


def frame_to_fgen_channels(frame: Frame, half: bool = True) -> tuple[dict, dict]:
    from fgcli.io import layouts

    return layouts.get("fgen").encode(frame, half)


# a written frame is one single-part, single-view image
_NOT_CARRIED = {"multiView", "name", "view"}


def fgen_attributes(frame: Frame, extra: dict | None = None) -> dict:
    """The header of an output frame: the source frame's metadata (minus its camera),
    the frame's camera (fgen JSON + OpenEXR worldToCamera/worldToNDC), fgen:version and
    `extra` (fgen:* provenance, see fgcli.io.output.fgen_attributes)."""
    attrs = {k: v for k, v in (frame.header or {}).items()
             if k not in cameras.CAMERA_ATTRIBUTES and k not in _NOT_CARRIED}
    attrs.update(cameras.header_attributes(frame.camera))
    attrs["fgen:version"] = __version__
    attrs.update(extra or {})
    return attrs


def write_frame(path: str, frame: Frame, layout="fgen", half: bool = True,
                compression: str = "zip", attributes: dict | None = None) -> None:
    """Write a Frame atomically in `layout` (a name, a .toml path or a layout object).
    `attributes` are added to the header (fgen:* keys)."""
    from fgcli.io import layouts

    chans, types = layouts.encode(frame, layout, half=half)
    if not chans:
        raise OutputError("frame has nothing this layout can write", file=path,
                          frame=frame.number)
    types_attr = dict(getattr(frame, "header_types", None) or {})
    types_attr.update(cameras.CAMERA_ATTRIBUTE_TYPES)
    for k in (attributes or {}):
        types_attr.pop(k, None)
    window = display = None
    dw = getattr(frame, "data_window", None)
    if dw is not None:  # write only the pixels that carry data (an EXR data window)
        h, w = frame.height, frame.width
        x, y, ww, hh = (int(v) for v in dw)
        if ww <= 0 or hh <= 0:  # nothing at all: one pixel (EXR needs a non-empty window)
            x, y, ww, hh = 0, 0, 1, 1
        if (x, y, ww, hh) != (0, 0, w, h):
            chans = {k: v[y:y + hh, x:x + ww] for k, v in chans.items()}
            window, display = (x, y, ww, hh), (w, h)
    exr.write_exr(path, chans, types, fgen_attributes(frame, attributes), compression,
                  attribute_types=types_attr, data_window=window, display=display)


def read_frame(path: str, number: int, layout=None, view: str | None = None,
               fields: set[str] | None = None) -> Frame:
    """Read one frame into the internal convention. layout None = auto-detect."""
    from fgcli.io import layouts

    header = exr.read_header(path)
    lay = layouts.resolve(layout, header)
    return lay.read(header, number, view=view, fields=fields)


def _sidecar_entries(folder: str):
    """(path, its "frames" entries) of `cameras.json` in `folder`; (path, None) when there
    is none. InputError naming the file when it does not parse."""
    p = os.path.join(str(folder), "cameras.json")
    if not os.path.isfile(p):
        return p, None
    try:
        with open(p) as fh:
            return p, list(json.load(fh)["frames"])
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise InputError(f"bad cameras.json: {e}", file=p) from None


def load_sidecar_cameras(folder: str) -> dict[int, Camera]:
    """Cameras from `cameras.json` in `folder` ({} when there is none). Format:
    {"frames": [{"frame": 12, "world_to_camera": [[4x4]], "projection": [[4x4]]}, ...]},
    row-major, column vectors, OpenGL camera (-Z forward, +Y up), NDC y up; other keys
    are ignored."""
    p, entries = _sidecar_entries(folder)
    if entries is None:
        return {}
    try:
        cams = {}
        for e in entries:
            if "world_to_camera" not in e and "projection" not in e:
                continue  # an entry with other facts only (jitter_px)
            w2c = np.asarray(e["world_to_camera"], dtype=np.float64)
            proj = np.asarray(e["projection"], dtype=np.float64)
            if w2c.shape != (4, 4) or proj.shape != (4, 4):
                raise ValueError(f"frame {e['frame']}: matrices must be 4x4")
            if not (np.isfinite(w2c).all() and np.isfinite(proj).all()):
                raise ValueError(f"frame {e['frame']}: non-finite matrix values")
            cams[int(e["frame"])] = Camera(w2c, proj)
        return cams
    except (ValueError, KeyError, TypeError) as e:
        raise InputError(f"bad cameras.json: {e}", file=p) from None


def load_sidecar_jitter(folder: str) -> dict[int, tuple[float, float]]:
    """Per-frame sub-pixel jitter from `cameras.json` ({} when none): entries
    {"frame": 12, "jitter_px": [jx, jy]} in input pixels, x right, y down (pixel (col, row)
    was sampled at (col + 0.5 + jx, row + 0.5 + jy) of the unjittered grid)."""
    p, entries = _sidecar_entries(folder)
    if entries is None:
        return {}
    try:
        out = {}
        for e in entries:
            if "jitter_px" not in e:
                continue
            j = [float(v) for v in e["jitter_px"]]
            if len(j) != 2 or not all(np.isfinite(j)):
                raise ValueError(f"frame {e['frame']}: jitter_px must be two finite numbers")
            out[int(e["frame"])] = (j[0], j[1])
        return out
    except (ValueError, KeyError, TypeError) as e:
        raise InputError(f"bad cameras.json: {e}", file=p) from None


def write_sidecar_cameras(folder: str, cams: dict[int, Camera], extra: dict | None = None) -> None:
    data = dict(extra or {})
    data["frames"] = [{"frame": n, **cams[n].to_json()} for n in sorted(cams)]
    atomic.write_text(os.path.join(folder, "cameras.json"), json.dumps(data, indent=1))
