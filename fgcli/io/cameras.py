"""Cameras: the internal Camera (OpenGL conventions) from and to EXR header attributes.

Internal (fgcli.frame.Camera, docs/design.md section 2): row-major 4x4 matrices applied to column
vectors; `world_to_camera` maps world to view space where the camera looks down -Z with +Y
up and +X right; `projection` maps view space to clip space, NDC = clip.xyz / clip.w in
[-1, 1] with x right and y up.

OpenEXR standard attributes (`worldToCamera`, `worldToNDC`): 4x4 matrices in the row-vector
convention (p' = p M), RenderMan-style left-handed camera space (looks down +Z, +Y up, +X
right), and NDC with (0, 0) at the top-left and (1, 1) at the bottom-right of the display
window (y down). The conversion (docs/conventions.md):

    world_to_camera = F @ worldToCamera^T             F = diag(1, 1, -1, 1)
    projection      = A @ worldToNDC^T @ inv(world_to_camera), then z row replaced
    A: x_clip = 2 x_ndc_h - w,  y_clip = w - 2 y_ndc_h  (EXR NDC -> OpenGL clip)

EXR NDC has no agreed depth mapping, so the projection's z row is rebuilt as OpenGL's for
near/far clip planes taken from the header (`nearClip`/`farClip`, `clipNear`/`clipFar`,
`nearClipPlane`/`farClipPlane`) or 0.1 / 10000.
"""
from __future__ import annotations

import json

import numpy as np

from fgcli.frame import Camera

F = np.diag([1.0, 1.0, -1.0, 1.0])
# EXR NDC (homogeneous, y down, [0, 1]) -> OpenGL clip (y up, [-1, 1]); z kept
A = np.array([[2.0, 0, 0, -1], [0, -2.0, 0, 1], [0, 0, 1.0, 0], [0, 0, 0, 1]])
A_INV = np.linalg.inv(A)
DEFAULT_NEAR, DEFAULT_FAR = 0.1, 10000.0
_NEAR_KEYS = ("nearClip", "clipNear", "nearClipPlane", "near")
_FAR_KEYS = ("farClip", "clipFar", "farClipPlane", "far")


def _mat(v) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    if a.size != 16:
        raise ValueError(f"expected a 4x4 matrix, got {a.size} values")
    a = a.reshape(4, 4)
    if not np.isfinite(a).all():
        raise ValueError("matrix has non-finite values")
    return a


def _clip(attrs: dict, keys, default: float) -> float:
    for k in keys:
        v = attrs.get(k)
        if isinstance(v, (int, float)) and np.isfinite(v) and v > 0:
            return float(v)
    return default


def gl_z_row(persp: bool, near: float, far: float) -> np.ndarray:
    if persp:
        return np.array([0, 0, -(far + near) / (far - near), -2 * far * near / (far - near)])
    return np.array([0, 0, -2 / (far - near), -(far + near) / (far - near)])


def from_exr(world_to_camera, world_to_ndc, near: float = DEFAULT_NEAR,
             far: float = DEFAULT_FAR) -> Camera:
    """Internal Camera from OpenEXR `worldToCamera` / `worldToNDC` (16 values each)."""
    m = _mat(world_to_camera)
    n = _mat(world_to_ndc)
    w2c = F @ m.T
    p = A @ n.T @ np.linalg.inv(w2c)
    w = p[3]
    scale = np.abs(w).max()
    if scale == 0:
        raise ValueError("worldToNDC has a zero w row")
    persp = abs(w[2]) > 1e-9 * scale and np.abs(w[[0, 1, 3]]).max() <= 1e-6 * abs(w[2])
    p = p / (-w[2] if persp else w[3] if abs(w[3]) > 1e-12 else scale)
    p[2] = gl_z_row(persp, near, far)
    return Camera(w2c, p)


def to_exr(cam: Camera) -> tuple[list[float], list[float]]:
    """OpenEXR (`worldToCamera`, `worldToNDC`) as 16 floats each, from an internal Camera."""
    w2c = np.asarray(cam.world_to_camera, dtype=np.float64)
    p = np.asarray(cam.projection, dtype=np.float64)
    m = (F @ w2c).T
    n = (A_INV @ p @ w2c).T
    return [float(v) for v in m.ravel()], [float(v) for v in n.ravel()]


def from_header_attributes(attrs: dict) -> tuple[Camera | None, str | None]:
    """(camera, where it came from) from one part's header attributes, or (None, None).

    `fgen:world_to_camera` / `fgen:projection` (JSON, internal convention, what fgen writes)
    win over the OpenEXR standard `worldToCamera` / `worldToNDC`.
    """
    if "fgen:world_to_camera" in attrs and "fgen:projection" in attrs:
        try:
            return Camera(_mat(json.loads(attrs["fgen:world_to_camera"])),
                          _mat(json.loads(attrs["fgen:projection"]))), "fgen header"
        except (ValueError, TypeError):
            pass
    if "worldToCamera" in attrs and "worldToNDC" in attrs:
        try:
            near = _clip(attrs, _NEAR_KEYS, DEFAULT_NEAR)
            far = _clip(attrs, _FAR_KEYS, DEFAULT_FAR)
            if far <= near:
                near, far = DEFAULT_NEAR, DEFAULT_FAR
            return from_exr(attrs["worldToCamera"], attrs["worldToNDC"], near, far), \
                "worldToCamera/worldToNDC"
        except (ValueError, TypeError, np.linalg.LinAlgError):
            return None, None
    return None, None


def header_attributes(cam: Camera | None) -> dict:
    """Header attributes describing `cam` (both fgen JSON and OpenEXR standard)."""
    if cam is None:
        return {}
    j = cam.to_json()
    w2c, ndc = to_exr(cam)
    return {"fgen:world_to_camera": json.dumps(j["world_to_camera"]),
            "fgen:projection": json.dumps(j["projection"]),
            "worldToCamera": w2c, "worldToNDC": ndc}


CAMERA_ATTRIBUTES = ("fgen:world_to_camera", "fgen:projection", "worldToCamera", "worldToNDC")
CAMERA_ATTRIBUTE_TYPES = {"worldToCamera": "matrix", "worldToNDC": "matrix"}


def project(cam: Camera, points_world: np.ndarray, width: int, height: int) -> np.ndarray:
    """(N, 3) world points -> (N, 3) pixel x, pixel y (y down, centres at +0.5), view depth."""
    p = np.concatenate([np.asarray(points_world, float), np.ones((len(points_world), 1))], 1)
    v = (np.asarray(cam.world_to_camera) @ p.T)
    c = np.asarray(cam.projection) @ v
    ndc = c[:3] / c[3]
    x = (ndc[0] + 1) / 2 * width
    y = (1 - ndc[1]) / 2 * height
    return np.stack([x, y, -v[2]], 1)


def sky_motion(cam: Camera, cam_prev: Camera, width: int, height: int) -> np.ndarray:
    """(2, H, W) motion vectors (toward the previous frame, pixels, y down) of points at
    infinity (sky) from the two cameras alone: only the camera rotation and the change of
    projection move them. Renderers such as Blender write 0 there even when the camera
    turns; the reader replaces those flagged vectors with these.
    """
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float64) + 0.5
    ndc = np.stack([2 * xs / width - 1, 1 - 2 * ys / height, np.ones_like(xs),
                    np.ones_like(xs)]).reshape(4, -1)
    view = np.linalg.inv(np.asarray(cam.projection, float)) @ ndc
    d_view = view[:3] / np.where(np.abs(view[3]) < 1e-12, 1e-12, view[3])
    r = np.asarray(cam.world_to_camera, float)[:3, :3]
    r_prev = np.asarray(cam_prev.world_to_camera, float)[:3, :3]
    d_prev = r_prev @ (np.linalg.inv(r) @ d_view)  # direction in the previous view space
    clip = np.asarray(cam_prev.projection, float) @ np.vstack([d_prev, np.zeros((1, d_prev.shape[1]))])
    w = np.where(np.abs(clip[3]) < 1e-12, 1e-12, clip[3])
    px = (clip[0] / w + 1) / 2 * width
    py = (1 - clip[1] / w) / 2 * height
    mv = np.stack([px.reshape(height, width) - xs, py.reshape(height, width) - ys])
    behind = (clip[3] <= 0).reshape(height, width)  # direction behind the previous camera
    mv[:, behind] = 0.0
    return np.clip(mv, -1e6, 1e6).astype(np.float32)
