"""Frame-level read/write in the `fgen` layout, and the sequence reader every command uses.

Other layouts (blender, nuke, multi-view, user TOML) plug in through fgcli.io.layouts.
"""
from __future__ import annotations

import json
import os

import numpy as np

from fgcli import __version__
from fgcli.errors import InputError
from fgcli.frame import Camera, Frame
from fgcli.io import exr

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
    chans: dict[str, np.ndarray] = {}
    types: dict[str, str] = {}
    for fld, names in FGEN_CHANNELS.items():
        t = getattr(frame, fld)
        if t is None:
            continue
        a = t.detach().cpu().numpy() if hasattr(t, "detach") else np.asarray(t)
        for i, n in enumerate(names):
            chans[n] = a[i]
            types[n] = "float" if (not half or fld in FLOAT_FIELDS) else "half"
    return chans, types


def fgen_attributes(frame: Frame, extra: dict | None = None) -> dict:
    attrs = {}
    for k, v in (frame.header or {}).items():
        attrs[k] = v
    if frame.camera is not None:
        attrs["fgen:world_to_camera"] = json.dumps(frame.camera.to_json()["world_to_camera"])
        attrs["fgen:projection"] = json.dumps(frame.camera.to_json()["projection"])
    attrs["fgen:version"] = __version__
    attrs.update(extra or {})
    return attrs


def write_frame(path: str, frame: Frame, layout: str = "fgen", half: bool = True,
                compression: str = "zip", attributes: dict | None = None) -> None:
    """Write a Frame atomically. `attributes` are added as header metadata (fgen:* keys)."""
    from fgcli.io import layouts

    chans, types = layouts.encode(frame, layout, half=half)
    exr.write_exr(path, chans, types, fgen_attributes(frame, attributes), compression)


def read_frame(path: str, number: int, layout=None, view: str | None = None,
               fields: set[str] | None = None) -> Frame:
    """Read one frame into the internal convention. layout None = auto-detect."""
    from fgcli.io import layouts

    header = exr.read_header(path)
    lay = layouts.resolve(layout, header)
    return lay.read(header, number, view=view, fields=fields)


def load_sidecar_cameras(folder: str) -> dict[int, Camera]:
    p = os.path.join(folder, "cameras.json")
    if not os.path.isfile(p):
        return {}
    try:
        with open(p) as fh:
            data = json.load(fh)
        cams = {}
        for e in data["frames"]:
            cams[int(e["frame"])] = Camera(np.asarray(e["world_to_camera"], dtype=np.float64),
                                           np.asarray(e["projection"], dtype=np.float64))
        return cams
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise InputError(f"bad cameras.json: {e}", file=p) from None


def write_sidecar_cameras(folder: str, cams: dict[int, Camera], extra: dict | None = None) -> None:
    data = dict(extra or {})
    data["frames"] = [{"frame": n, **cams[n].to_json()} for n in sorted(cams)]
    tmp = os.path.join(folder, ".fgen-tmp-cameras.json")
    with open(tmp, "w") as fh:
        json.dump(data, fh, indent=1)
    os.replace(tmp, os.path.join(folder, "cameras.json"))
