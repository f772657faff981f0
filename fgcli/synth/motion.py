"""Rigid motions and camera paths, evaluated in float64 numpy at any time (seconds).

Every motion is a pure function of time, defined for all real times (keyframed paths are
extended linearly past their ends), so the renderer can evaluate a surface point at the
current time and at the previous output time and get exact motion vectors.

Rotation conventions: angles in degrees in scene files; `rotation = [rx, ry, rz]` is applied
about X first, then Y, then Z (R = Rz @ Ry @ Rx); an axis-angle rotation turns
counter-clockwise when looking down the axis (right-hand rule).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

UP = np.array([0.0, 1.0, 0.0])


def axis_angle(axis, angle_rad: float) -> np.ndarray:
    """3x3 rotation about `axis` (any length > 0) by `angle_rad` (Rodrigues)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    x, y, z = a
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    C = 1.0 - c
    return np.array([[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
                     [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
                     [z * x * C - y * s, z * y * C + x * s, c + z * z * C]])


def euler_deg(rot) -> np.ndarray:
    """R = Rz @ Ry @ Rx for rot = [rx, ry, rz] in degrees."""
    rx, ry, rz = (math.radians(float(v)) for v in rot)
    return axis_angle((0, 0, 1), rz) @ axis_angle((0, 1, 0), ry) @ axis_angle((1, 0, 0), rx)


def _interp_keys(times: np.ndarray, values: np.ndarray, s: float, smooth: bool) -> np.ndarray:
    """Piecewise linear (or Catmull-Rom when smooth) through (times, values), linear
    extrapolation past both ends."""
    n = len(times)
    if n == 1:
        return values[0].copy()
    if s <= times[0]:
        i = 0
    elif s >= times[-1]:
        i = n - 2
    else:
        i = int(np.searchsorted(times, s, side="right")) - 1
        i = min(max(i, 0), n - 2)
    t0, t1 = times[i], times[i + 1]
    u = (s - t0) / (t1 - t0)
    p0, p1 = values[i], values[i + 1]
    if not smooth or u < 0.0 or u > 1.0:
        return p0 + (p1 - p0) * u
    # Catmull-Rom with non-uniform knots (finite-difference tangents), C1 through the keys
    m0 = (p1 - values[i - 1]) / (t1 - times[i - 1]) if i > 0 else (p1 - p0) / (t1 - t0)
    m1 = (values[i + 2] - p0) / (times[i + 2] - t0) if i + 2 < n else (p1 - p0) / (t1 - t0)
    h = t1 - t0
    u2, u3 = u * u, u * u * u
    return ((2 * u3 - 3 * u2 + 1) * p0 + (u3 - 2 * u2 + u) * h * m0
            + (-2 * u3 + 3 * u2) * p1 + (u3 - u2) * h * m1)


@dataclass
class Motion:
    """Object-to-world transform over time: x_world = R(s) @ x_local + T(s).

    kind: static | linear | ballistic | rotate | keyframes. `spin` (axis, deg/s) turns the
    object about its own origin on top of any kind.
    """

    kind: str
    position: np.ndarray
    rotation: np.ndarray  # base orientation (3x3)
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    acceleration: np.ndarray = field(default_factory=lambda: np.zeros(3))
    start: float = 0.0  # time origin of linear/ballistic/rotate motion (seconds)
    axis: np.ndarray = field(default_factory=lambda: UP.copy())
    speed: float = 0.0  # deg/s for rotate
    pivot: np.ndarray | None = None
    key_times: np.ndarray | None = None
    key_positions: np.ndarray | None = None
    key_rotations: np.ndarray | None = None  # euler degrees per key
    smooth: bool = False
    spin_axis: np.ndarray | None = None
    spin_speed: float = 0.0  # deg/s
    spin_phase: float = 0.0  # deg

    def at(self, s: float) -> tuple[np.ndarray, np.ndarray]:
        R = self.rotation
        if self.spin_axis is not None and (self.spin_speed != 0.0 or self.spin_phase != 0.0):
            R = axis_angle(self.spin_axis, math.radians(self.spin_phase + self.spin_speed * s)) @ R
        k = self.kind
        dt = s - self.start
        if k == "static":
            T = self.position.copy()
        elif k == "linear":
            T = self.position + self.velocity * dt
        elif k == "ballistic":
            T = self.position + self.velocity * dt + 0.5 * self.acceleration * dt * dt
        elif k == "rotate":
            Ra = axis_angle(self.axis, math.radians(self.speed * dt))
            piv = self.position if self.pivot is None else self.pivot
            T = piv + Ra @ (self.position - piv)
            R = Ra @ R
        elif k == "keyframes":
            T = _interp_keys(self.key_times, self.key_positions, s, self.smooth)
            if self.key_rotations is not None:
                R = euler_deg(_interp_keys(self.key_times, self.key_rotations, s, self.smooth)) @ R
        else:  # pragma: no cover - validated at load time
            raise ValueError(k)
        return R, np.asarray(T, dtype=np.float64)


def look_at(position, target) -> np.ndarray:
    """World-to-camera 4x4 (OpenGL: camera looks down -Z, +Y up)."""
    p = np.asarray(position, dtype=np.float64)
    f = np.asarray(target, dtype=np.float64) - p
    f = f / np.linalg.norm(f)
    up = UP if abs(f @ UP) < 0.999 else np.array([0.0, 0.0, -1.0])
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    M = np.eye(4)
    M[0, :3], M[1, :3], M[2, :3] = r, u, -f
    M[:3, 3] = -M[:3, :3] @ p
    return M


def perspective(tan_half_x: float, tan_half_y: float, near: float, far: float) -> np.ndarray:
    """OpenGL view-to-clip projection (NDC y up, z in [-1, 1])."""
    P = np.zeros((4, 4))
    P[0, 0] = 1.0 / tan_half_x
    P[1, 1] = 1.0 / tan_half_y
    P[2, 2] = (far + near) / (near - far)
    P[2, 3] = 2.0 * far * near / (near - far)
    P[3, 2] = -1.0
    return P


@dataclass
class CameraPath:
    """Camera position and target over time (seconds).

    kind: static | orbit | pan | dolly | keyframes. `follow` (an object's motion and a weight)
    pulls the target toward a moving object (a camera tracking a throw).
    """

    kind: str
    position: np.ndarray
    target: np.ndarray
    fov: float = 50.0  # vertical, degrees
    near: float = 0.05
    far: float = 1000.0
    # orbit
    center: np.ndarray | None = None
    radius: float = 5.0
    height: float = 1.5
    angle: float = 0.0  # deg at s=0
    speed: float = 0.0  # deg/s (orbit, pan)
    # pan
    pitch: float = 0.0
    # dolly
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    move_target: bool = True
    key_times: np.ndarray | None = None
    key_positions: np.ndarray | None = None
    key_targets: np.ndarray | None = None
    smooth: bool = True
    follow: Motion | None = None
    follow_weight: float = 1.0
    follow_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def at(self, s: float) -> tuple[np.ndarray, np.ndarray]:
        k = self.kind
        if k == "static":
            pos, tgt = self.position.copy(), self.target.copy()
        elif k == "orbit":
            a = math.radians(self.angle + self.speed * s)
            c = self.center
            pos = c + np.array([self.radius * math.sin(a), self.height, self.radius * math.cos(a)])
            tgt = c.copy()
        elif k == "pan":
            yaw = math.radians(self.angle + self.speed * s)
            pt = math.radians(self.pitch)
            cp = math.cos(pt)
            d = np.array([-math.sin(yaw) * cp, math.sin(pt), -math.cos(yaw) * cp])
            pos = self.position.copy()
            tgt = pos + d
        elif k == "dolly":
            pos = self.position + self.velocity * s
            tgt = self.target + (self.velocity * s if self.move_target else 0.0)
        elif k == "keyframes":
            pos = _interp_keys(self.key_times, self.key_positions, s, self.smooth)
            tgt = _interp_keys(self.key_times, self.key_targets, s, self.smooth)
        else:  # pragma: no cover
            raise ValueError(k)
        if self.follow is not None:
            _, T = self.follow.at(s)
            w = self.follow_weight
            tgt = (1.0 - w) * tgt + w * (T + self.follow_offset)
        return np.asarray(pos, dtype=np.float64), np.asarray(tgt, dtype=np.float64)

    def world_to_camera(self, s: float) -> np.ndarray:
        return look_at(*self.at(s))
