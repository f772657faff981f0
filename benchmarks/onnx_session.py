"""The mv-interp network's onnxruntime session alone at 1088x1920, several graphs
interleaved in one process (an A/B of export changes that the whole-pipeline benchmark's
run-to-run noise would hide).

    python benchmarks/onnx_session.py [GRAPH.onnx ...] [--runs 13] [--threads 2]

Default graph: the shipped fgcli/nets/weights/mv-interp.onnx. Inputs are random (the
session's cost does not depend on the values). Prints wall and CPU time per run (min and
median, the first run dropped).
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np


def main():
    from fgcli.nets.export import WEIGHTS_DIR

    ap = argparse.ArgumentParser()
    ap.add_argument("graphs", nargs="*", default=[os.path.join(WEIGHTS_DIR, "mv-interp.onnx")])
    ap.add_argument("--runs", type=int, default=13)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--size", default="1920x1088")
    args = ap.parse_args()
    import onnxruntime as ort

    w, h = (int(v) for v in args.size.split("x"))
    sessions = {}
    for g in args.graphs:
        so = ort.SessionOptions()
        so.intra_op_num_threads = args.threads
        so.inter_op_num_threads = 1
        so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        sessions[g] = ort.InferenceSession(g, so, providers=["CPUExecutionProvider"])
    r = np.random.default_rng(0).random
    feed = {k: r((1, c, h, w)).astype(np.float32) * s
            for k, c, s in (("x0", 3, 1), ("x1", 3, 1), ("w0", 3, 1), ("w1", 3, 1),
                            ("g0", 2, 3), ("g1", 2, 3), ("cue", 2, 1))}
    feed["t"] = np.full((1, 1, 1, 1), 0.5, np.float32)
    wall = {g: [] for g in sessions}
    cpu = {g: [] for g in sessions}
    for _ in range(args.runs):
        for g, s in sessions.items():
            t0, c0 = time.perf_counter(), time.process_time()
            s.run(None, feed)
            wall[g].append((time.perf_counter() - t0) * 1000.0)
            cpu[g].append((time.process_time() - c0) * 1000.0)
    print(f"# {w}x{h}, {args.threads} threads, {args.runs} runs each, interleaved")
    for g in sessions:
        a, c = wall[g][1:], cpu[g][1:]
        print(f"{g}: wall min {min(a):.0f} median {statistics.median(a):.0f} ms, "
              f"CPU min {min(c):.0f} median {statistics.median(c):.0f} ms")


if __name__ == "__main__":
    main()
