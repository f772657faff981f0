"""Process set-up that needs no torch (safe to call from the CLI entry point)."""
from __future__ import annotations

import ctypes


def tune_allocator(mmap_threshold: int = 32 << 20, trim_threshold: int = 1 << 30) -> bool:
    """Make glibc keep freed frame-sized buffers instead of returning them to the OS.

    Every op allocates a few 8-48 MB tensors per 1080p frame; by default glibc serves each
    from fresh mmap pages and the page faults cost more than the arithmetic (measured 3-10x
    on the 2-core box). Process-wide; call once at CLI start-up. Returns True on success
    (False off glibc). Safe to call repeatedly.

    glibc caps the mmap threshold at 32 MiB, so a larger block (GFFE's (3, 4, H, W)
    trajectory, 100 MB at 1080p) was still mapped fresh for every frame: allocating and
    filling it took 21.6 ms against 4.4 ms from the heap, and the history stage swung
    between 33 and 54 ms per frame with it. M_MMAP_MAX = 0 serves every block from the
    heap: a run's peak stays mapped (its frames allocate the same sizes again) and what
    lies above the trim threshold at the heap's top is given back.
    """
    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:
        return False
    ok = libc.mallopt(-3, int(mmap_threshold)) == 1  # M_MMAP_THRESHOLD
    ok &= libc.mallopt(-1, int(trim_threshold)) == 1  # M_TRIM_THRESHOLD
    ok &= libc.mallopt(-2, 64 << 20) == 1  # M_TOP_PAD
    ok &= libc.mallopt(-4, 0) == 1  # M_MMAP_MAX: no block from mmap, whatever its size
    return bool(ok)
