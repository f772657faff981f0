"""`fgen eval`: the evaluation protocol of docs/design.md section 4.

Input and ground truth share one frame-number timeline. Two sources:
- with ground truth: IN is the rendered input (step >= 2, MVs spanning the input interval),
  GT holds reference frames between input frames / after them;
- held out (--factor N): keep every N-th frame of a full-rate sequence; the kept frames'
  MVs are chained through the dropped frames so they span the kept interval
  (b2(p) = b_k(p) + b_{k-1}(p + b_k(p)), ...), so no vector points into a held-out frame.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from fgcli.errors import InputError, UsageError
from fgcli.frame import Frame


# ----------------------------------------------------------------------------- sources


class GTSource:
    """Rendered input + ground-truth folders on one timeline."""

    def __init__(self, reader_in, reader_gt):
        self.rin, self.rgt = reader_in, reader_gt
        self.inputs = list(reader_in.numbers)
        self.targets = [n for n in reader_gt.numbers if n not in set(self.inputs)]
        if len(self.inputs) < 2:
            raise InputError("evaluation needs at least two input frames", file=reader_in.folder)
        if (reader_in.width, reader_in.height) != (reader_gt.width, reader_gt.height):
            raise InputError(f"ground truth is {reader_gt.width}x{reader_gt.height}, input is "
                             f"{reader_in.width}x{reader_in.height}", file=reader_gt.folder)
        self._cache: dict = {}

    def input(self, n: int) -> Frame:
        key = ("in", n)
        if key not in self._cache:
            self._trim()
            self._cache[key] = self.rin.read(n)
        return self._cache[key]

    def gt(self, n: int) -> Frame:
        key = ("gt", n)
        if key not in self._cache:
            self._trim()
            self._cache[key] = self.rgt.read(n)
        return self._cache[key]

    def fine_mv(self, n: int):
        """Vectors of frame n toward frame n-1 on the fine timeline (for masks)."""
        if n in self.rgt.seq.files:
            return self.gt(n)
        return None

    def _trim(self, keep: int = 8):
        while len(self._cache) > keep:
            self._cache.pop(next(iter(self._cache)))


class HeldOutSource:
    """Full-rate sequence; every N-th frame is input (MVs chained), the rest ground truth."""

    def __init__(self, reader, factor: int):
        if factor < 2:
            raise UsageError("--factor must be >= 2")
        self.r, self.n = reader, factor
        nums = reader.numbers
        if reader.step != 1:
            raise InputError(f"--factor needs a full-rate sequence (frame step 1, found step "
                             f"{reader.step}); use --gt for a rendered input + ground truth",
                             file=reader.folder)
        self.inputs = nums[::factor]
        if len(self.inputs) < 2:
            raise InputError(f"too few frames for --factor {factor}", file=reader.folder)
        kept = set(self.inputs)
        self.targets = [n for n in nums if n not in kept]
        self._cache: dict = {}

    def _read(self, n: int) -> Frame:
        if n not in self._cache:
            while len(self._cache) > 2 * self.n + 4:
                self._cache.pop(next(iter(self._cache)))
            self._cache[n] = self.r.read(n)
        return self._cache[n]

    def input(self, n: int) -> Frame:
        """Kept frame n with its MVs chained back to frame n - N (what a renderer at the
        lower rate writes). The first kept frame has no earlier frames: its one-step vectors
        are scaled by N (constant-velocity assumption)."""
        from fgcli.ops import chain_mv

        f = self._read(n)
        if f.mv is None:
            return f
        chain = [self._read(k).mv for k in range(n, n - self.n, -1) if k in self.r.seq.files]
        if len(chain) == self.n:
            mv = chain_mv(chain)
        else:
            mv = f.mv * self.n
        return f.replace(mv=mv)

    def gt(self, n: int) -> Frame:
        return self._read(n)

    def fine_mv(self, n: int):
        return self._read(n) if n in self.r.seq.files else None


# ----------------------------------------------------------------------------- tasks


@dataclass
class Task:
    mode: str
    a: int | None  # older input (history for extrapolation)
    b: int  # newer input (interp: after the target; extrap: last input <= target)
    alpha: float
    target: int
    prev_time: float = 0.0


def make_tasks(src, mode: str) -> list[Task]:
    ins = src.inputs
    tasks = []
    for g in src.targets:
        if mode == "interp":
            if g <= ins[0] or g >= ins[-1]:
                continue
            i = max(k for k in range(len(ins)) if ins[k] < g)
            a, b = ins[i], ins[i + 1]
            tasks.append(Task("interp", a, b, (g - a) / (b - a), g))
        else:
            if g <= ins[0]:
                continue
            i = max(k for k in range(len(ins)) if ins[k] < g)
            b = ins[i]
            a = ins[i - 1] if i > 0 else None
            step = (ins[1] - ins[0])
            tasks.append(Task("extrap", a, b, (g - b) / step, g))
    # previous output frame on the merged timeline (for the generated frame's MVs)
    for t in tasks:
        t.prev_time = 0.0
    return tasks


# ----------------------------------------------------------------------------- masks


def target_masks(src, task: Task, gt: Frame, rel_tol: float = 0.05):
    """(disoccluded, moving) bool masks (1,H,W) for a ground-truth frame.

    Chain the fine-rate vectors from the target back to the source input frame (the older
    input for interpolation, the last input for extrapolation) with a depth test at every
    step: a pixel is disoccluded when its surface has no source there (off-screen, or a
    nearer surface covers it). Moving: the chained displacement exceeds 0.5 px.
    """
    import torch

    from fgcli.ops import backward_warp, disocclusion_mask, sample_nearest

    src_n = task.a if task.mode == "interp" else task.b
    H, W = gt.height, gt.width
    if gt.mv is None or gt.depth is None:
        return None, None
    disp = torch.zeros(2, H, W)  # chained displacement from the target to frame n - 1
    occluded = torch.zeros(1, H, W, dtype=torch.bool)
    cur_depth = gt.depth  # depth of the tracked surface in frame n
    for n in range(task.target, src_n, -1):
        fn = gt if n == task.target else src.fine_mv(n)
        prev = src.input(n - 1) if n - 1 == src_n else src.fine_mv(n - 1)
        if fn is None or fn.mv is None or prev is None or prev.depth is None:
            return None, None
        if n != task.target:
            cur_depth, _ = sample_nearest(fn.depth, disp)
            step_mv, _ = backward_warp(fn.mv, disp, mode="bilinear")
        else:
            step_mv = fn.mv
        disp = disp + step_mv
        occluded |= disocclusion_mask(cur_depth, disp, prev.depth, rel_tol)
    moving = disp.norm(dim=0, keepdim=True) > 0.5
    return occluded, moving


# ----------------------------------------------------------------------------- scoring


@dataclass
class Scores:
    psnr: list = field(default_factory=list)
    ssim: list = field(default_factory=list)
    flip: list = field(default_factory=list)
    flip_hdr: list = field(default_factory=list)
    sse_dis: float = 0.0
    n_dis: int = 0
    flip_dis: float = 0.0
    sse_mov: float = 0.0
    n_mov: int = 0
    flip_mov: float = 0.0
    per_frame: list = field(default_factory=list)

    def result(self) -> dict:
        def mean(x):
            return float(sum(x) / len(x)) if x else float("nan")

        def psnr_of(sse, n):
            if n == 0:
                return float("nan")
            mse = sse / n
            return float("inf") if mse == 0 else float(10 * math.log10(1.0 / mse))

        return {"psnr": mean(self.psnr), "ssim": mean(self.ssim), "flip": mean(self.flip),
                "flip_hdr": mean(self.flip_hdr),
                "psnr_disoccluded": psnr_of(self.sse_dis, self.n_dis),
                "flip_disoccluded": self.flip_dis / self.n_dis if self.n_dis else float("nan"),
                "psnr_moving": psnr_of(self.sse_mov, self.n_mov),
                "flip_moving": self.flip_mov / self.n_mov if self.n_mov else float("nan"),
                "frames": len(self.psnr)}


def region_box(frames, region: str = "data"):
    """The (x, y, w, h) box to score: region 'data' = the bounding box of the union of the
    frames' data windows (target and inputs; padding outside them carries no data and
    would inflate every score); 'display' or no windowed frame = None (the whole frame)."""
    wins = [getattr(f, "data_window", None) for f in frames if f is not None]
    if region == "display" or all(w is None for w in wins):
        return None
    f0 = next(f for f in frames if f is not None)
    boxes = [w if w is not None else (0, 0, f0.width, f0.height) for w in wins]
    boxes = [b for b in boxes if b[2] > 0 and b[3] > 0] or [(0, 0, 1, 1)]
    x0, y0 = min(b[0] for b in boxes), min(b[1] for b in boxes)
    x1, y1 = max(b[0] + b[2] for b in boxes), max(b[1] + b[3] for b in boxes)
    return (x0, y0, x1 - x0, y1 - y0)


def _crop(t, box):
    if t is None or box is None:
        return t
    x, y, w, h = box
    return t[..., y:y + h, x:x + w]


def score_frame(sc: Scores, out, gt, dis, mov, target: int, hdr: bool = True, box=None):
    import numpy as np

    from fgcli.ops import metrics as M
    from fgcli.ops.color import srgb_oetf

    out, gt, dis, mov = (_crop(t, box) for t in (out, gt, dis, mov))
    o = out.detach().float().cpu()
    g = gt.detach().float().cpu()
    od, gd = srgb_oetf(o), srgb_oetf(g)  # display-referred, for the pooled masked MSE
    p = float(M.psnr(o, g))
    s = float(M.ssim(o, g))
    fl, fmap = M.flip_ldr(g, o, return_map=True)
    sc.psnr.append(p)
    sc.ssim.append(s)
    sc.flip.append(float(fl))
    fh = float("nan")
    if hdr:
        fh = float(M.flip_hdr(g, o))
        sc.flip_hdr.append(fh)
    err = ((od - gd) ** 2).mean(dim=0).numpy()
    fmap = np.asarray(fmap)
    for mask, kind in ((dis, "dis"), (mov, "mov")):
        if mask is None:
            continue
        m = mask[0].cpu().numpy().astype(bool)
        k = int(m.sum())
        if kind == "dis":
            sc.sse_dis += float(err[m].sum()); sc.n_dis += k; sc.flip_dis += float(fmap[m].sum())
        else:
            sc.sse_mov += float(err[m].sum()); sc.n_mov += k; sc.flip_mov += float(fmap[m].sum())
    sc.per_frame.append({"frame": target, "psnr": p, "ssim": s, "flip": float(fl),
                         "flip_hdr": fh})


def evaluate(src, pipelines: list, mode: str, progress: bool = True, device: str = "cpu",
             hdr_flip: bool = True, keep_worst: bool = False, on_frame=None,
             scene_cuts: str = "auto", cut_threshold: float | None = None,
             backend: str = "auto", region: str = "data") -> dict:
    """Run every pipeline on every task; returns {"pipelines": {label: {...}}, ...}.
    on_frame: called with 1 per scored (frame, pipeline) (an executor's progress).
    backend: per-pixel kernels, auto | torch | numba (fgcli.kernels.resolve)."""
    import torch
    from tqdm import tqdm

    from fgcli.pipeline import Timings, frame_facts, run_stages
    from fgcli.runner import RunState, check_device, device_sync, make_ctx

    from fgcli.kernels import resolve

    check_device(device)
    rd = getattr(src, "rin", None) or getattr(src, "r", None)
    backend = resolve(backend, device, rd.width * rd.height if rd is not None else None)
    sync = device_sync(device)
    tasks = make_tasks(src, mode)
    if not tasks:
        raise InputError(f"no ground-truth frames to score in {mode} mode (inputs "
                         f"{src.inputs[:3]}..., targets {src.targets[:3]}...)")
    built = []
    for p in pipelines:
        if mode not in p.modes:
            continue
        built.append((p, p.build(mode), Timings(), Scores()))
    if not built:
        raise UsageError(f"none of the pipelines supports mode '{mode}'")
    masks_cache: dict = {}
    states = {id(b[1]): RunState() for b in built}  # recurrent state per pipeline
    from fgcli.temporal import TemporalChange, step_frames_of

    steps, chains = step_frames_of(src), {}
    tchange = {id(b[1]): TemporalChange(steps, chains=chains) for b in built}
    holes: dict = {}  # pipeline -> [unfilled pixels, pixels] (gffe_hole_fill)
    worst: dict = {}
    compare = None  # the frame every pipeline found hardest, all outputs (--report)
    cuts: list = []
    scored_px, total_px = 0, 0
    from fgcli.progress import LogProgress, wants_log

    if progress and wants_log():  # stderr is a log file: one line now and then
        bar = LogProgress(len(tasks) * len(built), f"eval {mode}")
    else:
        bar = tqdm(total=len(tasks) * len(built), desc=f"eval {mode}", unit="frame",
                   disable=None if progress else True, leave=False)
    with torch.inference_mode():
        for task in tasks:
            gt = src.gt(task.target)
            f1 = src.input(task.b)
            f0 = src.input(task.a) if task.a is not None else None
            if task.target not in masks_cache:
                masks_cache[task.target] = target_masks(src, task, gt)
            dis, mov = masks_cache[task.target]
            box = region_box([gt, f0, f1], region)
            if box is not None:
                scored_px += box[2] * box[3]
            else:
                scored_px += gt.width * gt.height
            total_px += gt.width * gt.height
            g0 = f0.to(device) if f0 is not None else None
            g1 = f1.to(device)
            fctx = make_ctx(g0, g1, task.alpha, mode)
            fctx["scene_cuts"] = scene_cuts
            if cut_threshold is not None:
                fctx["scene_cut_threshold"] = cut_threshold
            facts = frame_facts(fctx)  # once for all pipelines
            outs_here: dict = {}  # this frame's output of every pipeline (--report)
            if "cut_check" in facts:
                cuts.append({"frame": task.target, **facts["cut_check"]})
            for p, stages, tm, sc in built:
                ctx = make_ctx(g0, g1, task.alpha, mode)
                ctx["prev_time"] = task.prev_time
                ctx["state"] = states[id(stages)]
                ctx["backend"] = backend
                ctx = run_stages(stages, ctx, tm, label=str(task.target), sync=sync,
                                 measure_skips=True, facts=dict(facts))
                score_frame(sc, ctx["color"], gt.color, dis, mov, task.target, hdr_flip, box)
                tchange[id(stages)].add(task.target, ctx["color"], gt.color, gt)
                if ctx.get("holes") is not None:
                    hc = holes.setdefault(p.label, [0, 0])
                    hc[0] += int(ctx["holes"])
                    hc[1] += int(ctx["color"].shape[-1] * ctx["color"].shape[-2])
                if keep_worst:
                    w = worst.get(p.label)
                    if w is None or sc.psnr[-1] < w["psnr"]:
                        worst[p.label] = {"psnr": sc.psnr[-1], "frame": task.target,
                                          "out": ctx["color"].detach().cpu().clone(),
                                          "gt": gt.color.clone()}
                    outs_here[p.label] = (ctx["color"].detach().cpu().clone(), sc.psnr[-1])
                bar.update(1)
                if on_frame is not None:
                    on_frame(1)
            if keep_worst:
                from fgcli.report import keep_hardest

                compare = keep_hardest(compare, task.target, gt.color, outs_here)
    bar.close()
    res = {}
    for p, stages_, tm, sc in built:
        r = sc.result()
        r["temporal_change"] = tchange[id(stages_)].result()
        s = tm.summary()
        r.update({"ms_per_frame": s["ms_per_frame"], "stages": s["stages"],
                  "skipped_stage_runs": s["skipped"],
                  "ms_saved_per_frame": s["ms_saved_per_frame"],
                  "per_frame": sc.per_frame})
        dis_frac = [float(m[0].float().mean()) for m, _ in masks_cache.values() if m is not None]
        r["disoccluded_fraction"] = sum(dis_frac) / len(dis_frac) if dis_frac else None
        if p.label in holes:
            r["hole_fill_fraction"] = holes[p.label][0] / max(1, holes[p.label][1])
        res[p.label] = r
    return {"mode": mode, "frames": len(tasks), "inputs": src.inputs,
            "targets": [t.target for t in tasks], "pipelines": res,
            "scene_cuts": {"mode": scene_cuts, "candidates": cuts,
                           "cuts": [c["frame"] for c in cuts if c["cut"]]},
            "display": "sRGB OETF of clip(linear, 0, 1); HDR-FLIP on linear color",
            "backend": backend,
            "region": {"mode": region, "scored_fraction": scored_px / max(1, total_px),
                       "what": ("the whole display window" if scored_px == total_px else
                                "the bounding box of the data windows of the target and its "
                                "input frames (padding outside carries no data)")},
            "_worst": worst, "_compare": compare}


def markdown_table(result: dict) -> str:
    cols = [("psnr", "PSNR dB", "{:.2f}"), ("ssim", "SSIM", "{:.4f}"), ("flip", "LDR-FLIP", "{:.4f}"),
            ("flip_hdr", "HDR-FLIP", "{:.4f}"), ("psnr_disoccluded", "PSNR disocc", "{:.2f}"),
            ("flip_disoccluded", "FLIP disocc", "{:.4f}"), ("psnr_moving", "PSNR moving", "{:.2f}"),
            ("flip_moving", "FLIP moving", "{:.4f}"),
            ("temporal_change", "temporal change", "{:.4f}"),
            ("ms_per_frame", "ms/frame", "{:.1f}")]
    lines = ["| pipeline | " + " | ".join(c[1] for c in cols) + " | stages (median ms) |",
             "|---|" + "---|" * len(cols) + "---|"]
    for name, r in result["pipelines"].items():
        vals = []
        for key, _, fmt in cols:
            v = r.get(key)
            vals.append("n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else fmt.format(v))
        if r.get("ms_per_frame_spread"):  # --repeat N: min-max of the runs' medians
            vals[-1] += " ({:.1f}-{:.1f})".format(*r["ms_per_frame_spread"])
        st = ", ".join(f"{k} {v:.1f}" for k, v in r["stages"].items())
        if r.get("skipped_stage_runs"):
            st += ("; " if st else "") + (f"{r['skipped_stage_runs']} stage runs skipped (not "
                                          f"needed), saving {r['ms_saved_per_frame']:.1f} ms/frame")
        lines.append(f"| {name} | " + " | ".join(vals) + f" | {st} |")
    return "\n".join(lines)
