"""Whole pipelines of two versions of fgen, timed in one process, frame by frame in turn.

    python benchmarks/ab.py REV [--pipelines gffe-extrap,fsr3-interp] [--repeat 15]
                                [--sequence] [--size 1920x1080] [--backend numba]
                                [--input FOLDER]

On a machine whose speed swings 10-30 % between runs (the 2-core build box), two
benchmark runs cannot show a change of a few percent; alternating the two versions on
the same frames in one process can. REV (a git revision of this checkout) is exported
into a cache folder (~/.cache/fgen-ab/<commit>) as the package ``fgcli_ab`` (every
``fgcli`` import renamed; its own numba kernel cache, compiled there once: a few
minutes), the checkout's own package is the other side. Frames: the bundled blade scene
at 1/4 size, upscaled (as benchmarks/stages.py; a static camera), or with ``--input`` the
first frames of an EXR sequence (a moving camera: `fgen synth
sample_data/scenes/orbit.toml F --size 1920x1080 --frames 8 --spp 1`). Prints, per pipeline and mode, the
median and minimum ms per frame of each version and the median of the per-frame ratios
(new / old, each pair measured back to back).
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # (before torch is imported)
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

_RENAMES = [(re.compile(r"\bfgcli\."), "fgcli_ab."),
            (re.compile(r"\bfrom fgcli import\b"), "from fgcli_ab import"),
            (re.compile(r"^import fgcli$", re.M), "import fgcli_ab"),
            (re.compile(r"\bimport fgcli as\b"), "import fgcli_ab as")]


def export(rev: str) -> str:
    """The folder holding REV's fgcli as fgcli_ab (and its pipelines/), made once."""
    sha = subprocess.run(["git", "-C", ROOT, "rev-parse", rev], capture_output=True,
                         text=True, check=True).stdout.strip()
    base = os.path.join(os.path.expanduser("~"), ".cache", "fgen-ab", sha[:12])
    if os.path.isdir(os.path.join(base, "fgcli_ab")):
        return base
    os.makedirs(os.path.dirname(base), exist_ok=True)
    tmp = tempfile.mkdtemp(dir=os.path.dirname(base))
    try:
        arch = os.path.join(tmp, "src.tar")
        subprocess.run(["git", "-C", ROOT, "archive", "-o", arch, sha, "fgcli", "pipelines"],
                       check=True)
        with tarfile.open(arch) as t:
            try:
                t.extractall(tmp, filter="data")
            except TypeError:  # (Python before 3.11.4: no filters; our own archive)
                t.extractall(tmp)
        os.remove(arch)
        os.rename(os.path.join(tmp, "fgcli"), os.path.join(tmp, "fgcli_ab"))
        for d, _, files in os.walk(os.path.join(tmp, "fgcli_ab")):
            for f in files:
                if f.endswith(".py"):
                    p = os.path.join(d, f)
                    s = open(p, encoding="utf-8").read()
                    for rx, new in _RENAMES:
                        s = rx.sub(new, s)
                    open(p, "w", encoding="utf-8").write(s)
        os.rename(tmp, base)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return base


def upscaled(f, W: int, H: int, mv_step=None):
    """A frame rendered at 1/4 of W x H brought to W x H as the benchmarks use it: nearest
    upscale, vectors scaled, and rounded first as `fgen synth` writes them (mv_step: None =
    its 2**-10 px, 0 = the tracer's unrounded ones; benchmarks/stages.py --mv-step); the
    G-buffers dropped."""
    import torch

    from fgcli.synth.sequence import MV_STEP, written_vectors

    def u(x, k=1.0):
        return torch.nn.functional.interpolate(x[None], size=(H, W), mode="nearest")[0] * k

    mv = written_vectors(f.mv, MV_STEP if mv_step is None else mv_step)
    return f.replace(color=u(f.color), depth=u(f.depth), mv=u(mv, W / (W // 4)),
                     normal=None, albedo=None, roughness=None, alpha=None)


def blade_frames(size: str, times, mv_step=None):
    """The benchmark's frames: the bundled blade scene rendered at 1/4 of size (WxH) at
    each (time, previous time) of times, upscaled (upscaled: vectors as fgen synth writes
    them unless mv_step says otherwise)."""
    from fgcli.synth import load_scene, render

    W, H = (int(v) for v in size.lower().split("x"))
    scene = load_scene(os.path.join(ROOT, "sample_data", "scenes", "blade.toml"),
                       size=(W // 4, H // 4))
    return [upscaled(render(scene, t, tp, spp=2), W, H, mv_step).replace(number=i)
            for i, (t, tp) in enumerate(times)]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("rev", help="the other version: a git revision of this checkout")
    ap.add_argument("--pipelines", default="gffe-extrap,fsr3-interp,mob-fgsr")
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--sequence", action="store_true",
                    help="consecutive pairs, each version's state carried over")
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--backend", default="numba")
    ap.add_argument("--mv-step", type=float, default=None, metavar="PX",
                    help="the blade frames' vectors rounded to PX (default: as fgen synth "
                         "writes them, 2**-10; 0: unrounded; benchmarks/stages.py --mv-step)")
    ap.add_argument("--input", default=None, metavar="FOLDER",
                    help="frames from this EXR sequence instead of the blade scene")
    args = ap.parse_args()
    base = export(args.rev)
    env = dict(os.environ, PYTHONPATH=base)
    print(f"# {args.rev} as fgcli_ab from {base}", flush=True)
    if args.backend != "torch":  # (the kernels: compiled into that folder's cache once)
        subprocess.run([sys.executable, "-c", "from fgcli_ab.kernels.ops import warm; warm()"],
                       env=env, check=True, cwd=base)
    sys.path.insert(0, base)
    sys.path.insert(0, ROOT)
    import torch

    import fgcli.pipeline as P_new
    import fgcli_ab.pipeline as P_old
    from fgcli.runner import RunState, check_device, make_ctx
    from fgcli_ab.runner import RunState as RunState_old, make_ctx as make_ctx_old

    check_device("cpu")
    times = ([(2.0 + 0.5 * i, 1.0 + 0.5 * i) for i in range(args.repeat + 2)]
             if args.sequence else [(3.0, 2.0), (4.0, 3.0)])
    if args.input:
        from fgcli.io.reader import SequenceReader

        reader = SequenceReader(args.input)
        if len(reader.numbers) < len(times):
            sys.exit(f"--input: {len(times)} frames needed, {len(reader.numbers)} found")
        seq = [reader.read(n).replace(normal=None, albedo=None, roughness=None, alpha=None)
               for n in reader.numbers[:len(times)]]
    else:
        seq = blade_frames(args.size, times, args.mv_step)
    sides = {"old": (P_old, make_ctx_old, RunState_old), "new": (P_new, make_ctx, RunState)}
    print(f"| pipeline | mode | {args.rev} ms (min) | this checkout ms (min) | new / old |")
    print("|---|---|---|---|---|")
    with torch.inference_mode():
        for name in args.pipelines.split(","):
            built = {k: (v[0].load(name), v[1], v[2]) for k, v in sides.items()}
            for mode in built["new"][0].modes:
                stages = {k: v[0].build(mode) for k, v in built.items()}
                states = {k: v[2]() for k, v in built.items()}
                T = {"old": [], "new": []}
                for k in range(args.repeat + 1):  # (k = 0: warm-up, loads the kernels)
                    for side in (("old", "new") if k % 2 else ("new", "old")):
                        pl, mk, _ = built[side]
                        f0, f1 = (seq[k], seq[k + 1]) if args.sequence else (seq[0], seq[1])
                        ctx = mk(f0, f1, 0.5, mode)
                        ctx["state"] = states[side] if args.sequence else None
                        ctx["prev_time"] = 0.0
                        ctx["backend"] = args.backend
                        t0 = time.perf_counter()
                        sides[side][0].run_stages(stages[side], ctx, None)
                        if k:
                            T[side].append((time.perf_counter() - t0) * 1000.0)
                ratio = statistics.median(n / o for n, o in zip(T["new"], T["old"]))
                print(f"| {name} | {mode} | {statistics.median(T['old']):.1f} "
                      f"({min(T['old']):.1f}) | {statistics.median(T['new']):.1f} "
                      f"({min(T['new']):.1f}) | {ratio:.3f} |", flush=True)


if __name__ == "__main__":
    main()
