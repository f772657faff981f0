"""What a generated frame says about itself: its time, its camera, its alpha, and only the
metadata of its source frames that is true of it (docs/conventions.md, "Generated frames").

A generated frame sits at `x` on the input's frame-number timeline (interpolation:
x = a + alpha (b - a); extrapolation: x = b + alpha * step). Its header gets:

- `fgen:frame` (its file's number), `fgen:input_frame` (x), `fgen:numbering`;
- `fgen:time` / `fgen:time_seconds` / `fgen:mv_time`: the sources' values of these mapped
  linearly to x (two sources: the line through them; one: its value shifted by the frame
  rate when the header gives one); without them `fgen:time` is x;
- `fgen:frame_rate` (and the standard `framesPerSecond`): the source's rate times the
  timeline scale when the outputs are numbered on a scaled timeline;
- the camera at x (fgcli.io.cameras writes both fgen JSON and worldToCamera/worldToNDC):
  interpolation: the rigid motion between the two cameras taken in part (screw motion:
  rotation slerped, translation along the same screw), projection interpolated linearly;
  extrapolation: gffe-extrap's camera (fgcli.ops.gffe.extrapolate_camera, model rigid);
- every other `fgen:KEY` of the sources renamed `fgen:source_KEY` (one value when the
  sources agree, "v0,v1" in source order when they differ), and the standard attributes
  that date a frame (timeCode, capDate, utcOffset, keyCode) likewise.

Alpha of a generated frame (`generated_alpha`): the source frame nearest in time, sampled
(bilinear) where the generated frame's own motion vectors, scaled linearly to that source,
say its surface was. The same source pixels its colour's surface came from, up to the
pipeline's own disocclusion handling (holes take the alpha the vectors point at).
"""
from __future__ import annotations

import math
import numbers

import numpy as np

# written fresh for every generated frame (by this module or the runner)
FRESH = {"fgen:time", "fgen:time_seconds", "fgen:mv_time", "fgen:frame", "fgen:input_frame",
         "fgen:numbering", "fgen:timeline_scale", "fgen:frame_rate", "fgen:alpha",
         "fgen:source_frames", "fgen:pipeline", "fgen:mode", "fgen:command_line",
         "fgen:pipeline_json", "fgen:version", "fgen:rendered", "fgen:generated",
         "fgen:world_to_camera", "fgen:projection"}
# standard attributes that date or identify one rendered frame
DATING = ("timeCode", "smpte:TimeCode", "capDate", "utcOffset", "keyCode", "smpte:KeyCode")
TIME_KEYS = ("fgen:time", "fgen:time_seconds")


def _num(v):
    if isinstance(v, bool):
        return None
    if isinstance(v, numbers.Real):
        return float(v)
    try:
        return float(str(v))
    except (TypeError, ValueError):
        return None


def _rate(header: dict):
    """Frames per second of the frame numbers, from fgen:frame_rate or framesPerSecond."""
    r = _num(header.get("fgen:frame_rate"))
    if r is None:
        fps = header.get("framesPerSecond")
        if isinstance(fps, (tuple, list)) and len(fps) == 2 and fps[1]:
            r = float(fps[0]) / float(fps[1])
        else:
            r = _num(fps)
    return r if r and r > 0 and math.isfinite(r) else None


def time_on(points: list[tuple[float, dict]], key: str, x: float, step: float | None = None):
    """The value of header `key` at input frame number x, linear through the sources
    (frame number, header) that carry it. One source: seconds advance by its frame rate,
    fgen:time by its vectors' span (fgen:time - fgen:mv_time per input step `step`). None
    when neither is known."""
    pts = [(float(n), _num(h.get(key))) for n, h in points if h is not None]
    pts = [(n, v) for n, v in pts if v is not None and math.isfinite(v)]
    if len({n for n, _ in pts}) >= 2:
        (n0, v0), (n1, v1) = pts[0], pts[-1]
        return v0 + (x - n0) * (v1 - v0) / (n1 - n0)
    if len(pts) == 1:
        n0, v0 = pts[0]
        if x == n0:
            return v0
        h = next(h for n, h in points if h is not None and float(n) == n0)
        rate = _rate(h)
        if key == "fgen:time_seconds" and rate:
            return v0 + (x - n0) / rate
        mv = _num(h.get("fgen:mv_time"))
        if key == "fgen:time" and mv is not None and step and mv != v0:
            return v0 + (x - n0) * (v0 - mv) / step
    return None


def _joined(values: list):
    vals = [v for v in values if v is not None]
    if not vals:
        return None
    if all(str(v) == str(vals[0]) for v in vals):
        return vals[0]
    return ",".join(str(v) for v in vals)


def generated_header(sources: list[tuple[float, dict, dict]], x: float, number: int,
                     numbering: str, scale: int, prev_x: float | None = None,
                     step: float | None = None) -> tuple[dict, dict]:
    """(header, header_types) of a generated frame at input frame number x, written as
    output frame `number`. sources: (frame number, header, header types) of the input
    frames it was made from, oldest first. numbering: 'input', 'scaled' or 'sequential';
    scale: the timeline scale of 'scaled' numbering. prev_x: where the frame's motion
    vectors point to (the previous output frame) on the input timeline."""
    heads = [(n, h or {}) for n, h, _ in sources]
    like_h, like_t = (sources[-1][1] or {}), (sources[-1][2] or {})
    out, types = {}, {}
    keys = []
    for _, h, _ in sources:
        for k in (h or {}):
            if k not in keys:
                keys.append(k)
    for k in keys:
        vals = [h.get(k) for _, h in heads]
        if k.startswith("fgen:"):
            if k in FRESH or k.startswith("fgen:source_"):
                continue
            out["fgen:source_" + k[5:]] = _joined(vals)
        elif k in DATING:
            v = _joined([str(v) if v is not None else None for v in vals])
            if v is not None:
                out["fgen:source_" + k.replace(":", "_")] = v
        elif k == "framesPerSecond":
            continue  # below
        else:
            out[k] = like_h.get(k, vals[0])
            if k in like_t:
                types[k] = like_t[k]
    out.update(time_attributes(heads, x, number, numbering, scale, prev_x, step))
    return out, types


def time_attributes(heads: list[tuple[float, dict]], x: float, number: int, numbering: str,
                    scale: int, prev_x: float | None = None, step: float | None = None) -> dict:
    """fgen:frame, fgen:input_frame, fgen:numbering, fgen:time(_seconds), fgen:mv_time and
    the frame rate of an output frame at input frame number x (see the module doc)."""
    d = {"fgen:frame": int(number), "fgen:input_frame": float(x),
         "fgen:numbering": numbering_text(numbering, scale)}
    t = time_on(heads, "fgen:time", x, step)
    d["fgen:time"] = float(x) if t is None else t
    ts = time_on(heads, "fgen:time_seconds", x)
    if ts is not None:
        d["fgen:time_seconds"] = ts
    if prev_x is not None:
        mt = time_on(heads, "fgen:time", prev_x, step)
        if mt is not None or any("fgen:mv_time" in h for _, h in heads):
            d["fgen:mv_time"] = float(prev_x) if mt is None else mt
    last = heads[-1][1] if heads else {}
    rate = _num(last.get("fgen:frame_rate"))
    if rate:
        if numbering in ("input", "scaled"):
            d["fgen:frame_rate"] = rate * (scale if numbering == "scaled" else 1)
        else:
            d["fgen:source_frame_rate"] = rate
    fps = _rate({"framesPerSecond": last.get("framesPerSecond")})
    if fps:
        if numbering in ("input", "scaled"):
            d["framesPerSecond"] = last["framesPerSecond"] if numbering == "input" or \
                scale == 1 else _scaled_fps(last["framesPerSecond"], scale)
        else:
            d["fgen:source_framesPerSecond"] = fps
    return d


def _scaled_fps(fps, scale: int):
    if isinstance(fps, (tuple, list)) and len(fps) == 2:
        return (int(fps[0]) * scale, int(fps[1]))
    return float(fps) * scale


def numbering_text(numbering: str, scale: int) -> str:
    if numbering == "scaled" and scale != 1:
        return f"scaled: output frame = input frame number x {scale}"
    if numbering == "sequential":
        return "sequential: output frames numbered consecutively in time order"
    return "input: output frame = input frame number"


def copy_header(header: dict, x: float, number: int, numbering: str, scale: int,
                mv_scale: float = 1.0) -> dict:
    """Attributes to add to a rendered frame copied into the output (--emit all): its place
    on the output timeline and its frame rate there; when its vectors were rescaled (by
    mv_scale) to reach only the previous output frame, fgen:mv_time moves with them."""
    header = header or {}
    d = time_attributes([(float(x), header)], x, number, numbering, scale, None)
    for k in TIME_KEYS:
        if k in header:
            d[k] = header[k]
    t0, t1 = _num(header.get("fgen:mv_time")), _num(header.get("fgen:time"))
    if t0 is not None and t1 is not None and mv_scale != 1.0:
        d["fgen:mv_time"] = t1 - (t1 - t0) * mv_scale
    d["fgen:rendered"] = 1
    return d


# ----------------------------------------------------------------------------- camera


def interpolate_camera(cam0, cam1, t: float):
    """Camera at fraction t between cam0 and cam1: the rigid motion between them taken in
    part (screw motion: exact for orbits, turns and constant translation), the projection
    interpolated linearly. Non-rigid view matrices: both matrices interpolated linearly.
    None when either is missing."""
    from fgcli.frame import Camera
    from fgcli.ops.gffe import se3_power

    if cam0 is None or cam1 is None:
        return None
    v0 = np.asarray(cam0.world_to_camera, np.float64)
    v1 = np.asarray(cam1.world_to_camera, np.float64)
    p0 = np.asarray(cam0.projection, np.float64)
    p1 = np.asarray(cam1.projection, np.float64)
    proj = (1.0 - t) * p0 + t * p1
    if np.array_equal(v0, v1):
        return Camera(v1.copy(), proj)
    r0, r1 = v0[:3, :3], v1[:3, :3]
    if np.allclose(r0 @ r0.T, np.eye(3), atol=1e-5) and \
            np.allclose(r1 @ r1.T, np.eye(3), atol=1e-5):
        try:
            v = se3_power(v1 @ np.linalg.inv(v0), t) @ v0
            if np.isfinite(v).all():
                return Camera(v, proj)
        except (ArithmeticError, np.linalg.LinAlgError):
            pass
    return Camera((1.0 - t) * v0 + t * v1, proj)


def extrapolate_camera(cam0, cam1, alpha: float, ctx_camera=None):
    """Camera `alpha` input intervals past cam1: the pipeline's own (gffe-extrap's
    camera_x) when it computed one, else gffe-extrap's rigid extrapolation."""
    from fgcli.frame import Camera
    from fgcli.ops.gffe import extrapolate_camera as ex

    if ctx_camera is not None:
        v, p = ctx_camera if isinstance(ctx_camera, tuple) else (
            ctx_camera.world_to_camera, ctx_camera.projection)
        return Camera(np.asarray(v, np.float64), np.asarray(p, np.float64))
    if cam1 is None:
        return None
    try:
        v, p = ex(cam0, cam1, alpha, "rigid")
    except (ValueError, ArithmeticError):
        return None
    return Camera(v, p)


# ----------------------------------------------------------------------------- alpha


def generated_alpha(mv, t: float, prev_t: float, mode: str, alpha0, alpha1):
    """Alpha of a generated frame (see the module doc). mv: its vectors (2, H, W) toward the
    previous output frame, at fraction prev_t (interpolation: of the input interval after
    frame a; extrapolation: past frame b); t its own fraction. alpha0 / alpha1: the
    sources' alpha (frame a / frame b), either may be None. None when no source has one."""
    import torch

    from fgcli.ops import backward_warp

    if alpha0 is None and alpha1 is None:
        return None
    if mode == "interp":
        use_b = alpha0 is None or (t > 0.5 and alpha1 is not None)
        src = alpha1 if use_b else alpha0
        # vectors span t - prev_t; to frame a: t; to frame b: -(1 - t)
        span = t if not use_b else -(1.0 - t)
    else:
        src = alpha1 if alpha1 is not None else alpha0
        span = t if alpha1 is not None else t + 1.0
    if mv is None:
        return src.clone()
    if tuple(src.shape[-2:]) != tuple(mv.shape[-2:]):  # a source at another resolution
        src = torch.nn.functional.interpolate(src[None].float(), size=tuple(mv.shape[-2:]),
                                              mode="bilinear", align_corners=False)[0]
    step = t - prev_t
    if step == 0:
        return src.clone()
    flow = mv.to(torch.float32) * float(span / step)
    out, _ = backward_warp(src.to(torch.float32), flow, mode="bilinear")
    return out.clamp(0.0, 1.0) if float(src.min()) >= 0 and float(src.max()) <= 1 else out


# ----------------------------------------------------------------------------- info


def fgen_metadata(attributes: dict) -> dict:
    """The `fgen:*` attributes of a header, by name without the prefix (what `fgen info`
    shows); the long JSON ones (pipeline, camera matrices) parsed."""
    import json

    out = {}
    for k, v in sorted((attributes or {}).items()):
        if not k.startswith("fgen:"):
            continue
        name = k[5:]
        if name in ("pipeline_json", "world_to_camera", "projection") and isinstance(v, str):
            try:
                v = json.loads(v)
            except ValueError:
                pass
        elif isinstance(v, np.ndarray):
            v = v.tolist()
        elif isinstance(v, (np.floating, np.integer)):
            v = v.item()
        elif isinstance(v, tuple):
            v = list(v)
        out[name] = v
    return out


# ----------------------------------------------------------------------------- the hook


def finish_generated(gen, ctx: dict, f0, f1, a, b, t: float, prev_t: float, mode: str,
                     step: int, numbering: str = "scaled", scale: int = 1):
    """A generated Frame (fgcli.runner.generated_frame) with its own header (time, numbering,
    renamed source attributes), its camera and its alpha; a, b the input frame numbers
    (a None when extrapolating from the first frame), t / prev_t the fractions of the frame
    and of the previous output frame (its vectors' target)."""
    if mode == "interp":
        x, px = a + t * (b - a), a + prev_t * (b - a)
    else:
        x, px = b + t * step, b + prev_t * step
    sources = ([] if f0 is None or a is None else [(a, f0.header, f0.header_types)]) + \
        [(b, f1.header, f1.header_types)]
    header, types = generated_header(sources, x, gen.number, numbering, scale, px, step)
    c0 = None if f0 is None else f0.camera
    if mode == "interp":
        cam = interpolate_camera(c0, f1.camera, t)
    else:
        cam = extrapolate_camera(c0, f1.camera, t, ctx.get("camera_x"))
    al = generated_alpha(ctx.get("mv"), t, prev_t, mode, None if f0 is None else f0.alpha,
                         f1.alpha)
    if al is not None and gen.data_window is not None:
        import torch

        x0, y0, w, h = gen.data_window
        keep = torch.zeros_like(al, dtype=torch.bool)
        keep[..., y0:y0 + h, x0:x0 + w] = True
        al = torch.where(keep, al, torch.zeros_like(al))
    return gen.replace(header=header, header_types=types, camera=cam, alpha=al)
