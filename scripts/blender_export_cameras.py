"""Write fgen's sidecar `cameras.json` from a Blender scene.

Run inside Blender (no add-on needed):

    blender -b shot.blend --python scripts/blender_export_cameras.py -- OUT_DIR \
        [--start N] [--end M] [--step S]

OUT_DIR is the folder holding the rendered EXR sequence (default: the folder of the scene's
output path). One entry per frame, in the format fgen reads (docs/conventions.md):

    {"frames": [{"frame": 12, "world_to_camera": [[4x4]], "projection": [[4x4]]}, ...]}

Matrices are row-major and applied to column vectors; the camera looks down -Z with +Y up
(Blender's and OpenGL's convention); `projection` is Blender's camera matrix for the render
resolution (clip space, NDC y up), the same one Cycles renders with, so it includes the
sensor fit, shift and pixel aspect.
"""
from __future__ import annotations

import argparse
import json
import os
import sys


def matrix_rows(m) -> list[list[float]]:
    """A 4x4 matrix (mathutils.Matrix or nested sequences) as row-major lists."""
    return [[float(m[i][j]) for j in range(4)] for i in range(4)]


def build_document(entries, extra: dict | None = None) -> dict:
    """entries: iterable of (frame, world_to_camera, projection); returns the JSON document."""
    doc = dict(extra or {})
    doc["frames"] = [{"frame": int(f), "world_to_camera": matrix_rows(w2c),
                      "projection": matrix_rows(proj)} for f, w2c, proj in entries]
    return doc


def write_document(folder: str, doc: dict) -> str:
    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, "cameras.json")
    tmp = path + ".tmp"
    with open(tmp, "w") as fh:
        json.dump(doc, fh, indent=1)
    os.replace(tmp, path)
    return path


def _args(argv):
    argv = argv[argv.index("--") + 1:] if "--" in argv else []
    ap = argparse.ArgumentParser(prog="blender_export_cameras.py")
    ap.add_argument("out_dir", nargs="?", default=None)
    ap.add_argument("--start", type=int, default=None)
    ap.add_argument("--end", type=int, default=None)
    ap.add_argument("--step", type=int, default=None)
    ap.add_argument("--camera", default=None, help="camera object name (default: scene's)")
    return ap.parse_args(argv)


def main(argv=None) -> str:  # pragma: no cover - needs Blender
    import bpy

    args = _args(sys.argv if argv is None else argv)
    scene = bpy.context.scene
    cam = bpy.data.objects[args.camera] if args.camera else scene.camera
    if cam is None:
        raise SystemExit("the scene has no camera")
    r = scene.render
    scale = r.resolution_percentage / 100.0
    res_x, res_y = int(r.resolution_x * scale), int(r.resolution_y * scale)
    start = scene.frame_start if args.start is None else args.start
    end = scene.frame_end if args.end is None else args.end
    step = scene.frame_step if args.step is None else args.step
    out_dir = args.out_dir or os.path.dirname(bpy.path.abspath(r.filepath)) or os.getcwd()
    entries = []
    current = scene.frame_current
    for f in range(start, end + 1, step):
        scene.frame_set(f)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        ev = cam.evaluated_get(depsgraph)
        proj = ev.calc_matrix_camera(depsgraph, x=res_x, y=res_y,
                                     scale_x=r.pixel_aspect_x, scale_y=r.pixel_aspect_y)
        entries.append((f, ev.matrix_world.inverted(), proj))
    scene.frame_set(current)
    doc = build_document(entries, {"source": bpy.data.filepath, "camera": cam.name,
                                   "width": res_x, "height": res_y})
    path = write_document(out_dir, doc)
    print(f"wrote {len(entries)} cameras to {path}")
    return path


if __name__ == "__main__":  # pragma: no cover
    main()
