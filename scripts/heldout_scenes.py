"""Render held-out random scenes as evaluation sequences (input/ + gt/ per seed), for
checking a pipeline on data it was not tuned on.

    python scripts/heldout_scenes.py OUT --seeds 1050000:1050012
    python scripts/heldout_scenes.py OUT --seeds 2060000:2060012 --shading-only
    fgen eval OUT/<seed> --pipeline mv-interp,mob-fgsr,blend --no-hdr-flip

Seeds: the training data of `fgen train` uses 0 .. scenes-1, its validation 1,000,000 ..
1,000,063 and its shading-only scenes 2,000,000 .. 2,000,299 (fgcli.nets.data); the ranges
above are none of them. --shading-only: the same random scene with static geometry and
camera and moving lights (fgcli.nets.data.shading_only): only the shading changes.
"""
from __future__ import annotations

import argparse
import os


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--seeds", required=True, help="FIRST:END (END excluded)")
    ap.add_argument("--shading-only", action="store_true")
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--size", default="256x144")
    args = ap.parse_args()
    import numpy as np

    from fgcli.nets.data import shading_only
    from fgcli.synth import load_scene, random_scene
    from fgcli.synth.sequence import render_sequence

    a, b = (int(v) for v in args.seeds.split(":"))
    w, h = (int(v) for v in args.size.split("x"))
    for seed in range(a, b):
        spec = random_scene(seed, size=(w, h))
        if args.shading_only:
            spec = shading_only(spec, np.random.default_rng(seed))
        d = os.path.join(args.out, str(seed))
        render_sequence(load_scene(spec, frames=args.frames), os.path.join(d, "input"),
                        gt_dir=os.path.join(d, "gt"), gt_factor=2, progress=False,
                        overwrite=True, spp=2)
        print(d, flush=True)


if __name__ == "__main__":
    main()
