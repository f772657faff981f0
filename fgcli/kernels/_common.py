"""Per-pixel helpers shared by the kernels: the ops' sanitising rules, element by element
(the torch ops sanitise whole tensors only when needed; per element the result is the
same), and float32 bit views. Every helper is inlined into the kernels.

The ``*_b`` rules are written as selects, not branches: a branch in a kernel's per-pixel
body (even one never taken) stops LLVM from vectorising the row loop, which cost 2-7x at
1080p. ``sval`` (branches) is for the scalar passes only."""
from __future__ import annotations

import os

import numpy as np
import numba
from numba import njit
from numba.core.compiler import CompilerBase, DefaultPassBuilder


def use_wide_vectors() -> bool:
    """Let LLVM vectorise with 512-bit registers on AVX-512 CPUs.

    Without this, LLVM's tuning for recent Intel server CPUs (Skylake-X through Emerald
    Rapids) keeps loops at 256 bits. The gather-bound kernels run faster at 512 bits:
    mob-fgsr interpolation and fsr3-interp ~1.15-1.2x faster.
    Element-wise float32 arithmetic gives the same results at any vector width; the
    kernels use no fastmath and reassociate no sums.

    Process-wide, and it must run before the first @njit decoration: numba fixes its
    target machine then. Every kernel module imports this module first, and the call
    happens at its import. numba's on-disk cache keys compiled code by CPU features, so
    kernels cached under other features are compiled again, not reused.
    A user's NUMBA_CPU_NAME / NUMBA_CPU_FEATURES wins, and FGEN_VECTOR_WIDTH=256 opts out.
    Returns True when the setting is in effect."""
    if os.environ.get("NUMBA_CPU_NAME") or os.environ.get("FGEN_VECTOR_WIDTH") == "256":
        return False
    if os.environ.get("NUMBA_CPU_FEATURES") is None:
        import llvmlite.binding as ll

        feats = ll.get_host_cpu_features().flatten()
        if "+avx512f" not in feats.split(","):
            return False
        # (child processes, such as warm()'s, inherit the variable)
        os.environ["NUMBA_CPU_FEATURES"] = feats + ",-prefer-256-bit"
        numba.core.config.reload_config()  # numba read the environment at its import
    return os.environ["NUMBA_CPU_FEATURES"].endswith(",-prefer-256-bit")


WIDE_VECTORS = use_wide_vectors()


# numba's on-disk cache of a kernel is keyed by a hash of its own source file only, while
# its compiled code also holds the helpers it inlines from the package's other kernel
# files and the intrinsics of _intrin.py; a change there would leave every cached kernel
# of an unchanged file stale (a git pull, an upgrade over an old cache). So the kernels'
# cache stamp is their file's hash and the hash of every kernel source file.
_KERNEL_DIR = os.path.dirname(os.path.abspath(__file__))
# no compiled code: wrappers, the torch reference, the exactness contracts
_NOT_KERNEL_CODE = ("__init__.py", "ops.py", "reference.py", "contract.py")


def kernel_sources_hash(folder: str = _KERNEL_DIR) -> bytes:
    """sha256 over the names and contents of the kernel source files of ``folder``."""
    import hashlib

    h = hashlib.sha256()
    for name in sorted(os.listdir(folder)):
        if name.endswith(".py") and name not in _NOT_KERNEL_CODE:
            with open(os.path.join(folder, name), "rb") as f:
                h.update(name.encode() + b"\0" + hashlib.sha256(f.read()).digest())
    return h.digest()


def _stamp_kernel_caches(folder: str = _KERNEL_DIR) -> bool:
    """Make the cache stamp of the kernels defined in ``folder`` cover every kernel source
    file there (numba's cache locators, subclassed; must run before the first @njit
    decoration). False when numba's internals have moved (the plain per-file stamp then
    stays)."""
    try:
        from numba.core import caching

        impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl
        classes = list(impl._locator_classes)
    except (ImportError, AttributeError):
        return False
    folders = getattr(impl, "_fgen_kernel_folders", None)
    if folders is not None:  # another copy of this package (benchmarks/ab.py) made them
        folders.add(folder)
        return True
    bases = [c for c in classes if c.__name__ in (
        "UserProvidedCacheLocator", "InTreeCacheLocator", "UserWideCacheLocator")]
    if len(bases) != 3:
        return False
    folders = impl._fgen_kernel_folders = {folder}
    memo = {}

    def stamp(self):
        d = os.path.dirname(os.path.abspath(self._py_file))
        if d not in memo:
            memo[d] = kernel_sources_hash(d)
        return (super(type(self), self).get_source_stamp(), memo[d])

    def make(base):
        def from_function(cls, py_func, py_file):
            if os.path.dirname(os.path.abspath(py_file)) not in folders:
                return None
            return super(cls, cls).from_function(py_func, py_file)

        return type("Fgen" + base.__name__, (base,), {
            "get_source_stamp": stamp, "from_function": classmethod(from_function),
            "__module__": __name__})

    impl._locator_classes = [make(c) for c in bases] + classes
    return True


KERNEL_CACHE_STAMPED = _stamp_kernel_caches()

# (after the two set-ups above: they must precede any compilation)
from fgcli.kernels._intrin import HAVE_AVX2, lut16  # noqa: E402

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


class RowsCompiler(CompilerBase):
    """numba's nopython pipeline with the flag its parallel loops' bodies get when the
    kernel makes no aliases: the arrays passed in do not alias (noalias arguments in the
    LLVM IR, as the parfor body had). The ``ROWS`` functions are those bodies, written
    apart."""

    def define_pipelines(self):
        self.state.flags.noalias = True
        return [DefaultPassBuilder.define_nopython_pipeline(self.state)]


# the body of a big kernel's parallel loop as a function of its own, called once per chunk
# of rows: numba's parallel-loop passes copy a loop body's IR over and over (copy
# propagation), which grows with the square of its size; a kernel built from many inlined
# helpers took minutes to compile for that alone (warp_blend_kernel: 220 s on a Zen 3).
# As in a parallel loop's body: numpy's error model (no Python exception checks on integer
# division), arrays not aliased, no fastmath. And no reference counting (_nrt=False: the
# kernel passes in the row buffers it allocated): without the parallel passes' copy
# propagation, each array handed to an inlined helper is a new variable, counted up and
# down in every pixel loop (atomic operations: warp_blend 3x slower).
ROWS = dict(cache=True, nogil=True, fastmath=False, error_model="numpy", _nrt=False,
            pipeline_class=RowsCompiler)


# eight uint8 flags read as one word (a row's first w // 8 * 8 bytes viewed as uint64): the
# sparse loops (the gap fill's, the vector rule's) skip a word with nothing to do in one
# test instead of a branch per pixel
ALL1 = np.uint64(0x0101010101010101)  # eight flags 1 (valid)
NONE8 = np.uint64(0xFFFFFFFFFFFFFFFF)  # eight int8 codes -1 (none)


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
def f2i64(v):
    """np.int64(v) of a float32 v within +-2**31 (a clamped coordinate, the flat index of
    a pixel of an image below 2**31 pixels: the same truncation), converted through
    int32: AVX2 has no vector float -> int64 conversion, and each lane took a scalar one."""
    return np.int64(np.int32(v))


@njit(**INLINE)
def sdepth_b(v):
    """sanitize_depth as selects."""
    r = F32(0.0) if v <= F32(0.0) else v
    return INF if v != v else r


@njit(**INLINE)
def step_code(v, tab, b0, sh, n1, bottom):
    """A step table's value (fgcli.ops.fsr3.step_table: base[i] + (v >= thr[i])) at a
    float32 v >= 0 from fgcli.kernels.ops.packed_steps' table: one int32 gather per value
    instead of two (base and thr). Entry i = base[i] << (sh + 1) | the low sh bits of
    thr[i] (1 << sh where the bucket has no step): v and thr[i] share bucket i's high bits,
    so v >= thr[i] is the compare of their low bits (non-negative floats order as their
    bits). Below bucket 0 the value is ``bottom`` (base[0]: thr[0] lies inside bucket 0);
    above the last bucket its entry (no step there: packed_steps checks). b0, sh, n1,
    bottom: int32 (the bucket of v's bits >> sh, minus b0; the last bucket's index)."""
    bits = np.float32(v).view(np.int32)
    i = (bits >> sh) - b0
    below = i < np.int32(0)
    i = np.int32(0) if below else (n1 if i > n1 else i)
    e = tab[i]
    m = (np.int32(1) << sh) - np.int32(1)
    f = (np.int32(1) << (sh + np.int32(1))) - np.int32(1)
    c = (e >> (sh + np.int32(1))) + np.int32((bits & m) >= (e & f))
    return bottom if below else c


@njit(**INLINE)
def lut_row(tab, I, n, E):
    """E[x] = tab[I[x]] for x < n (1-D int32 arrays, 0 <= I < tab.size): 16 per lut16
    (two AVX2 gathers) where the CPU has AVX2, the rest one by one. (LLVM leaves a loop of
    table reads to scalar loads where gathers are slow, as on Zen.)"""
    nb = 0
    if HAVE_AVX2:
        nb = n // 16
        for b in range(nb):
            lut16(tab, I, np.int32(16 * b), E)
    for x in range(16 * nb, n):
        E[x] = tab[I[x]]


@njit(**INLINE)
def step_codes(B, n, tab, b0, sh, n1, bottom, I, E):
    """step_code of n values at once (a row): E[x] = the code of the float32 (>= 0) whose
    bits are B[x] (int32), x < n. The buckets into I (int32 row buffer), then the table's
    entries (lut_row), then the codes: the same values."""
    for x in range(n):
        i = (B[x] >> sh) - b0
        I[x] = np.int32(0) if i < np.int32(0) else (n1 if i > n1 else i)
    lut_row(tab, I, n, E)
    m = (np.int32(1) << sh) - np.int32(1)
    f = (np.int32(1) << (sh + np.int32(1))) - np.int32(1)
    for x in range(n):
        bits = B[x]
        e = E[x]
        c = (e >> (sh + np.int32(1))) + np.int32((bits & m) >= (e & f))
        E[x] = bottom if ((bits >> sh) - b0) < np.int32(0) else c


@njit(**INLINE)
def dealt(i, n):
    """The chunk (or row) a parallel loop's iteration i of n works on, dealt out so that
    each thread's share is spread over the frame: numba gives each thread one contiguous
    run of a prange's iterations (OpenMP's static schedule), so with chunk i = i the top of
    the frame went to one thread and the bottom to the other, and the work of a frame
    whose top differs from its bottom (sky, holes, disocclusions) was split unevenly
    (interp_depth_kernel: one thread busy 1.7x the other). For n a power of two (64
    chunks) the bit reversal of i (any power-of-two number of threads gets every T-th
    chunk), else the even ones first, then the odd ones (two threads alternate). A
    permutation of 0 .. n - 1 either way; int64."""
    i = np.int64(i)
    n = np.int64(n)
    if n & (n - 1) == 0:
        r = np.int64(0)
        k = n >> 1
        while k > 0:
            r = (r << 1) | (i & 1)
            i >>= 1
            k >>= 1
        return r
    m = (n + 1) // 2
    return 2 * i if i < m else 2 * (i - m) + 1
