"""EXR write cost per compression and the read cost, fgen's two EXR paths side by side
(issue 9 item 4): the OpenEXR binding fgen uses and OpenImageIO (its fallback).

    python benchmarks/exr_codecs.py FRAME.exr [--repeat 3]

Writes FRAME's colour (half), depth and vectors (float) in fgen's output layout with each
compression, one thread, best of --repeat, and reads FRAME's colour, depth and vectors.
Prints a markdown table (CPU ms, wall ms, MB).
"""
from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))


def cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def best(fn, repeat):
    w = c = float("inf")
    for _ in range(repeat):
        c0, t0 = cpu(), time.perf_counter()
        fn()
        w, c = min(w, time.perf_counter() - t0), min(c, cpu() - c0)
    return c * 1e3, w * 1e3


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("frame")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    import OpenImageIO as oiio

    from fgcli.io import exr
    from fgcli.io.frames import read_frame

    if exr._openexr() is None:
        sys.exit("the OpenEXR binding is not installed")
    fields = {"color", "depth", "mv"}
    fr = read_frame(args.frame, 0, fields=fields)
    c, d, m = fr.color.numpy(), fr.depth.numpy()[0], fr.mv.numpy()
    ch = {"R": c[0], "G": c[1], "B": c[2], "Z": d, "mv.x": m[0], "mv.y": m[1]}
    types = {"R": "half", "G": "half", "B": "half", "Z": "float", "mv.x": "float",
             "mv.y": "float"}
    exr.set_exr_threads(1)
    oiio.attribute("threads", 1)
    oiio.attribute("exr_threads", 1)
    binding = exr._openexr
    paths = {True: binding, False: lambda: None}
    print("| compression | OpenEXR writer CPU ms (wall) | OpenImageIO writer CPU ms (wall) "
          "| MB | lossless |")
    print("|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "c.exr")
        for comp in exr.COMPRESSIONS:
            res = {}
            for fast, fn in paths.items():
                exr._openexr = fn
                res[fast] = best(lambda: exr.write_exr(out, ch, types, None, comp),
                                 args.repeat)
            exr._openexr = binding
            mb = os.path.getsize(out) / 1e6
            lossless = "yes" if comp in ("zip", "zips", "piz", "rle", "none", "zstd") else "no"
            print(f"| {comp} | {res[True][0]:.0f} ({res[True][1]:.0f}) | "
                  f"{res[False][0]:.0f} ({res[False][1]:.0f}) | {mb:.2f} | {lossless} |")
    for fast, fn in paths.items():
        exr._openexr = fn
        cc, ww = best(lambda: read_frame(args.frame, 0, fields=fields), args.repeat)
        print(f"read colour, depth, vectors ({'OpenEXR' if fast else 'OpenImageIO'}): "
              f"CPU {cc:.0f} ms (wall {ww:.0f})")
    exr._openexr = binding


if __name__ == "__main__":
    main()
