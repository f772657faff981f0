"""Pipeline files (pipelines/*.toml) checked against the stage registry, and the per-frame
executor that runs the stages, times each one and skips what a frame does not need.

A pipeline file is data:

    name = "mob-fgsr"
    description = "..."
    modes = ["interp", "extrap"]
    [[stage]]
    use = "splat"            # registry name
    id = "splat"             # optional, defaults to `use`; used by --set/--variant
    modes = ["interp"]       # optional: only in these modes
    motion = "quadratic"     # stage options

Per-frame context keys (the contract between the runner and stages):
  inputs : color0, depth0, mv0 (older rendered frame, time 0; None without history in
           extrapolation), color1, depth1, mv1 (newer rendered frame, time 1), alpha, mode
           ("interp": target time alpha in (0,1); "extrap": target time 1 + alpha)
  outputs: color (3,H,W), depth (1,H,W), mv (2,H,W) of the generated frame
"""
from __future__ import annotations

import os
import re
import sys
import time
from dataclasses import dataclass, field

from fgcli.errors import UsageError
from fgcli.stages.base import Stage, get_stage

try:
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - python < 3.11
    import tomli as tomllib

# the checkout's pipelines/ (source and editable installs), then the copy a wheel installs
# under <prefix>/share/fgen/pipelines (pyproject's data-files)
PIPELINE_DIRS = [os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                              "pipelines"),
                 os.path.join(sys.prefix, "share", "fgen", "pipelines")]
TOP_KEYS = {"name", "description", "modes", "stage", "paper", "requires", "scale_only"}
# stage mode of the super-resolution stages: they run once per rendered frame when the
# output is larger than the input (--scale), before the frame-generation stages
SR_MODE = "sr"
STAGE_KEYS = {"use", "id", "modes"}
FINAL_OUTPUTS = ("color", "depth", "mv")
SCENE_CUT_THRESHOLD = 0.45  # FSR 3's symmetric-KL threshold on regional luminance histograms


@dataclass
class StageSpec:
    id: str
    use: str
    opts: dict
    modes: tuple
    line: int
    enabled: bool = True


@dataclass
class Pipeline:
    name: str
    description: str
    modes: tuple
    stages: list[StageSpec]
    path: str
    requires: tuple = ("color", "depth", "mv")
    variant: str | None = None  # label when built from a variant string
    scale_only: bool = False  # a super-resolution baseline: only with --scale > 1

    @property
    def has_sr(self) -> bool:
        """True when the pipeline has its own super-resolution stages (mode "sr")."""
        return any(SR_MODE in st.modes and st.enabled for st in self.stages)

    @property
    def label(self) -> str:
        return self.variant or self.name

    def with_overrides(self, sets: list[str], label: str | None = None,
                       origin: str | None = None) -> "Pipeline":
        """Apply `stage.option=value`, `option=value` (unique option) or `stage=off|on`.
        origin: where the overrides come from ('--set', "variant 'X'"): errors then name
        it and the override instead of the pipeline file."""
        import copy

        p = copy.deepcopy(self)
        origin = origin or (f"variant '{label}'" if label and label != self.name else None)
        for s in sets:
            try:
                touched = p._override(s)
                for st in touched:  # validate the new value now, blaming the override
                    get_stage(st.use)(where=f"{p.path}:{st.line}", **st.opts)
            except UsageError as e:
                if origin is None:
                    raise
                detail = e.detail
                if detail.startswith(f"{p.path}:"):  # "<file>:<line>: message"
                    detail = detail.split(": ", 1)[-1]
                raise UsageError(f"{origin} {s}: {detail}") from None
        p.variant = label
        p.build("interp" if "interp" in p.modes else p.modes[0])  # validate now
        return p

    def _override(self, s: str) -> list:
        """Apply one override in place; the stage specs it changed."""
        p = self
        if "=" not in s:
            raise UsageError(f"bad override '{s}' (use stage.option=value)")
        key, value = s.split("=", 1)
        key, value = key.strip(), value.strip()
        if "." in key:
            sid, opt = key.split(".", 1)
            targets = [st for st in p.stages if st.id == sid or st.use == sid]
            if not targets:
                raise UsageError(f"pipeline '{p.name}' has no stage '{sid}' "
                                 f"(stages: {', '.join(st.id for st in p.stages)})")
            for st in targets:
                cls = get_stage(st.use)
                if opt not in {o.name for o in cls.options}:
                    raise UsageError(f"stage '{sid}' has no option '{opt}' (options: "
                                     f"{', '.join(o.name for o in cls.options) or 'none'})")
                st.opts[opt] = value
            return targets
        stage_hits = [st for st in p.stages if st.id == key or st.use == key]
        if stage_hits and value.lower() in ("off", "on", "false", "true", "0", "1"):
            for st in stage_hits:
                st.enabled = value.lower() in ("on", "true", "1")
            return []
        hits = [st for st in p.stages if key in {o.name for o in get_stage(st.use).options}]
        owners = {st.id for st in hits}
        if not hits:
            raise UsageError(f"pipeline '{p.name}': no stage has option or id '{key}'")
        if len(owners) > 1:
            raise UsageError(f"pipeline '{p.name}': option '{key}' is ambiguous "
                             f"({', '.join(sorted(owners))}); use stage.{key}=...")
        for st in hits:
            st.opts[key] = value
        return hits

    def build(self, mode: str) -> list[tuple[StageSpec, Stage]]:
        if mode not in self.modes and not (mode == SR_MODE and self.has_sr):
            raise UsageError(f"pipeline '{self.name}' does not support mode '{mode}' "
                             f"(modes: {', '.join(self.modes)})")
        out = []
        for st in self.stages:
            if not st.enabled or (st.modes and mode not in st.modes):
                continue
            if (mode == SR_MODE) != (SR_MODE in st.modes):  # sr stages run in mode sr only
                continue
            cls = get_stage(st.use, f"{self.path}:{st.line}")
            out.append((st, cls(where=f"{self.path}:{st.line}", **st.opts)))
        for spec, stage in out:
            stage.configure(out, f"{self.path}:{spec.line}")
        check_flow(self, mode, out)
        return out


# Context keys the runner puts in every frame's context (see the module docstring); a
# stage's declared inputs must come from these or from an earlier stage's outputs.
FRAME_KEYS = frozenset({"color0", "depth0", "mv0", "camera0", "color1", "depth1", "mv1",
                        "camera1", "alpha", "mode", "width", "height", "prev_time", "state",
                        "facts", "number0", "number1"})
# what the super-resolution stages (mode "sr") get instead: one rendered frame (color1,
# depth1, mv1 at the input resolution), its jitter (LR pixels), the scale, and its depth
# and vectors already at the output resolution
SR_FRAME_KEYS = frozenset({"color1", "depth1", "mv1", "camera1", "jitter1", "scale",
                           "depth_hr", "mv_hr", "state", "facts", "number1", "width",
                           "height"})


def check_flow(p: "Pipeline", mode: str, built) -> None:
    """Data flow of one mode: every enabled stage's declared inputs are produced by the
    frame (FRAME_KEYS) or by an earlier stage, and the stages produce color, depth and mv.
    Errors name the file, the stage's line, the stage and the input."""
    have = set(SR_FRAME_KEYS if mode == SR_MODE else FRAME_KEYS)
    for spec, stage in built:
        for k in stage.inputs:
            if k not in have:
                raise UsageError(f"{p.path}:{spec.line}: stage '{spec.id}' ({spec.use}) needs "
                                 f"input '{k}', which neither the frame nor an earlier stage "
                                 f"produces in mode '{mode}'")
        have.update(stage.outputs)
    missing = [k for k in FINAL_OUTPUTS if k not in have]
    if missing:
        raise UsageError(f"{p.path}: pipeline '{p.name}' produces no {', '.join(missing)} "
                         f"in mode '{mode}'")


def flow(p: "Pipeline", mode: str) -> list[dict]:
    """Per enabled stage of a mode: its inputs (with where each comes from: 'frame' or the
    producing stage's id) and outputs."""
    src = {k: "frame" for k in (SR_FRAME_KEYS if mode == SR_MODE else FRAME_KEYS)}
    rows = []
    for spec, stage in p.build(mode):
        ins = [(k, src[k]) for k in stage.inputs]
        ins += [(k, src[k]) for k in stage.optional_inputs if k in src]
        rows.append({"id": spec.id, "inputs": ins, "outputs": list(stage.outputs)})
        for k in stage.outputs:
            src[k] = spec.id
    return rows


def _stage_lines(text: str) -> list[int]:
    return [i + 1 for i, ln in enumerate(text.splitlines()) if ln.strip().startswith("[[stage]]")]


def _key_line(text: str, start: int, key: str) -> int:
    lines = text.splitlines()
    for i in range(start, len(lines)):
        if i > start - 1 and lines[i].strip().startswith("[[") and i != start - 1:
            break
        if re.match(rf"\s*{re.escape(key)}\s*=", lines[i]):
            return i + 1
    return start


def load_pipeline_file(path: str) -> Pipeline:
    with open(path, "rb") as fh:
        raw = fh.read()
    text = raw.decode("utf-8", "replace")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise UsageError(f"{path}: invalid TOML: {e}") from None
    for k in data:
        if k not in TOP_KEYS:
            raise UsageError(f"{path}:{_key_line(text, 1, k)}: unknown key '{k}'")
    name = data.get("name") or os.path.splitext(os.path.basename(path))[0]
    modes = tuple(data.get("modes", ["interp"]))
    lines = _stage_lines(text)
    specs = []
    for i, st in enumerate(data.get("stage", [])):
        line = lines[i] if i < len(lines) else 0
        if "use" not in st:
            raise UsageError(f"{path}:{line}: stage without 'use'")
        cls = get_stage(st["use"], f"{path}:{line}")
        table = {o.name for o in cls.options}
        opts = {}
        for k, v in st.items():
            if k in STAGE_KEYS:
                continue
            if k not in table:
                raise UsageError(f"{path}:{_key_line(text, line, k)}: unknown option '{k}' for "
                                 f"stage '{st['use']}' (options: {', '.join(sorted(table)) or 'none'})")
            opts[k] = v
        smodes = tuple(st.get("modes", ()))
        for m in smodes:
            if m not in modes and m != SR_MODE:
                raise UsageError(f"{path}:{line}: stage mode '{m}' not in pipeline modes {modes}")
        specs.append(StageSpec(id=st.get("id", st["use"]), use=st["use"], opts=opts,
                               modes=smodes, line=line))
    p = Pipeline(name=name, description=data.get("description", ""), modes=modes,
                 stages=specs, path=path, requires=tuple(data.get("requires",
                                                                  ("color", "depth", "mv"))),
                 scale_only=bool(data.get("scale_only", False)))
    for m in modes + ((SR_MODE,) if p.has_sr else ()):
        p.build(m)  # option values are checked here
    return p


def available() -> dict[str, str]:
    found = {}
    for d in PIPELINE_DIRS:
        if os.path.isdir(d):
            for fn in sorted(os.listdir(d)):
                if fn.endswith(".toml"):
                    found.setdefault(fn[:-5], os.path.join(d, fn))
    return found


def load(name_or_variant: str) -> Pipeline:
    """'mob-fgsr', a path to a .toml, or a variant 'mob-fgsr:motion=linear,gap_fill=off'."""
    base, _, rest = name_or_variant.partition(":")
    if base.endswith(".toml") and os.path.isfile(base):
        p = load_pipeline_file(base)
    else:
        avail = available()
        if base not in avail:
            raise UsageError(f"unknown pipeline '{base}' (available: {', '.join(avail)})")
        p = load_pipeline_file(avail[base])
    if rest:
        return p.with_overrides([s for s in rest.split(",") if s], label=name_or_variant)
    return p


# --------------------------------------------------------------------------- execution


@dataclass
class Timings:
    """Per-stage milliseconds, one entry per generated frame; skips logged."""

    stages: dict = field(default_factory=dict)
    total: list = field(default_factory=list)
    io_read: list = field(default_factory=list)
    io_write: list = field(default_factory=list)
    skipped: list = field(default_factory=list)  # (frame label, stage id, reason)
    skip_cost: dict = field(default_factory=dict)  # stage id -> ms of one measured run
    cuts: list = field(default_factory=list)  # scene-cut candidates: {"frame", "score", "cut", ...}

    def add(self, sid: str, ms: float) -> None:
        self.stages.setdefault(sid, []).append(ms)

    @staticmethod
    def median(xs, warmup: int = 1) -> float:
        import statistics

        xs = list(xs)
        if len(xs) > warmup + 1:
            xs = xs[warmup:]
        return float(statistics.median(xs)) if xs else 0.0

    def summary(self) -> dict:
        per = {sid: self.median(v) for sid, v in self.stages.items()}
        saved = 0.0
        for _, sid, _ in self.skipped:
            saved += per.get(sid, self.skip_cost.get(sid, 0.0))
        frames = max(1, len(self.total))
        return {"ms_per_frame": self.median(self.total), "stages": per,
                "ms_saved_per_frame": saved / frames,
                "io_read_ms": self.median(self.io_read, 0), "io_write_ms": self.median(self.io_write, 0),
                "skipped": len(self.skipped), "ms_saved_by_skipping": saved}


def frame_facts(ctx: dict, detect_cuts: bool = True) -> dict:
    """Cheap per-frame facts computed once; stages use them in needed()."""
    import torch

    t0 = time.perf_counter()

    from fgcli.ops._util import reads_back

    mv1, mv0 = ctx.get("mv1"), ctx.get("mv0")
    detect_cuts = (detect_cuts and ctx.get("scene_cuts", "auto") != "off"
                   and ctx.get("color0") is not None)
    score = None
    on_host = reads_back(ctx["color1"])
    extra = {}  # facts only the GPU path has

    def nonzero(t):
        # NaN counts as motion. numba: a scan that stops at the first moving pixel; torch:
        # one min/max pass (2x faster than count_nonzero at 1080p)
        if t is None or t.numel() == 0:
            return False
        if ctx.get("backend") == "numba":
            from fgcli.kernels.ops import any_nonzero

            return any_nonzero(t)
        lo, hi = torch.aminmax(t)
        lo, hi = float(lo), float(hi)
        return not (lo == 0.0 and hi == 0.0)

    if on_host:
        any_motion, history_motion = nonzero(mv1), nonzero(mv0)
        if detect_cuts:
            from fgcli.kernels import op

            score = float(op("scene_change_score_tensor", ctx)(ctx["color0"], ctx["color1"]))
    else:
        # on a GPU every value read back is a host round-trip: the motion tests and the
        # scene-cut histogram score come back together, in one transfer per frame
        from fgcli.ops.scene import scene_change_score_tensor

        vals, slots = [], {}
        for key, t in (("mv1", mv1), ("mv0", mv0)):
            if t is not None and t.numel():
                slots[key] = len(vals)
                vals.extend(torch.aminmax(t))
        if detect_cuts:
            slots["score"] = len(vals)
            vals.append(scene_change_score_tensor(ctx["color0"], ctx["color1"]))
        got = torch.stack([v.float() for v in vals]).tolist() if vals else []

        def moved(key):
            i = slots.get(key)
            return i is not None and not (got[i] == 0.0 and got[i + 1] == 0.0)

        any_motion, history_motion = moved("mv1"), moved("mv0")
        score = got[slots["score"]] if "score" in slots else None
        if "mv1" in slots:  # largest |component| of frame 1's vectors (NaN: unknown)
            i = slots["mv1"]
            extra["mv1_absmax"] = max(abs(got[i]), abs(got[i + 1]))
    facts = {"any_motion": any_motion,
             "has_history": ctx.get("color0") is not None,
             "history_motion": history_motion, **extra}
    if detect_cuts:
        from fgcli.ops import confirm_cut

        # FSR 3's histogram rule finds candidates; a candidate is a cut only when neither a
        # repeat, the frame's own vectors nor a cheap optical flow explain the new frame
        chk = confirm_cut(ctx["color0"], ctx["color1"], ctx.get("mv1"),
                          float(ctx.get("scene_cut_threshold", SCENE_CUT_THRESHOLD)),
                          score=score)
        facts["scene_change"] = chk["score"]
        facts["scene_cut"] = chk["cut"]
        if chk["candidate"]:
            facts["cut_check"] = {"score": round(chk["score"], 4), "cut": chk["cut"],
                                  **{k: (None if v is None else round(v, 4))
                                     for k, v in chk["explain"].items()}}
    else:
        facts["scene_cut"] = False
    cam0, cam1 = ctx.get("camera0"), ctx.get("camera1")
    if cam0 is not None and cam1 is not None:
        import numpy as np

        facts["camera_moved"] = not np.allclose(cam0.world_to_camera, cam1.world_to_camera)
    facts["_ms"] = (time.perf_counter() - t0) * 1000.0
    return facts


def run_stages(stages: list[tuple[StageSpec, Stage]], ctx: dict, timings: Timings | None = None,
               label: str = "", sync=None, measure_skips: bool = False,
               detect_cuts: bool = True, facts: dict | None = None) -> dict:
    """Run the built stages on one frame's context. Returns the context with outputs.

    facts: the cheap per-frame facts (frame_facts) when the caller computed them once for
    several pipelines (their cost, facts["_ms"], is still charged to each). They are timed
    as the pseudo-stage "facts" (motion test, scene-cut histograms).

    A stage whose needed() says no is skipped (its exact skip() outputs are used) and logged
    with the reason. measure_skips: the first time a stage is skipped before it has ever
    run, run it anyway once (output discarded) so the time saved is measured, not guessed.
    """
    t_all = time.perf_counter()
    shared_ms = 0.0
    if facts is not None:
        shared_ms = float(facts.get("_ms", 0.0))
    if facts is None:
        facts = frame_facts(ctx, detect_cuts)
        if timings is not None:
            timings.add("facts", (time.perf_counter() - t_all) * 1000.0)
    elif timings is not None:  # computed once, shared by several pipelines: still charged
        timings.add("facts", shared_ms)
    ctx["facts"] = facts
    if timings is not None and "cut_check" in facts:
        frame = int(label) if label.lstrip("-").isdigit() else label
        timings.cuts.append({"frame": frame, **facts["cut_check"]})
    if facts["scene_cut"]:
        # a camera cut between the two rendered frames: never smear two shots together;
        # every pipeline repeats the nearest frame of the right shot
        ctx.update(cut_outputs(ctx))
        if ctx.get("state") is not None:  # recurrent state never crosses a cut
            ctx["state"].store.clear()
        if timings is not None:
            for spec, _ in stages:
                timings.skipped.append((label, spec.id, f"scene cut (score "
                                        f"{facts['scene_change']:.2f})"))
            timings.total.append((time.perf_counter() - t_all) * 1000.0 + shared_ms)
        return ctx
    i = 0
    while i < len(stages):
        spec, stage = stages[i]
        i += 1
        t0 = time.perf_counter()
        need, why = stage.needed(ctx, facts)
        if need and i < len(stages):  # a fused pass of this stage and the next one
            nspec, nstage = stages[i]
            out = stage.fuse(nstage, ctx, facts)
            if out is not None:
                i += 1
                if sync is not None:
                    sync()
                ctx.update(out)
                if timings is not None:
                    timings.add(f"{spec.id}+{nspec.id}", (time.perf_counter() - t0) * 1000.0)
                continue
        if need:
            out = stage.run(ctx)
        else:
            if measure_skips and timings is not None and spec.id not in timings.skip_cost:
                costs = []
                for _ in range(2):  # the second run is the warm one
                    t1 = time.perf_counter()
                    stage.run(_borrowed(ctx))
                    if sync is not None:
                        sync()
                    costs.append((time.perf_counter() - t1) * 1000.0)
                timings.skip_cost[spec.id] = min(costs)
            t0 = time.perf_counter()
            out = stage.skip(ctx)
            if timings is not None:
                timings.skipped.append((label, spec.id, why))
        if sync is not None:
            sync()
        ctx.update(out)
        if timings is not None and need:
            timings.add(spec.id, (time.perf_counter() - t0) * 1000.0)
    if sync is not None:
        sync()
    if timings is not None:
        timings.total.append((time.perf_counter() - t_all) * 1000.0 + shared_ms)
    missing = [k for k in FINAL_OUTPUTS if ctx.get(k) is None]
    if missing:
        raise UsageError(f"pipeline produced no {', '.join(missing)} (check its stages)")
    return ctx


def _borrowed(ctx: dict) -> dict:
    """A copy of ctx for measuring a skipped stage: results an in-place refinement could
    write into (SplatResult.scratch, tensors marked scratch: fgcli.ops._util) go in as
    non-scratch views, so the measuring run cannot change what the pipeline goes on with."""
    from fgcli.ops._util import unmarked

    return {k: (v.replace(scratch=False) if getattr(v, "scratch", False) is True
                else unmarked(v))
            for k, v in ctx.items()}


def cut_outputs(ctx: dict) -> dict:
    """Outputs at a scene cut: the temporally nearest rendered frame, no motion."""
    import torch

    from fgcli.ops import sanitize_depth, sanitize_values

    use0 = ctx["mode"] == "interp" and ctx["alpha"] <= 0.5
    color, depth = (ctx["color0"], ctx["depth0"]) if use0 else (ctx["color1"], ctx["depth1"])
    mv = ctx["mv1"] if ctx.get("mv1") is not None else ctx.get("mv0")
    return {"color": sanitize_values(color), "depth": sanitize_depth(depth),
            "mv": torch.zeros_like(mv) if mv is not None else torch.zeros(
                2, *color.shape[-2:], device=color.device)}


def describe(p: Pipeline) -> dict:
    out = {"name": p.name, "description": p.description, "modes": list(p.modes),
           "file": p.path, "stages": []}
    for st in p.stages:
        cls = get_stage(st.use)
        opts = {o.name: st.opts.get(o.name, o.default) for o in cls.options}
        out["stages"].append({"id": st.id, "use": st.use, "modes": list(st.modes) or list(p.modes),
                              "enabled": st.enabled, "options": opts})
    out["flow"] = {m: flow(p, m) for m in p.modes + ((SR_MODE,) if p.has_sr else ())}
    return out
