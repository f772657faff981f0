"""Contact sheet of scenes: color at the first, middle and last input frame, then depth and
motion vectors of the middle frame, one row per scene (PNG)."""
from __future__ import annotations

import os

import numpy as np

from fgcli.errors import OutputError
from fgcli.synth.tracer import render
from fgcli.synth.scene import Scene

COLUMNS = ("first", "middle", "last", "depth", "motion")


def _srgb8(color: np.ndarray) -> np.ndarray:
    """(3, H, W) linear -> (H, W, 3) uint8 sRGB."""
    from fgcli.ops.color import srgb_oetf

    x = srgb_oetf(np.transpose(color, (1, 2, 0)))
    return np.ascontiguousarray((x * 255.0 + 0.5).astype(np.uint8))


def _depth8(depth: np.ndarray) -> np.ndarray:
    import cv2

    d = depth[0]
    fin = np.isfinite(d)
    inv = np.zeros_like(d)
    if fin.any():
        inv[fin] = d[fin].min() / d[fin]
    g = (np.clip(inv, 0, 1) * 255).astype(np.uint8)
    rgb = cv2.applyColorMap(g, cv2.COLORMAP_VIRIDIS)[:, :, ::-1]
    rgb[~fin] = 0
    return np.ascontiguousarray(rgb)


def _motion8(mv: np.ndarray) -> np.ndarray:
    """Direction as hue, length as brightness (full at 4% of the frame width)."""
    import cv2

    dx, dy = mv[0], mv[1]
    mag = np.hypot(dx, dy)
    ang = (np.degrees(np.arctan2(dy, dx)) % 360) / 2
    val = np.clip(mag / (0.04 * mv.shape[2]), 0, 1) * 255
    hsv = np.stack([ang, np.full_like(ang, 255), val], -1)
    return np.ascontiguousarray(cv2.cvtColor(hsv.astype(np.uint8), cv2.COLOR_HSV2RGB))


def _label(img: np.ndarray, text: str) -> None:
    """White text on a darkened strip along the top of the tile."""
    import cv2

    strip = img[:17]
    strip[:] = (strip.astype(np.uint16) * 2 // 5).astype(np.uint8)
    cv2.putText(img, text, (4, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (255, 255, 255), 1,
                cv2.LINE_AA)


def contact_sheet(scenes: list[Scene], spp: int | None = None, gap: int = 4) -> np.ndarray:
    """(H, W, 3) uint8 RGB: one row per scene, COLUMNS across."""
    rows = []
    for sc in scenes:
        last = sc.frames - 1
        mid = last // 2
        tiles = []
        for name, t in (("first", 0), ("middle", mid), ("last", last)):
            f = render(sc, t, t - 1, spp=spp)
            img = _srgb8(f.color.numpy())
            _label(img, f"{sc.name} t={t}" if name == "first" else f"t={t}")
            tiles.append(img)
            if name == "middle":
                mf = f
        d = _depth8(mf.depth.numpy())
        _label(d, "depth")
        m = _motion8(mf.mv.numpy())
        _label(m, "motion vectors")
        tiles += [d, m]
        h = max(x.shape[0] for x in tiles)
        pad = [np.pad(x, ((0, h - x.shape[0]), (0, gap), (0, 0)), constant_values=255)
               for x in tiles]
        rows.append(np.concatenate(pad, 1)[:, :-gap])
    w = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, gap), (0, w - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    return np.concatenate(rows, 0)[:-gap]


def write_contact_sheet(scenes: list[Scene], path: str, spp: int | None = None) -> tuple[int, int]:
    import cv2

    sheet = contact_sheet(scenes, spp)
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise OutputError("folder does not exist", file=folder)
    tmp = os.path.join(folder, f".fgen-tmp-{os.getpid()}.png")
    if not cv2.imwrite(tmp, np.ascontiguousarray(sheet[:, :, ::-1])):
        raise OutputError("cannot write PNG", file=path)
    os.replace(tmp, path)
    return sheet.shape[1], sheet.shape[0]

