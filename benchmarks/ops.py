"""Timing script for the ops (not a test): ``python benchmarks/ops.py [--size 1920x1080]``.

Prints the median of a few runs per op at the given size on a synthetic scene (textured
background, moving rectangles, camera pan), plus the ratio to a reference measured in the
same run (one full-frame colour copy), as docs/design.md section 6 asks.
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

import torch

from fgcli import ops


def synth(h, w, seed=0):
    g = torch.Generator().manual_seed(seed)
    yy = torch.arange(h, dtype=torch.float32)[:, None].expand(h, w)
    xx = torch.arange(w, dtype=torch.float32).expand(h, w)
    frames = []
    for t in (-1, 0, 1):
        col = torch.stack([0.5 + 0.4 * torch.sin(xx * 0.05 + t * 0.3),
                           0.5 + 0.4 * torch.cos(yy * 0.07),
                           torch.rand(h, w, generator=g)]) * 2.0
        depth = (10.0 + yy / h * 20.0)[None].clone()
        depth[:, : h // 8] = float("inf")  # sky band
        mv = torch.zeros(2, h, w)
        mv[0] = 1.5  # camera pan
        for k in range(6):
            x0 = int(w * (0.1 + 0.13 * k) + 8 * t * (k + 1))
            y0 = int(h * (0.2 + 0.1 * (k % 4)))
            sl = (slice(y0, y0 + h // 6), slice(max(x0, 0), max(x0 + w // 10, 0)))
            depth[0][sl] = 2.0 + k
            mv[0][sl] = -8.0 * (k + 1)
            mv[1][sl] = 0.5 * k
            col[:, sl[0], sl[1]] = torch.tensor([4.0, 0.5, 0.2 * k])[:, None, None]
        frames.append((col, depth, mv))
    return frames


def timeit(fn, runs):
    """(median wall ms, median process-CPU ms). On a shared box the CPU time (which
    excludes time the process waited for a core) is the steadier number; with N threads it
    is ~N x wall when all threads are busy."""
    fn()
    ts, cs = [], []
    for _ in range(runs):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        ts.append(time.perf_counter() - t0)
        cs.append(time.process_time() - c0)
    return statistics.median(ts) * 1000.0, statistics.median(cs) * 1000.0


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--no-tune", action="store_true", help="skip ops.tune_allocator()")
    ap.add_argument("--metrics", action="store_true", help="also time PSNR/SSIM/FLIP")
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0: leave as is)")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    if not args.no_tune:
        ops.tune_allocator()
    w, h = (int(v) for v in args.size.lower().split("x"))
    (_, _, _), (c0, d0, m0), (c1, d1, m1) = synth(h, w)
    alpha = 0.5
    print(f"size {w}x{h}, torch {torch.__version__}, threads {torch.get_num_threads()}, "
          f"tune_allocator {not args.no_tune}, "
          f"OMP_WAIT_POLICY={os.environ.get('OMP_WAIT_POLICY', '(unset)')}")
    print("(with cores shared by other busy processes set OMP_WAIT_POLICY=PASSIVE before "
          "torch is imported: the default spin-wait made every op ~5-10x slower here)")

    ref = timeit(lambda: c1.clone(), args.runs)
    rows = [("reference: colour copy", ref)]
    dd, mm = ops.dilate_nearest_depth(d1, m1)
    r = ops.splat_motion(dd, mm, m0, alpha, depth0=d0)
    rf = ops.gap_fill(r, fallback_mv=m0)
    c0s, v0 = ops.backward_warp(c0, rf.to0)
    c1s, v1 = ops.backward_warp(c1, rf.to1)
    d0s, _ = ops.sample_nearest(d0, rf.to0)
    d1s, _ = ops.sample_nearest(d1, rf.to1)
    re = ops.gap_fill(ops.splat_motion(dd, mm, m0, alpha, model="linear", mode="extrap"))

    def interp_chain():
        a, b = ops.dilate_nearest_depth(d1, m1)
        s = ops.splat_motion(a, b, m0, alpha, depth0=d0)
        s = ops.gap_fill(s, fallback_mv=m0)
        x0, u0 = ops.backward_warp(c0, s.to0)
        x1, u1 = ops.backward_warp(c1, s.to1)
        y0, _ = ops.sample_nearest(d0, s.to0)
        y1, _ = ops.sample_nearest(d1, s.to1)
        return ops.blend_interp(x0, x1, y0, y1, u0, u1, alpha=alpha)

    def extrap_chain():
        a, b = ops.dilate_nearest_depth(d1, m1)
        s = ops.splat_motion(a, b, m0, alpha, model="linear", mode="extrap")
        s = ops.fill_extrap_holes(ops.gap_fill(s), b, a)
        return ops.backward_warp(c1, s.to1)[0]

    cases = [
        ("dilate_nearest_depth", lambda: ops.dilate_nearest_depth(d1, m1)),
        ("splat_motion quadratic+depth0", lambda: ops.splat_motion(dd, mm, m0, alpha, depth0=d0)),
        ("splat_motion quadratic", lambda: ops.splat_motion(dd, mm, m0, alpha)),
        ("splat_motion linear", lambda: ops.splat_motion(dd, mm, None, alpha)),
        ("gap_fill (+fallback)", lambda: ops.gap_fill(r, fallback_mv=m0)),
        ("backward_warp bilinear", lambda: ops.backward_warp(c1, rf.to1)),
        ("backward_warp nearest", lambda: ops.backward_warp(c1, rf.to1, "nearest")),
        ("backward_warp catmull-rom", lambda: ops.backward_warp(c1, rf.to1, "catmull-rom")),
        ("sample_nearest depth", lambda: ops.sample_nearest(d1, rf.to1)),
        ("blend_interp", lambda: ops.blend_interp(c0s, c1s, d0s, d1s, v0, v1, alpha=alpha)),
        ("blend_linear", lambda: ops.blend_linear(c0, c1, alpha)),
        ("fill_extrap_holes", lambda: ops.fill_extrap_holes(re, mm, dd)),
        ("mv_warp_interp", lambda: ops.mv_warp_interp(c0, c1, m1, alpha)),
        ("chain_mv (2)", lambda: ops.chain_mv([m1, m0])),
        ("disocclusion_mask", lambda: ops.disocclusion_mask(d1, m1, d0)),
        ("INTERP chain (dilate+splat+fill+2 warps+2 depth+blend)", interp_chain),
        ("EXTRAP chain (dilate+splat+fill+holes+warp)", extrap_chain),
    ]
    if args.metrics:
        cases += [("psnr", lambda: ops.psnr(c0, c1)), ("ssim", lambda: ops.ssim(c0, c1)),
                  ("flip_ldr", lambda: ops.flip_ldr(c0, c1))]
    for name, fn in cases:
        rows.append((name, timeit(fn, args.runs if "flip" not in name else 1)))
    width = max(len(n) for n, _ in rows)
    print(f"{'':<{width}}  {'wall ms':>9}  {'x ref':>7}  {'cpu ms':>9}  {'x ref':>7}")
    for name, (wall, cpu) in rows:
        print(f"{name:<{width}}  {wall:9.1f}  {wall / ref[0]:7.1f}  {cpu:9.1f}  "
              f"{cpu / max(ref[1], 1e-9):7.1f}")


if __name__ == "__main__":
    main()
