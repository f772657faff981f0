"""Shared test fixtures: small and generic.

`tiny_scene(t)` renders frame t of a scene whose motion is known exactly (numpy only):
a textured background panning +1 px/frame in x, a textured 8x8 square moving (+2, +1)
px/frame in front of it, and sky in the top rows (depth +inf, static color). It returns
the internal convention: color (3,H,W), depth (1,H,W), mv (2,H,W) toward t-1, mv_fwd
(2,H,W) toward t+1, normal, albedo, roughness and ids (H,W: 0 sky, 1 background, 2 square).
"""
from __future__ import annotations

import contextlib
import os

# as fgen itself (fgcli/cli.py, the benchmarks): torch's OpenMP threads must not spin,
# or two busy processes on a 2-core machine (a test run beside a build) slow each other
# down 10-50x; set before anything imports torch
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

SKY_ROWS = 4
BG_SPEED = (1, 0)
FG_SPEED = (2, 1)
FG_SIZE = 8


def _tex(x, y, seed):
    return (0.5 + 0.25 * np.sin(0.9 * x + seed) * np.cos(0.7 * y - seed)
            + 0.2 * np.sin(0.37 * x * (1 + seed) + 0.53 * y))


def render_scene(t: int, h: int = 24, w: int = 32) -> dict:
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    bx, by = x - BG_SPEED[0] * t, y - BG_SPEED[1] * t
    color = np.stack([_tex(bx, by, s) for s in (0.1, 0.2, 0.3)])
    depth = np.full((1, h, w), 10.0)
    mv = np.stack([np.full((h, w), -BG_SPEED[0], float), np.full((h, w), -BG_SPEED[1], float)])
    fwd = -mv.copy()
    ids = np.ones((h, w), np.int32)
    x0, y0 = 4 + FG_SPEED[0] * t, 6 + FG_SPEED[1] * t
    fg = (x >= x0) & (x < x0 + FG_SIZE) & (y >= y0) & (y < y0 + FG_SIZE)
    lx, ly = x - x0, y - y0
    for c, s in enumerate((1.1, 1.7, 2.3)):
        color[c] = np.where(fg, 2.0 * _tex(lx, ly, s) + 0.1, color[c])
    depth[0][fg] = 2.0
    mv[0][fg], mv[1][fg] = -FG_SPEED[0], -FG_SPEED[1]
    fwd[0][fg], fwd[1][fg] = FG_SPEED[0], FG_SPEED[1]
    ids[fg] = 2
    sky = y < SKY_ROWS
    for c in range(3):
        color[c][sky] = (0.3 + 0.1 * c + 0.01 * x)[sky]
    depth[0][sky] = np.inf
    ids[sky] = 0
    normal = np.zeros((3, h, w))
    normal[2] = 1.0
    normal[:, sky] = 0.0
    albedo = np.clip(color * 0.5, 0, 1)
    rough = np.where(fg, 0.2, 0.7)[None]
    f32 = lambda a: np.ascontiguousarray(a, dtype=np.float32)  # noqa: E731
    return {"color": f32(color), "depth": f32(depth), "mv": f32(mv), "mv_fwd": f32(fwd),
            "normal": f32(normal), "albedo": f32(albedo), "roughness": f32(rough),
            "ids": ids}


@pytest.fixture
def tiny_scene():
    return render_scene

# Property tests draw the same examples on every run and machine (derandomize): CI must not
# pass or fail by the luck of the draw. Set FGEN_HYPOTHESIS_RANDOM=1 to explore new examples.
import os as _os

from hypothesis import settings as _hsettings

_hsettings.register_profile("fgen", derandomize=True)
_hsettings.register_profile("explore", derandomize=False)
_hsettings.load_profile("explore" if _os.environ.get("FGEN_HYPOTHESIS_RANDOM") else "fgen")


@pytest.fixture(scope="session", autouse=True)
def _numba_kernels_compiled():
    """A fresh checkout has no numba cache: compile every kernel once at the start, split
    between two processes (fgcli.kernels.ops.warm: numba compiles under the GIL, so the
    tests hitting the kernels one by one would compile them on one core, ~4 of a cold
    suite's minutes on 2 cores). A warm cache costs a file check. Under pytest-xdist
    (``-n 2``), one worker compiles while the others wait on a file lock, then find the
    cache warm (each compiling on its own would do the same work twice over)."""
    try:
        from fgcli.kernels import numba_available
        from fgcli.kernels.ops import _cache_cold, warm
    except ImportError:  # no torch / numba here: nothing to compile
        yield
        return
    if numba_available() and _cache_cold():
        lock = contextlib.nullcontext()
        if _os.environ.get("PYTEST_XDIST_WORKER"):
            lock = _warm_lock()
        with lock:
            if _cache_cold():
                warm()
    yield


@contextlib.contextmanager
def _warm_lock():
    """An exclusive lock on a file beside the kernels' numba cache (POSIX; elsewhere no
    lock: each worker compiles what it finds cold)."""
    try:
        import fcntl
    except ImportError:
        yield
        return
    import fgcli.kernels

    d = _os.path.join(_os.path.dirname(fgcli.kernels.__file__), "__pycache__")
    _os.makedirs(d, exist_ok=True)
    with open(_os.path.join(d, ".fgen-warm.lock"), "w") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)
