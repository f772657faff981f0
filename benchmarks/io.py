"""End-to-end I/O comparison (issue 9, item 4): `fgen interpolate` (mob-fgsr, x2) against
the plain serial OpenImageIO floor on the same frames, measured in the same run.

    python benchmarks/io.py IN_DIR [--pipeline mob-fgsr] [--backend auto]

The floor reads each input file in one call, keeps colour/depth/mv, and writes one
6-channel (half RGB, float Z and mv) zip frame per consecutive pair, serially: the blended
colour, the depth and half the vectors (real vectors: zero ones, which zip squeezes to
nothing, would make the floor ~300 ms per 1080p frame too fast). Prints both
wall times and their ratio (target: fgen <= 1.1x the floor). Make a 1080p input with
`fgen synth` (not committed: big files).
"""
from __future__ import annotations

import argparse
import glob
import os
import resource
import subprocess
import sys
import tempfile
import time


def plain_oiio(files, out_dir, compression="zip"):
    import numpy as np
    import OpenImageIO as oiio

    t0 = time.perf_counter()
    prev = None
    for i, path in enumerate(files):
        inp = oiio.ImageInput.open(path)
        spec = inp.spec()
        px = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)  # one call, all channels
        inp.close()
        names = list(spec.channelnames)
        # colour, depth and vectors (the "keep colour/depth/mv"; fgen's layout)
        pick = [names.index(c) for c in ("R", "G", "B", "Z", "mv.x", "mv.y")]
        cur = px[:, :, pick]
        if prev is not None:
            # a blend, the depth, and half the vectors: a frame with real vectors, as
            # fgen writes (zeros would compress to nothing and flatter the floor)
            out = np.ascontiguousarray(np.concatenate(
                [0.5 * (prev[..., :3] + cur[..., :3]), cur[..., 3:4], 0.5 * cur[..., 4:6]],
                axis=2))
            h, w = out.shape[:2]
            ospec = oiio.ImageSpec(w, h, 6, oiio.FLOAT)
            ospec.channelnames = ("R", "G", "B", "Z", "mv.x", "mv.y")
            ospec.channelformats = (oiio.HALF,) * 3 + (oiio.FLOAT,) * 3
            ospec.attribute("compression", compression)
            o = oiio.ImageOutput.create(os.path.join(out_dir, f"p.{i:04d}.exr"))
            o.open(os.path.join(out_dir, f"p.{i:04d}.exr"), ospec)
            if not (o.write_image(out) and o.close()):  # a failed write must not count
                raise RuntimeError(f"floor write failed: {o.geterror()}")
        prev = cur
    return time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("input")
    ap.add_argument("--pipeline", default="mob-fgsr")
    ap.add_argument("--backend", default="auto")
    args = ap.parse_args()
    files = sorted(glob.glob(os.path.join(args.input, "*.exr")))
    with tempfile.TemporaryDirectory() as tmp:
        c0 = time.process_time()
        floor = plain_oiio(files, tmp)
        floor_cpu = time.process_time() - c0
        out = os.path.join(tmp, "fgen")
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "fgcli", "interpolate", args.input, out,
                        "--pipeline", args.pipeline, "--backend", args.backend,
                        "--no-progress"], check=True)
        fg = time.perf_counter() - t0
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        fg_cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    print(f"{len(files)} input frames: plain serial OIIO {floor:.2f} s, fgen interpolate "
          f"{fg:.2f} s ({fg / floor:.2f}x; target <= 1.1x)")
    # on a shared machine the wall times follow the other load; CPU time much less so
    print(f"cpu time: plain serial OIIO {floor_cpu:.2f} s, fgen interpolate {fg_cpu:.2f} s "
          f"(start-up included); load average {os.getloadavg()[0]:.2f} on "
          f"{os.cpu_count()} cores")


if __name__ == "__main__":
    main()
