"""Render a scene's input sequence (and ground truth) to EXR folders in the fgen layout.

Frame-number timeline (docs/synth.md): with ground truth at factor K, input frame i is
number i*K, rendered at t = i with vectors toward t = i-1; ground-truth frame i*K + j
(0 < j < K) is rendered at t = i + j/K with vectors toward the previous fine-rate frame
(t = i + (j-1)/K), including the K-1 frames after the last input frame (extrapolation
targets). Without ground truth the input frames are numbered 0, 1, 2, ...
"""
from __future__ import annotations

import os
import re
import time

from fgcli.errors import OutputError, UsageError
from fgcli.io.frames import write_frame, write_sidecar_cameras
from fgcli.synth.render import frame_camera, render
from fgcli.synth.scene import Scene


def frame_name(scene: Scene, number: int) -> str:
    return f"{scene.name}.{number:04d}.exr" if number >= 0 else f"{scene.name}.-{-number:04d}.exr"


def schedule(scene: Scene, gt_factor: int | None) -> list[tuple[str, int, float, float]]:
    """(role, frame number, t, prev_t) for every frame to render, in number order.

    gt_factor None: input frames only, numbered 0, 1, 2, ...
    """
    jobs = []
    K = gt_factor or 1
    for i in range(scene.frames):
        jobs.append(("input", i * K, float(i), float(i - 1)))
        if gt_factor:
            # with `jitter` the input is a low-resolution render: ground truth also holds the
            # full-resolution frame at each input time (the super-sampling target)
            for j in range(0 if scene.has("jitter") else 1, K):
                jobs.append(("gt", i * K + j, i + j / K, i + (j - 1) / K))
    return sorted(jobs, key=lambda j: (j[1], j[0]))


def _prepare(folder: str, overwrite: bool, keep: set[str], scene: Scene) -> None:
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise OutputError("not a folder", file=folder)
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError as e:
        raise OutputError(f"cannot create output folder: {e.strerror}", file=folder) from None
    present = [f for f in os.listdir(folder) if not f.startswith(".")]
    if present and not overwrite:
        raise OutputError(f"output folder is not empty ({len(present)} entries); pass "
                          "--overwrite to replace its frames", file=folder)
    # frames of this scene left over from an earlier, longer render would join the sequence
    mine = re.compile(rf"^{re.escape(scene.name)}\.-?\d+\.exr$")
    for f in present:
        if mine.match(f) and f not in keep:
            os.unlink(os.path.join(folder, f))


def render_sequence(scene: Scene, out_dir: str, gt_dir: str | None = None, gt_factor: int = 2,
                    progress: bool = True, overwrite: bool = False, spp: int | None = None
                    ) -> dict:
    """Render the input frames of `scene` into out_dir (and ground truth into gt_dir).

    Writes `<scene>.<number:04d>.exr` in the fgen layout plus cameras.json in each folder.
    Returns a summary: frames written per folder, seconds, work counters.
    """
    out_dir = os.fspath(out_dir)
    if gt_dir is not None:
        gt_dir = os.fspath(gt_dir)
        if int(gt_factor) < 2:
            raise UsageError(f"--gt-factor must be 2 or more (got {gt_factor})")
        if os.path.abspath(gt_dir) == os.path.abspath(out_dir):
            raise OutputError("ground truth and input need different folders", file=gt_dir)
    K = int(gt_factor) if gt_dir is not None else None
    jobs = schedule(scene, K)
    spp = spp or scene.spp
    folders = {"input": out_dir, "gt": gt_dir}
    for role, folder in folders.items():
        if folder is not None:
            keep = {frame_name(scene, n) for r, n, _, _ in jobs if r == role}
            _prepare(folder, overwrite, keep, scene)
    rate = scene.fps * (K or 1)  # frames per second of the frame numbers
    cams = {"input": {}, "gt": {}}
    scene.reset_stats()
    t_start = time.perf_counter()
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(jobs), unit="frame", desc=f"synth {scene.name}", leave=False)
    try:
        for role, num, t, prev_t in jobs:
            frame = render(scene, t, prev_t, spp=spp, role=role, number=num)
            frame.time = float(num)
            attrs = {
                "fgen:synth_scene": scene.name,
                "fgen:synth_hash": scene.hash,
                "fgen:synth_role": role,
                "fgen:synth_effects": ",".join(sorted(scene.effects)) or "none",
                "fgen:synth_spp": spp,
                "fgen:time": t,
                "fgen:time_seconds": scene.seconds(t),
                "fgen:mv_time": prev_t,
                "fgen:frame_rate": rate,
                "fgen:gt_factor": K or 1,
                "fgen:alpha": "coverage (straight)",
                "fgen:mv_space": "pixels to the previous output frame, prev_xy = xy + mv",
            }
            if role == "input":
                fc = frame_camera(scene, t, role)
                if scene.has("jitter"):
                    attrs["fgen:jitter_x"], attrs["fgen:jitter_y"] = fc.jitter
                if scene.has("overscan"):
                    attrs["fgen:overscan"] = fc.border
            path = os.path.join(folders[role], frame_name(scene, num))
            write_frame(path, frame, attributes=attrs)
            cams[role][num] = frame.camera
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    extra = {"scene": scene.name, "synth_hash": scene.hash, "frame_rate": rate}
    for role, folder in folders.items():
        if folder is not None:
            write_sidecar_cameras(folder, cams[role], extra=extra)
    return {"input": len(cams["input"]), "gt": len(cams["gt"]),
            "seconds": time.perf_counter() - t_start, "stats": dict(scene.stats)}
