"""Per-pixel helpers shared by the kernels: the ops' sanitising rules, element by element
(the torch ops sanitise whole tensors only when needed; per element the result is the
same), and float32 bit views. Every helper is inlined into the kernels.

The ``*_b`` rules are written as selects, not branches: a branch in a kernel's per-pixel
body (even one never taken) stops LLVM from vectorising the row loop, which cost 2-7x at
1080p. ``sval`` (branches) is for the scalar passes only."""
from __future__ import annotations

import numpy as np
from numba import njit

F32 = np.float32
INF = np.float32(np.inf)
MV_MAX = np.float32(1.0e6)  # fgcli.ops._util.MV_MAX
BIG = np.float32(1.0e30)  # fgcli.ops._util.BIG
FAR = np.float32(4.0e6)  # sanitize_flow_positions: 4 * MV_MAX
I64_MAX = np.int64((1 << 63) - 1)
INLINE = dict(inline="always", cache=True)
# every kernel: compiled once per process into the on-disk cache, no fastmath (results
# must stay bit-identical to the torch reference), all cores
KERNEL = dict(cache=True, parallel=True, fastmath=False, nogil=True)


@njit(**INLINE)
def sval(v):
    """sanitize_values: NaN -> 0, +-inf -> +-1e30."""
    if v != v:
        return F32(0.0)
    if v == INF:
        return BIG
    if v == -INF:
        return -BIG
    return v


@njit(**INLINE)
def bits(v):
    return np.float32(v).view(np.int32)


@njit(**INLINE)
def sval_b(v):
    """sanitize_values as selects."""
    r = BIG if v == INF else v
    r = -BIG if v == -INF else r
    return F32(0.0) if v != v else r


@njit(**INLINE)
def sflow_b(v):
    """sanitize_flow_positions as selects."""
    r = FAR if v > FAR else v
    r = -FAR if v < -FAR else r
    return -FAR if v != v else r


@njit(**INLINE)
def smv_b(v):
    """sanitize_mv as selects."""
    r = MV_MAX if v > MV_MAX else v
    r = -MV_MAX if v < -MV_MAX else r
    return F32(0.0) if v != v else r


@njit(**INLINE)
def clamp_b(v, lo, hi):
    """clamp to [lo, hi] for finite v (torch.clamp_), as selects."""
    v = lo if v < lo else v
    return hi if v > hi else v


@njit(**INLINE)
def sdepth_b(v):
    """sanitize_depth as selects."""
    r = F32(0.0) if v <= F32(0.0) else v
    return INF if v != v else r
