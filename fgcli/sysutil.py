"""Process set-up that needs no torch (safe to call from the CLI entry point)."""
from __future__ import annotations

import ctypes


def tune_allocator(mmap_threshold: int = 32 << 20, trim_threshold: int = 1 << 30) -> bool:
    """Make glibc keep freed frame-sized buffers instead of returning them to the OS.

    Every op allocates a few 8-48 MB tensors per 1080p frame; by default glibc serves each
    from fresh mmap pages and the page faults cost more than the arithmetic (measured 3-10x
    on the 2-core box). Process-wide; call once at CLI start-up. Returns True on success
    (False off glibc). Safe to call repeatedly.
    """
    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:
        return False
    ok = libc.mallopt(-3, int(mmap_threshold)) == 1  # M_MMAP_THRESHOLD
    ok &= libc.mallopt(-1, int(trim_threshold)) == 1  # M_TRIM_THRESHOLD
    ok &= libc.mallopt(-2, 64 << 20) == 1  # M_TOP_PAD
    return bool(ok)
