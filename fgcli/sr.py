"""Output at a multiple of the input resolution (--scale): reconstruct every rendered frame
at high resolution (HR), generate frames at HR, and score both kinds (SS / ESS).

- SS frames ("super sampled"): the rendered times, reconstructed at HR by the pipeline's
  super-resolution stages (mode "sr"), or by the bicubic `upscale` stage for pipelines that
  have none.
- ESS frames ("extrapolated super sampled", the ExtraSS paper's split): the generated times.
  A pipeline with SR stages generates them from the HR reconstructions (Mob-FGSR's ISR /
  ESR); any other pipeline generates them at the input resolution and the result is
  upscaled (so every pipeline stays comparable in one table).

Depth and vectors go to HR consistently: the nearest surface of the 2x2 LR samples around
each HR pixel (never an average across an edge), vectors scaled by s
(fgcli.ops.sr.upsample_geometry).
"""
from __future__ import annotations

import sys
import time

from fgcli.errors import InputError, UsageError
from fgcli.frame import Frame
from fgcli.pipeline import SR_MODE, Pipeline, StageSpec, Timings, frame_facts, run_stages

JITTER_KEYS = ("fgen:jitter_x", "fgen:jitter_y")


def frame_jitter(f: Frame) -> tuple[float, float] | None:
    """A frame's sub-pixel jitter (input pixels, x right, y down: pixel (col, row) was
    sampled at (col + 0.5 + jx, row + 0.5 + jy) of the unjittered grid), from, in order:
    the header's fgen:jitter_x/y (fgen synth), a sidecar's per-frame `jitter_px` (the
    reader puts it in the header), or an off-centre principal point of a perspective
    projection (the jittered projection engines render with: jx = P[0][2] W / 2,
    jy = -P[1][2] H / 2; only offsets within one pixel count as jitter, a larger one is
    a lens shift). None: the frame carries none."""
    h = f.header or {}
    if all(k in h for k in JITTER_KEYS):
        try:
            return float(h[JITTER_KEYS[0]]), float(h[JITTER_KEYS[1]])
        except (TypeError, ValueError):
            raise InputError(f"jitter attributes are not numbers: "
                             f"{h[JITTER_KEYS[0]]!r}, {h[JITTER_KEYS[1]]!r}",
                             file=f.source, frame=f.number) from None
    cam = f.camera
    if cam is not None:
        import numpy as np

        p = np.asarray(cam.projection, dtype=np.float64)
        if p.shape == (4, 4) and p[3, 2] == -1.0 and p[3, 3] == 0.0:  # perspective
            jx, jy = p[0, 2] * f.width / 2.0, -p[1, 2] * f.height / 2.0
            if (jx, jy) != (0.0, 0.0) and abs(jx) <= 1.0 and abs(jy) <= 1.0:
                return float(jx), float(jy)
    return None


def upscale_frame(f: Frame, scale: int, color=None, jitter=None, depth=None,
                  mv=None) -> Frame:
    """A frame at scale x its size: colour (the given HR colour, or the bicubic jitter-aware
    upscale of f's), alpha bicubic (clamped to [0, 1]), depth/vectors (the given HR ones,
    or the nearest surface of the 2x2 LR samples)."""
    import torch

    from fgcli.ops.sr import upsample_geometry, upscale

    jit = jitter if jitter is not None else (frame_jitter(f) or (0.0, 0.0))
    if color is None:
        color = upscale(f.color, scale, jit)
    if depth is None:
        depth, mv, _ = upsample_geometry(f.depth, f.mv, scale, jit)
    alpha = None
    if f.alpha is not None:
        alpha = upscale(f.alpha, scale, jit).clamp_(0.0, 1.0)
    if mv is None:
        mv = torch.zeros(2, *depth.shape[-2:])
    return Frame(number=f.number, color=color, depth=depth, mv=mv, alpha=alpha,
                 camera=f.camera, header=dict(f.header), header_types=dict(f.header_types),
                 source=f.source, time=f.time)


_UPSCALE_SPEC = StageSpec(id="upscale", use="upscale", opts={}, modes=(SR_MODE,), line=0)


class Reconstructor:
    """HR reconstructions of a sequence's rendered frames, made in frame order (recurrent
    SR state: the HR history), the last few kept. read(n) -> the LR Frame n; numbers: the
    rendered (shaded) frames in order. Asking for an earlier frame than the last one made
    starts over from the first frame (what a chunk of a farm run does: its state is then
    the one an uninterrupted run has)."""

    def __init__(self, pipeline: Pipeline, scale: int, read, numbers, backend: str = "torch",
                 sync=None, scene_cuts: str = "auto", keep: int = 4):
        from fgcli.runner import RunState
        from fgcli.stages.sr import Upscale

        self.scale, self.read, self.numbers = scale, read, list(numbers)
        self.backend, self.sync, self.scene_cuts, self.keep = backend, sync, scene_cuts, keep
        if pipeline.has_sr:
            self.stages = pipeline.build(SR_MODE)
        else:
            self.stages = [(_UPSCALE_SPEC, Upscale())]
        self.state = RunState()
        self.made: dict = {}
        self.pos = -1
        self.prev = None  # the last LR frame (scene cuts)
        self.no_jitter: list = []  # frames read without jitter metadata
        self.cuts: list = []

    def frame(self, n: int, timings: Timings | None = None) -> Frame:
        if n in self.made:
            return self.made[n]
        if n not in self.numbers:
            raise InputError("no rendered frame to reconstruct", frame=n)
        i = self.numbers.index(n)
        if i <= self.pos:  # start over: the state must be an uninterrupted run's
            from fgcli.runner import RunState

            self.state, self.pos, self.made, self.prev = RunState(), -1, {}, None
        for k in range(self.pos + 1, i + 1):
            self._make(self.numbers[k], timings)
            self.pos = k
        return self.made[n]

    def _make(self, n: int, timings: Timings | None) -> None:
        from fgcli.ops.sr import upsample_geometry

        f = self.read(n)
        jit = frame_jitter(f)
        if jit is None:
            if n not in self.no_jitter:  # (a run that starts over reads it again)
                self.no_jitter.append(n)
            jit = (0.0, 0.0)
        t0 = time.perf_counter()
        depth_hr, mv_hr, _ = upsample_geometry(f.depth, f.mv, self.scale, jit)
        if timings is not None:
            timings.add("geometry_up", (time.perf_counter() - t0) * 1000.0)
        ctx = {"color1": f.color, "depth1": f.depth, "mv1": f.mv, "camera1": f.camera,
               "jitter1": jit, "scale": self.scale, "depth_hr": depth_hr, "mv_hr": mv_hr,
               "state": self.state, "number1": n, "width": f.width * self.scale,
               "height": f.height * self.scale, "backend": self.backend,
               "scene_cuts": self.scene_cuts}
        fctx = {"color0": None if self.prev is None else self.prev.color,
                "color1": f.color, "mv1": f.mv, "mv0": None, "backend": self.backend,
                "scene_cuts": self.scene_cuts}
        facts = frame_facts(fctx)
        if facts.get("scene_cut"):  # no history across a camera cut
            self.state.store.clear()
            if n not in self.cuts:  # (a run that starts over meets it again)
                self.cuts.append(n)
        facts["scene_cut"] = False
        ctx = run_stages(self.stages, ctx, timings, label=str(n), sync=self.sync, facts=facts)
        hr = upscale_frame(f, self.scale, color=ctx["color"], jitter=jit,
                           depth=ctx["depth"], mv=ctx["mv"])
        self.prev = f
        self.made[n] = hr
        while len(self.made) > self.keep:
            self.made.pop(next(iter(self.made)))


def generate(pipeline_stages, has_sr: bool, rec: Reconstructor, f0: Frame | None, f1: Frame,
             alpha: float, mode: str, state, scale: int, backend: str,
             timings: Timings | None = None, label: str = "", sync=None,
             prev_time: float = 0.0, facts: dict | None = None) -> dict:
    """One generated frame at HR: from the HR reconstructions (pipelines with SR stages)
    or generated at the input resolution and upscaled. Returns the stage context (color,
    depth, mv at HR)."""
    from fgcli.ops.sr import upsample_geometry, upscale
    from fgcli.runner import make_ctx

    if has_sr:
        h1 = rec.frame(f1.number, timings)
        h0 = rec.frame(f0.number, timings) if f0 is not None else None
        ctx = make_ctx(h0, h1, alpha, mode)
    else:
        ctx = make_ctx(f0, f1, alpha, mode)
    ctx["state"], ctx["backend"], ctx["prev_time"] = state, backend, prev_time
    ctx = run_stages(pipeline_stages, ctx, timings, label=label, sync=sync,
                     facts=None if has_sr else facts)
    if not has_sr:
        t0 = time.perf_counter()
        color = upscale(ctx["color"], scale)
        depth, mv, _ = upsample_geometry(ctx["depth"], ctx["mv"], scale)
        ctx.update(color=color, depth=depth, mv=mv)
        if timings is not None:
            timings.add("upscale_out", (time.perf_counter() - t0) * 1000.0)
            timings.total[-1] += (time.perf_counter() - t0) * 1000.0
    return ctx


def warn_no_jitter(frames: list, where: str) -> None:
    """One warning per run for rendered frames read without jitter metadata."""
    if frames:
        print(f"warning: {where}: {len(frames)} input frame(s) carry no jitter "
              f"(fgen:jitter_x/y, or jitter_px in cameras.json; first: frame {frames[0]}):"
              " scored as jitter 0", file=sys.stderr)


# ----------------------------------------------------------------------------- evaluation


class ScaledGTSource:
    """A low-resolution rendered input and its ground truth at scale x its size, on one
    frame-number timeline. inputs: the shaded input frames; G-buffer-only input frames
    (no colour) are never inputs: their numbers are generated (ESS) targets.
    ss_targets: ground-truth frames at the inputs' numbers; targets: the other ones."""

    def __init__(self, reader_in, reader_gt, scale: int):
        self.rin, self.rgt, self.scale = reader_in, reader_gt, scale
        self.gbuffer_only = sorted(getattr(reader_in, "gbuffer_only", ()) or ())
        self.inputs = list(reader_in.numbers)  # shaded frames only
        if len(self.inputs) < 2:
            raise InputError("evaluation needs at least two shaded input frames",
                             file=reader_in.folder)
        want = (reader_in.width * scale, reader_in.height * scale)
        if (reader_gt.width, reader_gt.height) != want:
            raise InputError(f"ground truth is {reader_gt.width}x{reader_gt.height}; with "
                             f"--scale {scale} it must be {want[0]}x{want[1]} (the input is "
                             f"{reader_in.width}x{reader_in.height})", file=reader_gt.folder)
        ins = set(self.inputs)
        self.ss_targets = [n for n in reader_gt.numbers if n in ins]
        self.targets = [n for n in reader_gt.numbers if n not in ins]
        self._cache: dict = {}

    def _get(self, key, fn):
        if key not in self._cache:
            while len(self._cache) > 10:
                self._cache.pop(next(iter(self._cache)))
            self._cache[key] = fn()
        return self._cache[key]

    def input(self, n: int) -> Frame:
        return self._get(("in", n), lambda: self.rin.read(n))

    def gt(self, n: int) -> Frame:
        return self._get(("gt", n), lambda: self.rgt.read(n))

    def fine_mv(self, n: int):
        return self.gt(n) if n in self.rgt.seq.files else None


class _HRView:
    """The ground truth seen as the input for masks at HR: fine vectors and depth of every
    frame number come from the ground-truth frames."""

    def __init__(self, src: ScaledGTSource):
        self.src = src

    def input(self, n: int):
        f = self.src.fine_mv(n)
        if f is None:
            raise KeyError(n)
        return f

    def fine_mv(self, n: int):
        return self.src.fine_mv(n)


def _masks(view, task, gt):
    from fgcli.evaluate import target_masks

    try:
        return target_masks(view, task, gt)
    except KeyError:
        return None, None


def evaluate_scaled(src: ScaledGTSource, pipelines: list, mode: str, progress: bool = True,
                    device: str = "cpu", hdr_flip: bool = True, keep_worst: bool = False,
                    on_frame=None, scene_cuts: str = "auto", cut_threshold: float | None = None,
                    backend: str = "auto", region: str = "data") -> dict:
    """Score pipelines on SS and ESS frames at src.scale x the input resolution. The
    result has the usual keys (means over every scored frame) and, per pipeline, "ss" and
    "ess" objects with the same metric keys."""
    import torch
    from tqdm import tqdm

    from fgcli.evaluate import Scores, Task, make_tasks, region_box, score_frame
    from fgcli.kernels import resolve
    from fgcli.runner import RunState, check_device, device_sync, make_ctx
    from fgcli.temporal import TemporalChange

    check_device(device)
    s = src.scale
    backend = resolve(backend, device, src.rin.width * src.rin.height * s * s)
    sync = device_sync(device)
    tasks = make_tasks(src, mode)
    ins = src.inputs
    if mode == "interp":
        ss = [n for n in src.ss_targets if ins[0] <= n <= ins[-1]]
    else:
        ss = list(src.ss_targets)
    events = sorted([(n, 0, None) for n in ss] + [(t.target, 1, t) for t in tasks],
                    key=lambda e: (e[0], e[1]))
    if not events:
        raise InputError(f"no ground-truth frames to score at --scale {s} in {mode} mode")

    def read(n):
        return src.input(n).to(device) if device != "cpu" else src.input(n)

    built, chains = [], {}
    for p in pipelines:
        if mode not in p.modes:
            continue
        built.append({"p": p, "stages": p.build(mode),
                      "rec": Reconstructor(p, s, read, ins, backend, sync, scene_cuts),
                      "tm_ss": Timings(), "tm_ess": Timings(), "ss": Scores(),
                      "ess": Scores(), "all": Scores(), "state": RunState(),
                      **{k: TemporalChange(src.fine_mv, chains=chains)
                         for k in ("tc", "tc_ss", "tc_ess")}})
    if not built:
        raise UsageError(f"none of the pipelines supports mode '{mode}'")
    view = _HRView(src)
    worst: dict = {}
    bar = tqdm(total=len(events) * len(built), desc=f"eval {mode} x{s}", unit="frame",
               disable=None if progress else True, leave=False)
    with torch.inference_mode():
        for n, kind, task in events:
            gt = src.gt(n)
            box = region_box([gt], region)
            facts = None
            if kind == 0:
                i = ins.index(n)
                dis, mov = (_masks(view, Task("extrap", None, ins[i - 1], 1.0, n), gt)
                            if i > 0 else (None, None))
            else:
                dis, mov = _masks(view, task, gt)
                f1 = read(task.b)
                f0 = read(task.a) if task.a is not None else None
                fctx = make_ctx(f0, f1, task.alpha, mode)
                fctx["scene_cuts"] = scene_cuts
                if cut_threshold is not None:
                    fctx["scene_cut_threshold"] = cut_threshold
                facts = frame_facts(fctx)
            for b in built:
                rec = b["rec"]
                if kind == 0:
                    color = rec.frame(n, b["tm_ss"]).color
                    part = "ss"
                else:
                    # the rendered frames' reconstructions are charged to SS
                    rec.frame(task.b, b["tm_ss"])
                    if task.a is not None:
                        rec.frame(task.a, b["tm_ss"])
                    ctx = generate(b["stages"], b["p"].has_sr, rec, f0, f1, task.alpha, mode,
                                   b["state"], s, backend, b["tm_ess"], label=str(n),
                                   sync=sync, prev_time=task.prev_time,
                                   facts=None if facts is None else dict(facts))
                    color = ctx["color"]
                    part = "ess"
                for key in (part, "all"):
                    score_frame(b[key], color, gt.color, dis, mov, n, hdr_flip, box)
                for key in ("tc", "tc_" + part):
                    b[key].add(n, color, gt.color, gt)
                if keep_worst:
                    w = worst.get(b["p"].label)
                    if w is None or b["all"].psnr[-1] < w["psnr"]:
                        worst[b["p"].label] = {"psnr": b["all"].psnr[-1], "frame": n,
                                               "out": color.detach().cpu().clone(),
                                               "gt": gt.color.clone()}
                bar.update(1)
                if on_frame is not None:
                    on_frame(1)
    bar.close()
    res = {}
    no_jitter = []
    for b in built:
        r = b["all"].result()
        r["temporal_change"] = b["tc"].result()
        for part, tm in (("ss", b["tm_ss"]), ("ess", b["tm_ess"])):
            pr = b[part].result()
            sm = tm.summary()
            pr.update({"temporal_change": b["tc_" + part].result(),
                       "ms_per_frame": sm["ms_per_frame"], "stages": sm["stages"],
                       "skipped_stage_runs": sm["skipped"],
                       "ms_saved_per_frame": sm["ms_saved_per_frame"],
                       "per_frame": b[part].per_frame})
            r[part] = pr
        r.update({"ms_per_frame": r["ess"]["ms_per_frame"] if tasks else r["ss"]["ms_per_frame"],
                  "stages": {**{f"sr:{k}": v for k, v in r["ss"]["stages"].items()},
                             **r["ess"]["stages"]},
                  "skipped_stage_runs": r["ess"]["skipped_stage_runs"],
                  "ms_saved_per_frame": r["ess"]["ms_saved_per_frame"],
                  "per_frame": b["all"].per_frame})
        res[b["p"].label] = r
        no_jitter = no_jitter or b["rec"].no_jitter
    warn_no_jitter(no_jitter, src.rin.folder)
    return {"mode": mode, "scale": s, "frames": len(events), "inputs": ins,
            "targets": [e[0] for e in events], "ss_frames": ss,
            "ess_frames": [t.target for t in tasks],
            "gbuffer_only_inputs": src.gbuffer_only, "pipelines": res,
            "scene_cuts": {"mode": scene_cuts, "candidates": [],
                           "cuts": sorted({c for b in built for c in b["rec"].cuts})},
            "display": "sRGB OETF of clip(linear, 0, 1); HDR-FLIP on linear color",
            "backend": backend,
            "region": {"mode": region, "scored_fraction": 1.0,
                       "what": "the whole display window" if region == "display" else
                               "the ground truth's data window"},
            "jitter_missing": no_jitter, "_worst": worst}


def markdown_tables(result: dict) -> str:
    """The SS and ESS tables of a scaled evaluation (the ExtraSS paper's Table 1 split)."""
    from fgcli.evaluate import markdown_table

    out = []
    for part, title in (("ss", "SS frames (rendered times, reconstructed)"),
                        ("ess", "ESS frames (generated times)")):
        rows = {k: v[part] for k, v in result["pipelines"].items() if v[part]["frames"]}
        if rows:
            out.append(f"## {title}, x{result['scale']}")
            out.append(markdown_table({"pipelines": rows}))
    return "\n".join(out)
