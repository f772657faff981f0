"""The numba kernels one at a time: where a pipeline's time goes, and old vs new of one kernel.

    python benchmarks/kernels.py profile --pipelines fsr3-interp [--repeat 9] [--size WxH]
                                 [--input FOLDER]
    python benchmarks/kernels.py ab fsr3.interp_window_kernel REV --pipeline fsr3-interp
                                 [--mode interp] [--call 1] [--repeat 30] [--input FOLDER]

``profile`` wraps every compiled kernel of fgcli.kernels.* (after they are loaded, so the
kernels that call each other stay compiled together) with a clock and runs the pipelines
on the frames of benchmarks/stages.py: per kernel, the calls per frame and the median ms
per frame. Time outside the kernels (torch glue, allocation) is the pipeline's total
minus their sum.

``ab`` records the arguments of one call of a kernel while the pipeline runs a frame
(``--call``: which call, counting from 1), then runs that kernel of this checkout and of
REV (exported as benchmarks/ab.py does) on copies of them, alternating, and prints the
medians, the median of the paired ratios (new / old) and whether every array the two
versions wrote (and what they returned) is identical bit for bit. On the 2-core build box
two separate runs differ by 10-30 %; alternating in one process shows a few percent.
"""
from __future__ import annotations

import argparse
import copy
import importlib
import os
import statistics
import sys
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # (before torch is imported)
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
MODULES = ("blend", "field", "fill", "flow", "fsr3", "geom", "gffe", "pyramid", "scene",
           "splat", "warp")


def frames(size: str, folder: str | None = None):
    """The two frames of benchmarks/stages.py and ab.py (blade, a static camera), or the
    first two of the EXR sequence in folder (a moving camera: `fgen synth
    sample_data/scenes/orbit.toml F --size 1920x1080 --frames 8 --spp 1`), with fgen's
    allocator set-up."""
    from ab import blade_frames

    from fgcli.runner import check_device

    check_device("cpu")  # what fgen does at start-up (allocator tuning)
    if folder:
        from fgcli.io.reader import SequenceReader

        r = SequenceReader(folder)
        if len(r.numbers) < 2:
            sys.exit(f"--input: 2 frames needed, {len(r.numbers)} found in {folder}")
        return [r.read(n).replace(normal=None, albedo=None, roughness=None, alpha=None)
                for n in r.numbers[:2]]
    return blade_frames(size, [(3.0, 2.0), (4.0, 3.0)])


def runner(name: str, mode: str, seq):
    """A callable running pipeline NAME in MODE once on the two frames (numba backend)."""
    import fgcli.pipeline as P
    from fgcli.runner import make_ctx

    stages = P.load(name).build(mode)

    def run():
        ctx = make_ctx(seq[0], seq[1], 0.5, mode)
        ctx["state"] = None
        ctx["prev_time"] = 0.0
        ctx["backend"] = "numba"
        P.run_stages(stages, ctx, None)
    return run


def dispatchers(pkg: str = "fgcli"):
    from numba.core.registry import CPUDispatcher

    for m in MODULES:
        mod = importlib.import_module(f"{pkg}.kernels.{m}")
        for k, v in list(vars(mod).items()):
            if isinstance(v, CPUDispatcher) and v.__module__ == mod.__name__:
                yield mod, k, v


def profile(args):
    import torch

    from fgcli import pipeline as P
    from fgcli.kernels.ops import warm

    warm()
    seq = frames(args.size, args.input)
    clocks: dict[str, list[float]] = {}

    def wrap(name, fn):
        def w(*a, **kw):
            t0 = time.perf_counter()
            r = fn(*a, **kw)
            clocks[name].append(time.perf_counter() - t0)
            return r
        return w

    for mod, k, v in dispatchers():
        name = f"{mod.__name__.rsplit('.', 1)[1]}.{k}"
        clocks[name] = []
        setattr(mod, k, wrap(name, v))
    names = list(P.available()) if args.pipelines == "all" else args.pipelines.split(",")
    with torch.inference_mode():
        for pname in names:
            for mode in P.load(pname).modes:
                run = runner(pname, mode, seq)
                run()
                for v in clocks.values():
                    v.clear()
                totals, per = [], {k: [] for k in clocks}
                for _ in range(args.repeat):
                    marks = {k: len(v) for k, v in clocks.items()}
                    t0 = time.perf_counter()
                    run()
                    totals.append(time.perf_counter() - t0)
                    for k, v in clocks.items():
                        per[k].append((sum(v[marks[k]:]), len(v) - marks[k]))
                total = statistics.median(totals) * 1000
                rows = sorted(((statistics.median(s for s, _ in p) * 1000, p[0][1], k)
                               for k, p in per.items() if p and p[0][1]), reverse=True)
                print(f"\n{pname} {mode}: {total:.1f} ms per frame (median of {args.repeat})")
                print("| kernel | calls | ms |\n|---|---|---|")
                for ms, n, k in rows:
                    print(f"| {k} | {n} | {ms:.2f} |")
                print(f"| (outside the kernels) | | {total - sum(r[0] for r in rows):.1f} |")


def _arrays(obj):
    import numpy as np

    if isinstance(obj, np.ndarray):
        return [obj]
    if isinstance(obj, (tuple, list)):
        return [a for o in obj for a in _arrays(o)]
    return []


def ab(args):
    import numpy as np
    import torch

    import ab as abmod

    base = abmod.export(args.rev)
    sys.path.insert(1, base)
    modname, kname = args.kernel.rsplit(".", 1)
    new_mod = importlib.import_module(f"fgcli.kernels.{modname}")
    old_mod = importlib.import_module(f"fgcli_ab.kernels.{modname}")
    new_fn, old_fn = getattr(new_mod, kname), getattr(old_mod, kname)
    seq = frames(args.size, args.input)
    captured = []

    def rec(*a, **kw):
        if len(captured) < args.call:
            captured.append(copy.deepcopy((a, kw)))
        return new_fn(*a, **kw)

    setattr(new_mod, kname, rec)
    with torch.inference_mode():
        runner(args.pipeline, args.mode, seq)()
    setattr(new_mod, kname, new_fn)
    if len(captured) < args.call:
        sys.exit(f"{args.kernel}: {len(captured)} calls in one {args.pipeline} "
                 f"{args.mode} frame, --call {args.call} asked for")
    a, kw = captured[args.call - 1]
    outs = {}
    T = {"old": [], "new": []}
    for k in range(args.repeat + 1):
        for side in (("old", "new") if k % 2 else ("new", "old")):
            fn = new_fn if side == "new" else old_fn
            ca, ckw = copy.deepcopy((a, kw))
            t0 = time.perf_counter()
            r = fn(*ca, **ckw)
            dt = (time.perf_counter() - t0) * 1000
            if k:
                T[side].append(dt)
            else:
                outs[side] = _arrays(ca) + _arrays(list(ckw.values())) + _arrays(r)
    same = (len(outs["old"]) == len(outs["new"]) and all(
        x.dtype == y.dtype and x.shape == y.shape and
        np.array_equal(x.view(np.uint8), y.view(np.uint8))
        for x, y in zip(outs["old"], outs["new"])))
    ratio = statistics.median(n / o for n, o in zip(T["new"], T["old"]))
    print(f"{args.kernel} ({args.pipeline} {args.mode}, call {args.call}): "
          f"{args.rev} {statistics.median(T['old']):.2f} ms (min {min(T['old']):.2f}), "
          f"this checkout {statistics.median(T['new']):.2f} ms (min {min(T['new']):.2f}), "
          f"new / old {ratio:.3f}; outputs {'bit-identical' if same else 'DIFFER'}")
    if not same:
        sys.exit(1)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("profile", help="per-kernel ms per frame inside pipelines")
    p.add_argument("--pipelines", default="fsr3-interp,mob-fgsr,gffe-extrap")
    p.add_argument("--repeat", type=int, default=9)
    p.add_argument("--size", default="1920x1080")
    p.add_argument("--input", default=None, metavar="FOLDER",
                   help="frames from this EXR sequence instead of the blade scene")
    p.set_defaults(fn=profile)
    p = sub.add_parser("ab", help="one kernel, this checkout against REV, on captured input")
    p.add_argument("kernel", help="MODULE.KERNEL of fgcli.kernels, e.g. fill.gap_fill_kernel")
    p.add_argument("rev")
    p.add_argument("--pipeline", required=True)
    p.add_argument("--mode", default="interp")
    p.add_argument("--call", type=int, default=1)
    p.add_argument("--repeat", type=int, default=30)
    p.add_argument("--size", default="1920x1080")
    p.add_argument("--input", default=None, metavar="FOLDER",
                   help="frames from this EXR sequence instead of the blade scene")
    p.set_defaults(fn=ab)
    args = ap.parse_args()
    args.fn(args)


if __name__ == "__main__":
    main()
