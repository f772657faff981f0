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

import torch

from fgcli.errors import OutputError, UsageError
from fgcli.io.frames import write_sidecar_cameras
from fgcli.io.output import OutputFolder
from fgcli.synth.scene import Scene
from fgcli.synth.tracer import frame_camera, render


def frame_name(scene: Scene, number: int) -> str:
    return f"{scene.name}.{number:04d}.exr" if number >= 0 else f"{scene.name}.-{-number:04d}.exr"


def _write_overscan(path: str, frame, attrs: dict, border: int, camera) -> None:
    """An overscan frame: the border lies outside the display window (an EXR data window
    larger than the display window), so readers see the nominal frame and methods that
    can use the border find it in the data window. `camera` is the display window's."""
    from fgcli.io import cameras, exr, layouts
    from fgcli.io.frames import fgen_attributes

    frame = frame.replace(camera=camera)
    chans, types = layouts.encode(frame, "fgen", half=True)
    H, W = frame.height, frame.width
    exr.write_exr(path, chans, types, fgen_attributes(frame, attrs), "zip",
                  attribute_types=dict(cameras.CAMERA_ATTRIBUTE_TYPES),
                  data_window=(-border, -border, W, H), display=(W - 2 * border, H - 2 * border))


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


def _prepare(folder: str, overwrite: bool, keep: set[str], scene: Scene) -> OutputFolder:
    if os.path.isdir(folder):
        present = [f for f in os.listdir(folder) if not f.startswith(".")]
        if present and not overwrite:
            raise OutputError(f"output folder is not empty ({len(present)} entries); pass "
                              "--overwrite to replace its frames", file=folder)
    out = OutputFolder(folder, overwrite=True, prefix=f"{scene.name}.", padding=4)
    # frames of this scene left over from an earlier, longer render would join the sequence
    mine = re.compile(rf"^{re.escape(scene.name)}\.-?\d+\.exr$")
    for f in os.listdir(folder):
        if mine.match(f) and f not in keep:
            os.unlink(os.path.join(folder, f))
    return out


MV_STEP = 2.0 ** -10  # written motion vectors are rounded to 1/1024 pixel


def written_vectors(mv: torch.Tensor, step: float = MV_STEP) -> torch.Tensor:
    """The motion vectors as render_sequence writes them: rounded to multiples of step (a
    power of two, so exact in float32; 0 keeps every bit). The tracer's vectors carry
    float32 noise below a thousandth of a pixel (a static surface under an unchanged camera
    reprojects to its pixel within ~1e-5 px, not exactly); rounded, they are exactly zero
    there, as a rasteriser's are (the same vertex through the same matrices)."""
    if not step:
        return mv
    return torch.round(mv * (1.0 / step)) * step


def render_sequence(scene: Scene, out_dir: str, gt_dir: str | None = None, gt_factor: int = 2,
                    progress: bool = True, overwrite: bool = False, spp: int | None = None,
                    mv_step: float = MV_STEP, gbuffer_only: str = "none") -> dict:
    """Render the input frames of `scene` into out_dir (and ground truth into gt_dir).

    Writes `<scene>.<number:04d>.exr` in the fgen layout plus cameras.json in each folder.
    mv_step: motion vectors are rounded to multiples of it (a power of two, so the float32
    values are exact; 0 keeps every bit): below a thousandth of a pixel the float32 bits
    are arithmetic noise, and rounding them away makes the files 2-3x smaller.
    gbuffer_only: "odd" writes every odd input frame (input index 1, 3, ...) without colour
    and alpha, as an engine that shades every other frame writes them (depth, vectors,
    normals, albedo, roughness only; `fgen:gbuffer_only` = 1 in the header).
    Returns a summary: frames written per folder, seconds, work counters.
    """
    if gbuffer_only not in ("none", "odd"):
        raise UsageError(f"gbuffer_only must be 'none' or 'odd' (got {gbuffer_only!r})")
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
    outs = {}
    for role, folder in folders.items():
        if folder is not None:
            keep = {frame_name(scene, n) for r, n, _, _ in jobs if r == role}
            outs[role] = _prepare(folder, overwrite, keep, scene)
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
            frame.mv = written_vectors(frame.mv, mv_step)
            attrs = {
                "fgen:synth_scene": scene.name,
                "fgen:synth_hash": scene.hash,
                "fgen:synth_role": role,
                "fgen:synth_effects": ",".join(sorted(scene.effects)) or "none",
                "fgen:synth_spp": (scene.jitter_spp if role == "input" and
                                   scene.has("jitter") else spp),
                "fgen:time": t,
                "fgen:time_seconds": scene.seconds(t),
                "fgen:mv_time": prev_t,
                "fgen:frame_rate": rate,
                "fgen:gt_factor": K or 1,
                "fgen:synth_alpha": "coverage of geometry (straight; sky is 0)",
                "fgen:mv_space": "pixels to the previous output frame, prev_xy = xy + mv",
                "fgen:mv_step": mv_step,
            }
            fc = frame_camera(scene, t, role)
            if role == "input" and gbuffer_only == "odd" and int(round(t)) % 2 == 1:
                frame = frame.replace(color=None, alpha=None)
                attrs["fgen:gbuffer_only"] = 1
            if scene.has("jitter") and role == "input":
                attrs["fgen:jitter_x"], attrs["fgen:jitter_y"] = fc.jitter
            path = os.path.join(folders[role], frame_name(scene, num))
            if fc.border:
                attrs["fgen:overscan"] = fc.border
                _write_overscan(path, frame, attrs, fc.border, fc.display_camera)
            else:
                outs[role].write(path, frame, attributes=attrs)
            cams[role][num] = fc.display_camera
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
