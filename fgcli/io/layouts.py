"""Layouts: map a file's channel names and conventions onto the internal convention.

Each layout is an object with
  name, detect(header) -> score (0 = no), read(header, number, view, fields) -> Frame,
  encode(frame, half) -> (channels, types).
"""
from __future__ import annotations

import json

import numpy as np

from fgcli.errors import InputError, UsageError
from fgcli.frame import Camera, Frame
from fgcli.io import exr


def _torch():
    import torch

    return torch


def _clean_nonfinite(arr: np.ndarray, path: str, number: int, name: str, stats: dict | None):
    bad = ~np.isfinite(arr)
    if bad.any():
        if stats is not None:
            stats.setdefault(name, []).append((number, int(bad.sum())))
        arr = np.where(bad, 0.0, arr).astype(np.float32)
    return arr


class FgenLayout:
    """The canonical layout fgen writes (see docs/conventions.md)."""

    name = "fgen"

    def channels(self):
        from fgcli.io.frames import FGEN_CHANNELS

        return FGEN_CHANNELS

    def detect(self, header: exr.Header) -> int:
        ch = set(header.parts[0].channels)
        return 10 if {"R", "G", "B", "mv.x", "mv.y"} <= ch else (
            1 if {"R", "G", "B"} <= ch else 0)

    def read(self, header: exr.Header, number: int, view: str | None = None,
             fields: set[str] | None = None, nonfinite: dict | None = None) -> Frame:
        torch = _torch()
        p = header.parts[0]
        mapping = self.channels()
        want = {}
        for fld, names in mapping.items():
            if fields is not None and fld not in fields and fld != "color":
                continue
            if all(n in p.channels for n in names):
                want[fld] = names
            elif fld in ("color",) or (fields is not None and fld in fields and fld in ("depth", "mv")):
                missing = [n for n in names if n not in p.channels]
                raise InputError(
                    f"missing channels {missing} for {fld} (layout '{self.name}'; found: "
                    f"{', '.join(p.channels)})", file=header.path, frame=number, channel=missing[0])
        arrays = exr.read_channels(header.path, [(0, n) for ns in want.values() for n in ns], header)
        kw = {}
        for fld, names in want.items():
            a = np.stack([arrays[(0, n)] for n in names])
            if fld == "depth":
                a = np.where(np.isnan(a), np.inf, a)  # keep +inf sky
            elif fld in ("color", "mv", "alpha", "albedo", "roughness", "normal"):
                a = _clean_nonfinite(a, header.path, number, fld, nonfinite)
            kw[fld] = torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))
        cam = camera_from_header(header)
        return Frame(number=number, camera=cam, header=dict(header.attributes),
                     source=header.path, **kw)

    def encode(self, frame: Frame, half: bool = True):
        from fgcli.io.frames import frame_to_fgen_channels

        return frame_to_fgen_channels(frame, half)


def camera_from_header(header: exr.Header) -> Camera | None:
    a = header.attributes
    if "fgen:world_to_camera" in a and "fgen:projection" in a:
        try:
            return Camera(np.asarray(json.loads(a["fgen:world_to_camera"])),
                          np.asarray(json.loads(a["fgen:projection"])))
        except ValueError:
            return None
    return None


LAYOUTS = {"fgen": FgenLayout()}


def get(name: str):
    if name not in LAYOUTS:
        raise UsageError(f"unknown layout '{name}' (known: {', '.join(LAYOUTS)})")
    return LAYOUTS[name]


def resolve(layout, header: exr.Header):
    if layout is None or layout == "auto":
        scored = sorted(((l.detect(header), n) for n, l in LAYOUTS.items()), reverse=True)
        if not scored or scored[0][0] <= 0:
            raise InputError(f"cannot detect the layout from channels "
                             f"{[c for _, c, _ in header.all_channels()]} (tried: "
                             f"{', '.join(LAYOUTS)}); pass --layout", file=header.path)
        return LAYOUTS[scored[0][1]]
    if isinstance(layout, str):
        return get(layout)
    return layout


def encode(frame: Frame, layout: str = "fgen", half: bool = True):
    return get(layout).encode(frame, half)
