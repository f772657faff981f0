"""Compile time of the numba kernels on this machine, in a fresh cache.

    python benchmarks/compile_time.py [--families core,fsr3,gffe] [--top 25]

A machine's first run compiles the kernels it needs into numba's on-disk cache (later runs
load them in about a second). This compiles the kernels of the given families (default
all) in one process, in a throw-away NUMBA_CACHE_DIR, and prints the total and each
kernel's own compile time, longest first (numba's timers: ``compiler_lock`` is the whole
compile, ``llvm_lock`` the part in LLVM; a kernel's time includes the functions it calls,
which are listed too). One process on purpose: ``fgcli.kernels.ops.warm`` splits the work
between two, which halves the wall time but mixes the figures.

Use it after changing a kernel: numba's parallel-loop passes cost time that grows with
the square of a prange body's size (docs/performance.md), so a kernel that grows
can take minutes to compile on a slow CPU without running any slower.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--families", default=None,
                    help="comma-separated kernel families (core, fsr3, gffe; default all)")
    ap.add_argument("--top", type=int, default=25, help="how many kernels to list")
    args = ap.parse_args(argv)
    os.environ["NUMBA_CACHE_DIR"] = tempfile.mkdtemp(prefix="fgen-compile-")
    sys.path.insert(0, ROOT)
    import gc

    from numba.core.dispatcher import Dispatcher

    from fgcli.kernels import ops

    fams = None if args.families is None else [f.strip() for f in args.families.split(",")]
    inputs = ops._inputs()
    tasks = []  # warm()'s tasks in its order (there two processes share them), here in turn
    for k, (fam, call) in enumerate(ops._TASKS):
        if fams is None or fam in fams:
            t0 = time.perf_counter()
            call(inputs)
            tasks.append((k, time.perf_counter() - t0))
    total = sum(t for _, t in tasks)
    rows = []
    for d in gc.get_objects():
        if isinstance(d, Dispatcher) and d.py_func.__module__.startswith("fgcli"):
            for sig in d.signatures:
                tm = d.get_metadata(sig).get("timers", {})
                rows.append((tm.get("compiler_lock", 0.0), tm.get("llvm_lock", 0.0),
                             f"{d.py_func.__module__}.{d.py_func.__name__}"))
    rows.sort(reverse=True)
    import llvmlite.binding as ll

    print(f"# {ll.get_host_cpu_name()}, families {fams or 'all'}: {total:.1f} s in one "
          f"process, {len(rows)} compiled signatures")
    print("warm()'s tasks in its order (task: s): "
          + ", ".join(f"{k}: {t:.1f}" for k, t in tasks))
    print("| kernel | compile s | of it LLVM s |")
    print("|---|---|---|")
    for c, lv, name in rows[:args.top]:
        print(f"| {name} | {c:.1f} | {lv:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
