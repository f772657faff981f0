"""The frame model every stage sees (docs/design.md section 2, docs/conventions.md).

Tensors are torch float32, channel-first (C, H, W). Pixel centres at integer + 0.5, x right,
y down, origin top-left.

- color: (3, H, W) linear scene-referred RGB (HDR).
- alpha: (1, H, W) or None; straight (not premultiplied) coverage as read from the file.
- depth: (1, H, W) linear view depth (along the camera forward axis), > 0, +inf for sky.
- mv: (2, H, W) pixels, from frame t to frame t-1: prev_xy = xy + mv[:, y, x].
- mv_valid: (1, H, W) bool or None; False where the layout says the vectors cannot be
  trusted (e.g. Blender writes 0 for sky pixels even when the camera moves).
- normal: (3, H, W) world-space unit normals or None; albedo (3, H, W); roughness (1, H, W).
- camera: Camera or None (world_to_camera and projection, OpenGL conventions).
- mv_fwd: (2, H, W) or None; forward vectors, pixels, from frame t to frame t+1:
  next_xy = xy + mv_fwd[:, y, x]. Only some layouts carry them (Blender, Nuke).
- header_types: OpenImageIO type names of the `header` attributes (so writers keep them).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np


@dataclass
class Camera:
    """Per-frame camera. Row-major 4x4 matrices applied to column vectors.

    world_to_camera: camera looks down -Z, +Y up (OpenGL/Blender).
    projection: camera (view) space -> clip space, NDC y up, x right, NDC in [-1, 1].
    """

    world_to_camera: np.ndarray
    projection: np.ndarray

    def to_json(self) -> dict:
        return {"world_to_camera": np.asarray(self.world_to_camera, dtype=float).tolist(),
                "projection": np.asarray(self.projection, dtype=float).tolist()}


# Names of the tensor fields of Frame, with their channel counts.
TENSOR_FIELDS = {"color": 3, "alpha": 1, "depth": 1, "mv": 2, "normal": 3, "albedo": 3,
                 "roughness": 1}


@dataclass
class Frame:
    number: int
    color: Any  # torch.Tensor (3, H, W)
    depth: Any = None
    mv: Any = None
    alpha: Any = None
    normal: Any = None
    albedo: Any = None
    roughness: Any = None
    mv_valid: Any = None
    camera: Camera | None = None
    header: dict = field(default_factory=dict)
    source: str | None = None
    time: float | None = None  # number + alpha for generated frames; defaults to number
    mv_fwd: Any = None  # (2, H, W) pixels toward frame t+1, y down; optional
    header_types: dict = field(default_factory=dict)  # header attribute -> OIIO type name
    # (x, y, w, h) of the pixels that carry data, within the (display-sized) tensors; None =
    # all of them. Outside it: no data (alpha 0, depth +inf, vectors invalid).
    data_window: tuple | None = None
    # an overscan render's pixels beyond the display window: {"origin": (x, y) of the
    # rendered region relative to the display window (negative: a border), "color": (3, He,
    # We), "depth": (1, He, We)}; None = the frame has no such border. Only stages that
    # can use it read it (gffe-extrap's hole fill); outputs never carry it.
    overscan: dict | None = None

    def _plane(self):
        # a G-buffer-only frame (written for a frame an engine did not shade) has no colour
        return self.color if self.color is not None else self.depth

    @property
    def height(self) -> int:
        return int(self._plane().shape[-2])

    @property
    def width(self) -> int:
        return int(self._plane().shape[-1])

    @property
    def t(self) -> float:
        return float(self.number if self.time is None else self.time)

    def replace(self, **kw) -> "Frame":
        return replace(self, **kw)

    def to(self, device) -> "Frame":
        kw = {}
        for name in list(TENSOR_FIELDS) + ["mv_valid", "mv_fwd"]:
            v = getattr(self, name)
            if v is not None:
                kw[name] = v.to(device)
        if self.overscan is not None:
            kw["overscan"] = {k: (v.to(device) if k != "origin" else v)
                              for k, v in self.overscan.items()}
        return replace(self, **kw)
