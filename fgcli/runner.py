"""Walk a sequence and generate frames with a pipeline: interpolation and extrapolation.

Keeps only the frames a window needs in memory, carries explicit per-sequence state
(history), times every stage and the EXR I/O separately, writes every generated frame with
its color, depth and MVs atomically, and records the resolved pipeline in fgen-run.json.
"""
from __future__ import annotations

import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from fractions import Fraction

from fgcli.errors import UsageError
from fgcli.frame import Frame
from fgcli.io import atomic
from fgcli.io.layouts import RawFrame
from fgcli.pipeline import Pipeline, Timings, describe, run_stages


def parse_alphas(alpha: str | None, factor: int | None, mode: str) -> list[Fraction]:
    if alpha:
        out = []
        for a in alpha.split(","):
            try:
                v = Fraction(a.strip()).limit_denominator(1024)
            except ValueError:
                raise UsageError(f"bad --alpha value '{a}'") from None
            if mode == "interp" and not (0 < v < 1):
                raise UsageError(f"interpolation alpha must be in (0, 1), got {a}")
            if mode == "extrap" and not v > 0:
                raise UsageError(f"extrapolation alpha must be > 0, got {a}")
            out.append(v)
        return sorted(set(out))
    n = 2 if factor is None else factor
    if n < 2:
        raise UsageError("--factor must be >= 2")
    return [Fraction(k, n) for k in range(1, n)]


def timeline_scale(step: int, times: list[Fraction]) -> int:
    """Smallest m such that rendered frames n*m and generated frames (a + t*step)*m are all
    integers on one frame-number timeline."""
    m = 1
    for t in times:
        m = math.lcm(m, (t * step).denominator)
    return m


def parse_chunk(spec: str | None) -> tuple[int, int] | None:
    """'K/N' (1 <= K <= N) -> (K, N); None -> None."""
    if spec is None or spec == "":
        return None
    try:
        k, n = (int(x) for x in str(spec).split("/"))
    except ValueError:
        raise UsageError(f"bad --chunk '{spec}' (use K/N, e.g. 3/8)") from None
    if n < 1 or not 1 <= k <= n:
        raise UsageError(f"bad --chunk '{spec}': need 1 <= K <= N")
    return k, n


def chunk_slice(total: int, k: int, n: int) -> range:
    """Indices of part k (1-based) of n contiguous, near-equal parts of `total` items; the
    n parts cover range(total) exactly once."""
    return range((k - 1) * total // n, k * total // n)


def pipeline_history(stages) -> int | None:
    """Warm-up jobs the built stages need (Stage.history): None = from the sequence start."""
    need = 0
    for _, st in stages:
        h = getattr(type(st), "history", 0)
        if h is None:
            return None
        need = max(need, int(h))
    return need


def warmup_jobs(selected: list[int], history: int | None) -> list[int]:
    """Job indices to run (in order) so that each selected job sees the state an
    uninterrupted run gives it: the selected ones plus their `history` predecessors."""
    if not selected:
        return []
    if history is None:
        return list(range(0, max(selected) + 1))
    run = set()
    for i in selected:
        run.update(range(max(0, i - history), i + 1))
    return sorted(run)


def _usable_mv(f) -> bool:
    """False when a frame's vectors are flagged invalid everywhere (forward-only files with
    nothing to derive backward vectors from): no stage may read them as motion."""
    v = getattr(f, "mv_valid", None)
    return f.mv is not None and (v is None or bool(v.any()))


def _no_backward(reader) -> dict | None:
    fn = getattr(reader, "frames_without_backward", None)
    frames = fn() if fn else []
    return {"frames": frames, "effect": reader.NO_BACKWARD_EFFECT} if frames else None


def make_ctx(f0: Frame | None, f1: Frame, alpha: float, mode: str) -> dict:
    return {"color0": None if f0 is None else f0.color, "depth0": None if f0 is None else f0.depth,
            "mv0": f0.mv if f0 is not None and _usable_mv(f0) else None,
            "camera0": None if f0 is None else f0.camera,
            "color1": f1.color, "depth1": f1.depth, "mv1": f1.mv, "camera1": f1.camera,
            "overscan1": getattr(f1, "overscan", None),
            "alpha": float(alpha), "mode": mode, "width": f1.width, "height": f1.height,
            "number0": None if f0 is None else getattr(f0, "number", None),
            "number1": getattr(f1, "number", None)}


def content_window(color, depth) -> tuple:
    """(x, y, w, h) bounding the pixels a generated frame has content at (finite depth or
    non-zero color)."""
    import torch

    has = torch.isfinite(depth[0]) | (color != 0).any(0)
    rows, cols = torch.nonzero(has.any(1)).flatten(), torch.nonzero(has.any(0)).flatten()
    if rows.numel() == 0:
        return (0, 0, 0, 0)
    y0, y1, x0, x1 = int(rows[0]), int(rows[-1]), int(cols[0]), int(cols[-1])
    return (x0, y0, x1 - x0 + 1, y1 - y0 + 1)


def generated_frame(ctx: dict, number: int, time_: float, like: Frame,
                    windowed: bool = False) -> Frame:
    """The output frame; windowed (an input had a data window smaller than the display
    window): its data window bounds what it contains."""
    dw = content_window(ctx["color"], ctx["depth"]) if windowed else None
    return Frame(number=number, color=ctx["color"], depth=ctx["depth"], mv=ctx["mv"],
                 header=dict(like.header), header_types=dict(like.header_types), time=time_,
                 data_window=dw)


@dataclass
class RunState:
    """Per-sequence state carried from frame to frame (history for recurrent methods)."""

    history: list = field(default_factory=list)  # previous rendered frames, oldest first
    store: dict = field(default_factory=dict)  # stage-owned recurrent state


class FrameCache:
    """Reads frames on demand, prefetches the next ones on a background thread (EXR decode
    overlaps compute, and the start-up: see run_sequence), and keeps at most `keep` in
    memory (least recently used goes)."""

    def __init__(self, reader, timings: Timings, device: str = "cpu", keep: int = 4):
        import threading
        from concurrent.futures import ThreadPoolExecutor

        self.reader, self.timings, self.device, self.keep = reader, timings, device, keep
        self.frames: dict = {}  # number -> Future[Frame, or RawFrame until finished]
        self.pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="fgen-read")
        self.lock = threading.Lock()  # the reader is used by one thread at a time
        # set once torch is loaded: until then the reader thread only decodes (numpy) and
        # get() finishes those frames (torch tensors over the same memory)
        self.torch_loaded = threading.Event()
        self.split = hasattr(reader, "read_raw") and hasattr(reader, "finish")

    def _load(self, n: int):
        t0 = time.perf_counter()
        with self.lock:
            if self.split and not self.torch_loaded.is_set():
                f = self.reader.read_raw(n)  # no torch: does not wait for its import
            else:
                f = self.reader.read(n)
        self.timings.io_read.append((time.perf_counter() - t0) * 1000.0)
        return f

    def prefetch(self, n: int | None) -> None:
        if n is None:
            return
        if n in self.frames:  # asked for again: most recently used (kept longest)
            self.frames[n] = self.frames.pop(n)
            return
        self.frames[n] = self.pool.submit(self._load, n)
        while len(self.frames) > self.keep:
            self.frames.pop(next(iter(self.frames)))

    def get(self, n: int) -> Frame:
        if n in self.frames:
            self.frames[n] = self.frames.pop(n)  # most recently used last
        else:
            self.prefetch(n)
        f = self.frames[n].result()
        if isinstance(f, RawFrame):  # decoded before torch was loaded: finish it here
            from concurrent.futures import Future
            from contextlib import nullcontext

            # finishing reads no file (almost always): no need to wait for the reader
            # thread's current decode
            reads = getattr(self.reader, "finish_reads", lambda n: True)(n)
            with self.lock if reads else nullcontext():
                f = self.reader.finish(f)
            done = Future()
            done.set_result(f)
            self.frames[n] = done
        return f.to(self.device) if self.device != "cpu" else f

    def close(self) -> None:
        # reads prefetched for frames the run no longer needs (an error, an early guess
        # that missed) are dropped, not decoded
        self.pool.shutdown(wait=True, cancel_futures=True)


class AsyncWriter:
    """Writes frames on background threads (EXR encode overlaps compute); at most
    `depth` writes pending; errors surface on the next submit or on close(). `threads`
    writer threads (FGEN_WRITE_THREADS, default 2 on machines with two or more cores)
    write that many frames at once."""

    def __init__(self, out, timings: Timings, depth: int = 2, threads: int = 1):
        from concurrent.futures import ThreadPoolExecutor

        self.out, self.timings, self.depth = out, timings, depth
        self.pool = ThreadPoolExecutor(max_workers=max(1, threads),
                                       thread_name_prefix="fgen-write")
        self.pending: list = []

    def _write(self, path, frame, kw):
        t0 = time.perf_counter()
        self.out.write(path, frame, **kw)
        self.timings.io_write.append((time.perf_counter() - t0) * 1000.0)

    def submit(self, path, frame, **kw) -> None:
        if self.depth == 0:  # serial: write now, on this thread
            self._write(path, frame, kw)
            return
        while len(self.pending) >= self.depth:
            self.pending.pop(0).result()
        self.pending.append(self.pool.submit(self._write, path, frame, kw))

    def close(self) -> None:
        try:
            for f in self.pending:
                f.result()
        finally:
            self.pool.shutdown(wait=True)


def _cpu_count() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - non-Linux
        return os.cpu_count() or 1


class IOThreads:
    """Thread counts while frames are decoded and encoded on the reader and writer threads
    beside the compute; both settings are process-wide, and restore() puts them back.

    OpenImageIO decodes/encodes a file with a pool of one thread per core by default, and
    torch (and numba) compute with one thread per core: with the reader and writer threads
    running beside the compute, a 2-core machine then runs 4-6 busy threads on 2 cores and
    every one slows the others (measured per frame at 1080p on 2 cores: compute 965 ms
    instead of 380, read 970, write 1110). While the I/O threads run:
    - limit_io(): OpenImageIO and the OpenEXR binding use `FGEN_OIIO_THREADS` threads per
      file (default 1: the reader and the writer already run beside each other and the
      compute; with --device cuda the compute leaves the cores free, and both keep their
      default of one thread per core);
    - limit_compute(): the compute uses at most `FGEN_COMPUTE_THREADS` threads (default:
      the cores less one, at least 1), never more than it was set to (an executor's
      per-worker setting stays).
    restore() before the last writes (nothing else runs then: they get every core).
    """

    def __init__(self):
        self.saved: dict = {}

    @staticmethod
    def _env(name: str, default: int) -> int:
        try:
            return max(1, int(os.environ.get(name, default)))
        except ValueError:
            raise UsageError(f"{name} must be a number of threads, not "
                             f"'{os.environ.get(name)}'") from None

    def limit_io(self, device: str = "cpu") -> None:
        import OpenImageIO as oiio

        if device.startswith("cuda") and "FGEN_OIIO_THREADS" not in os.environ:
            return  # the compute runs on the GPU: the decoder keeps one thread per core
        from fgcli.io import exr

        n = self._env("FGEN_OIIO_THREADS", 1)
        for k in ("threads", "exr_threads"):
            self.saved.setdefault(("oiio", k), oiio.get_int_attribute(k, 0))
            oiio.attribute(k, n)
        was = exr.exr_threads()  # the OpenEXR binding (fgcli.io.exr) alike
        if was is not None:
            self.saved.setdefault("openexr", was)
            exr.set_exr_threads(n)

    def limit_compute(self, backend: str, device: str) -> None:
        if device.startswith("cuda"):
            return
        import torch

        n = self._env("FGEN_COMPUTE_THREADS", max(1, _cpu_count() - 1))
        self.saved.setdefault("torch", torch.get_num_threads())
        torch.set_num_threads(min(self.saved["torch"], n))
        if backend == "numba":
            import numba

            self.saved.setdefault("numba", numba.get_num_threads())
            numba.set_num_threads(min(self.saved["numba"], n))

    def restore(self) -> None:
        for key, v in self.saved.items():
            if key == "torch":
                import torch

                torch.set_num_threads(v)
            elif key == "numba":
                import numba

                numba.set_num_threads(v)
            elif key == "openexr":
                from fgcli.io import exr

                exr.set_exr_threads(v)
            else:
                import OpenImageIO as oiio

                oiio.attribute(key[1], v)
        self.saved.clear()


def read_ahead(reader, budget_mb: int | None = None) -> int:
    """Frames the FrameCache keeps (and so reads ahead): as many as fit in
    `FGEN_READ_AHEAD_MB` (default 512) at 8 float32 planes a frame, 4 to 16 (4 at 4K; 8
    at 1080p: the start-up of a short 1080p run decodes every frame it needs)."""
    if budget_mb is None:
        try:
            budget_mb = int(os.environ.get("FGEN_READ_AHEAD_MB", "512"))
        except ValueError:
            raise UsageError("FGEN_READ_AHEAD_MB must be a number of megabytes, not "
                             f"'{os.environ.get('FGEN_READ_AHEAD_MB')}'") from None
    w, h = getattr(reader, "width", 0) or 0, getattr(reader, "height", 0) or 0
    frame_mb = max(w * h * 8 * 4, 1) / (1 << 20)
    return max(4, min(16, int(budget_mb // frame_mb)))


def first_reads(plan: dict, out, keep: int = 4) -> list[int]:
    """The input frames a run most likely reads first, in order (at most `keep`), to start
    decoding them before the compute libraries are loaded: those of the first copied
    frames and jobs whose outputs will be written. A guess (resumed outputs and the history
    of recurrent stages are known only later): a frame guessed wrong costs one read, never
    a wrong result."""
    def will_write(on: int) -> bool:
        return getattr(out, "overwrite", False) or not os.path.exists(out.path_for(on))

    def needed():
        for n, on in plan["copies"]:
            if will_write(on):
                yield n
        for i in plan["mine"]:
            a, b, _, on, _ = plan["jobs"][i]
            if will_write(on):
                yield b
                if a is not None:
                    yield a

    first: list[int] = []
    for n in needed():
        if n not in first:
            first.append(n)
            if len(first) >= keep:
                break
    return first


def device_sync(device: str):
    if device.startswith("cuda"):
        import torch

        return torch.cuda.synchronize
    return None


def check_device(device: str) -> str:
    """Validate --device and prepare the process for frame-sized tensors."""
    import torch

    from fgcli.ops import tune_allocator

    tune_allocator()  # keep freed frame buffers: page faults cost more than the arithmetic

    if device.startswith("cuda") and not torch.cuda.is_available():
        raise UsageError("--device cuda requested but no CUDA device is available")
    if not (device == "cpu" or device.startswith("cuda")):
        raise UsageError(f"unknown device '{device}' (cpu or cuda[:N])")
    return device


def _progress(total: int, desc: str, enabled: bool):
    from fgcli.progress import LogProgress, wants_log

    if enabled and wants_log():  # stderr is a log file (a farm): one line now and then
        return LogProgress(total, desc)
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="frame", disable=None if enabled else True, file=sys.stderr,
                leave=False)


def plan_outputs(numbers: list[int], step: int, mode: str, times: list[Fraction],
                 count: int = 1, emit: str = "generated",
                 chunk: tuple[int, int] | None = None) -> dict:
    """What a run makes, before any pixel is read: the generation jobs (a, b, alpha,
    output number, previous alpha) in sequence order, the rendered frames copied through
    (emit all) as (input number, output number), the timeline scale m, and for a chunk the
    indices of its jobs ("mine") and its copies. "outputs": this run's output numbers."""
    if mode == "extrap":
        times = sorted({a * k for a in times for k in range(1, count + 1)})
        if len(numbers) > 1 and max(times) >= 1:
            raise UsageError("extrapolated frames would reach the next rendered frame "
                             "(alpha x count must be < 1)")
    m = timeline_scale(step, times)
    jobs = []  # (a_number or None, b_number, alpha, out_number, previous output time)
    if mode == "interp":
        if len(numbers) < 2:
            raise UsageError("interpolation needs at least two rendered frames")
        for a, b in zip(numbers, numbers[1:]):
            for k, t in enumerate(times):
                jobs.append((a, b, t, int((a + t * (b - a)) * m), times[k - 1] if k else 0))
    else:
        for i, b in enumerate(numbers):
            a = numbers[i - 1] if i > 0 else None
            for k, t in enumerate(times):
                jobs.append((a, b, t, int((b + t * step) * m), times[k - 1] if k else 0))
    copies = [(n, n * m) for n in numbers] if emit == "all" else []
    all_outputs = sorted([on for _, on in copies] + [j[3] for j in jobs])
    if chunk is not None:
        part = set(all_outputs[i] for i in chunk_slice(len(all_outputs), *chunk))
        copies = [c for c in copies if c[1] in part]
        mine = [i for i, j in enumerate(jobs) if j[3] in part]
    else:
        mine = list(range(len(jobs)))
    outputs = sorted([on for _, on in copies] + [jobs[i][3] for i in mine])
    return {"numbers": list(numbers), "step": step, "times": times, "m": m, "jobs": jobs,
            "copies": copies, "mine": mine, "outputs": outputs, "total_outputs": len(all_outputs)}


def run_sequence(reader, out, pipeline: Pipeline, mode: str, times: list[Fraction],
                 emit: str = "generated", device: str = "cpu", progress: bool = True,
                 count: int = 1, out_layout: str = "fgen", half: bool = True,
                 compression: str = "zip", command: str = "",
                 chunk: tuple[int, int] | None = None, on_frame=None,
                 scene_cuts: str = "auto", cut_threshold: float | None = None,
                 backend: str = "auto", scale: int = 1, numbering: str = "scaled") -> dict:
    """Generate frames for a whole sequence. times: interpolation alphas, or extrapolation
    alphas (each alpha * k for k in 1..count). Returns the run summary (also written to
    OUT/fgen-run.json, or OUT/fgen-run.chunk-K-of-N.json for a chunk).

    chunk: (K, N): write only part K of N contiguous parts of the output frames (ordered by
    output frame number); the input frames those outputs need (the neighbour across a part
    boundary, and the history of recurrent stages, replayed but not written) are read as
    well, so the union of the N parts is byte-identical to one run.
    on_frame: called with the number of output frames just finished (progress of an
    executor that drives several runs).
    scene_cuts: "auto" (detect camera cuts, repeat the nearest frame across one) or "off";
    cut_threshold: the histogram score that makes a cut candidate (default FSR 3's).
    backend: per-pixel kernels, auto | torch | numba (fgcli.kernels.resolve); in every
    frame's ctx["backend"].
    scale: output resolution / input resolution (fgcli.sr): rendered frames are
    reconstructed at that size (emit all writes them), generated frames made at it.
    numbering: output frame numbers, scaled | input | sequential (fgcli.numbering)."""
    from fgcli.numbering import renumber

    plan = renumber(plan_outputs(reader.numbers, reader.step, mode, times, count, emit, chunk),
                    numbering, mode, emit)
    out.check_all([out.path_for(on) for on in plan["outputs"]])
    timings = Timings()
    # decode the first frames while torch loads and the stages are built (1-3 s of start-up
    # that the reader thread would otherwise sit out)
    threads = IOThreads()
    threads.limit_io(device)
    cache = FrameCache(reader, timings, device, keep=read_ahead(reader))
    try:
        for n in first_reads(plan, out, cache.keep):
            cache.prefetch(n)
        return _run(reader, out, pipeline, mode, plan, cache, threads, timings, emit,
                    device, progress, out_layout, half, compression, command, chunk,
                    on_frame, scene_cuts, cut_threshold, backend, scale)
    finally:
        cache.close()
        threads.restore()


def _run(reader, out, pipeline: Pipeline, mode: str, plan: dict, cache: FrameCache,
         threads: IOThreads, timings: Timings, emit: str, device: str, progress: bool,
         out_layout: str, half: bool, compression: str, command: str, chunk, on_frame,
         scene_cuts: str, cut_threshold: float | None, backend: str, scale: int = 1) -> dict:
    import torch

    from fgcli.kernels import resolve

    cache.torch_loaded.set()
    device = check_device(device)
    cache.device = device
    backend = resolve(backend, device, reader.width * reader.height * scale * scale)
    threads.limit_compute(backend, device)
    stages = pipeline.build(mode)
    kernel_load_s = None
    if backend == "numba" and any(st.uses_kernels for _, st in stages):
        from fgcli.kernels.ops import _cache_cold, families_of, warm

        fams = families_of([st for _, st in stages])  # only what this pipeline calls
        if _cache_cold(fams):
            print("fgen: compiling the numba CPU kernels (first run of this fgen version on "
                  "this machine: one to three minutes on 2 cores; --backend torch skips them)",
                  file=sys.stderr)
        kernel_load_s = warm(families=fams)
        if kernel_load_s > 3.0:
            print(f"fgen: compiled the numba CPU kernels in {kernel_load_s:.0f} s (once per "
                  f"machine and fgen version; cached, later runs load them in < 1 s)",
                  file=sys.stderr)
    numbers, step, times, m, jobs, copies, mine = (
        plan["numbers"], plan["step"], plan["times"], plan["m"], plan["jobs"], plan["copies"],
        plan["mine"])
    from fgcli.io.metadata import copy_header, finish_generated

    numbering = plan.get("numbering", "scaled")
    state = RunState()
    sync = device_sync(device)
    pinfo = describe(pipeline)
    attrs_common = {"fgen:pipeline": pipeline.label, "fgen:mode": mode,
                    "fgen:command_line": command, "fgen:pipeline_json": json.dumps(pinfo)}
    rec = None
    if scale > 1:
        from fgcli.sr import Reconstructor

        attrs_common["fgen:scale"] = scale
        rec = Reconstructor(pipeline, scale, cache.get, numbers, backend, sync, scene_cuts)
    written, skipped_existing, replayed = 0, 0, 0
    windows: dict = {}  # rendered frame -> adaptive rendering window (gffe_window)
    bar = _progress(len(mine) + len(copies), f"{pipeline.label} {mode}", progress)

    def done(k: int = 1) -> None:
        bar.update(k)
        if on_frame is not None and k:
            on_frame(k)

    # two frames encode at once where there are two cores: the encode (zip of float depth
    # and vectors) is the longest per-frame task of a CPU run, ~2x the compute at 1080p
    # (two at once: ~10 % less wall time end to end, docs/performance.md)
    writer = AsyncWriter(out, timings, depth=int(os.environ.get("FGEN_WRITE_QUEUE", "2")),
                         threads=IOThreads._env("FGEN_WRITE_THREADS",
                                                2 if _cpu_count() > 1 else 1))
    wkw = {"layout": out_layout, "half": half, "compression": compression}
    try:
        with torch.inference_mode():
            def copy_out(n: int, on: int) -> None:
                nonlocal written, skipped_existing
                path = out.path_for(on)
                if out.should_write(path):
                    f = cache.get(n) if rec is None else rec.frame(n, timings)
                    mv_scale = 1.0
                    if f.mv is not None and n != numbers[0]:
                        # in the merged sequence the previous output frame is the last
                        # generated one: rescale the rendered vectors (linear motion)
                        mv_scale = 1.0 - float(max(times))
                        f = f.replace(mv=f.mv * mv_scale)
                    writer.submit(path, f.replace(number=on).to("cpu"), **wkw,
                                  attributes={**attrs_common, "fgen:source_frames": str(n),
                                              **copy_header(f.header, n, on, numbering, m,
                                                            mv_scale)})
                    written += 1
                else:
                    skipped_existing += 1
                done(1)

            # the copies go out in frame order between the jobs that read the same frames,
            # so that a reconstruction (--scale) runs through the sequence once
            pending = list(copies)
            write = [i for i in mine if out.should_write(out.path_for(jobs[i][3]))]
            skipped_existing += len(mine) - len(write)
            done(len(mine) - len(write))
            # recurrent stages: replay (compute, do not write) the jobs their state needs
            todo = warmup_jobs(write, pipeline_history(stages))
            to_write = set(write)
            replayed = len(todo) - len(write)
            for i, ji in enumerate(todo):
                a, b, t, on, prev_t = jobs[ji]
                while pending and pending[0][0] <= b:
                    copy_out(*pending.pop(0))
                f1 = cache.get(b)
                f0 = cache.get(a) if a is not None else None
                # decode the next jobs' frames while this one computes (as many as the
                # cache holds besides this pair)
                for nxt in todo[i + 1:i + 1 + max(1, cache.keep // 2)]:
                    cache.prefetch(jobs[nxt][1])
                    cache.prefetch(jobs[nxt][0])
                if rec is not None:
                    from fgcli.sr import generate

                    ctx = generate(stages, pipeline.has_sr, rec, f0, f1, float(t), mode,
                                   state, scale, backend,
                                   timings if ji in to_write else None, label=str(on),
                                   sync=sync, prev_time=float(prev_t))
                else:
                    ctx = make_ctx(f0, f1, float(t), mode)
                    ctx["state"] = state
                    ctx["prev_time"] = float(prev_t)
                    ctx["scene_cuts"] = scene_cuts
                    ctx["backend"] = backend
                    if cut_threshold is not None:
                        ctx["scene_cut_threshold"] = cut_threshold
                    ctx = run_stages(stages, ctx, timings if ji in to_write else None,
                                     label=str(on), sync=sync)
                if ji not in to_write:
                    continue
                if ctx.get("render_window") is not None:
                    windows[str(b)] = ctx["render_window"]
                base, span = (b, step) if mode == "extrap" else (a, b - a)
                windowed = rec is None and (getattr(f1, "data_window", None) is not None
                                            or getattr(f0, "data_window", None) is not None)
                gen = generated_frame(ctx, on, (float(base) + float(t) * span) * m, f1, windowed)
                gen = finish_generated(gen, ctx, f0, f1, a, b, float(t), float(prev_t), mode,
                                       step, numbering, m)
                src = f"{a},{b}" if a is not None else f"{b}"
                writer.submit(out.path_for(on), gen.to("cpu"), **wkw,
                              attributes={**attrs_common, "fgen:alpha": float(t),
                                          "fgen:source_frames": src})
                written += 1
                done(1)
            for n, on in pending:
                copy_out(n, on)
    finally:
        cache.close()  # nothing more to read
        threads.restore()  # the writes still queued get every core
        writer.close()
    bar.close()
    reader.warn_nonfinite()
    if rec is not None:
        from fgcli.sr import warn_no_jitter

        warn_no_jitter(rec.no_jitter, reader.folder)
    summary = {"pipeline": pinfo, "mode": mode, "alphas": [str(t) for t in times],
               "input": reader.folder, "input_frames": numbers, "timeline_scale": m,
               "numbering": numbering, "numbering_note": plan.get("note"),
               "chunk": None if chunk is None else f"{chunk[0]}/{chunk[1]}",
               "no_backward_vectors": _no_backward(reader),
               "outputs": [os.path.basename(out.path_for(on)) for on in plan["outputs"]],
               "written": written, "skipped_existing": skipped_existing,
               "replayed_for_history": replayed,
               **({"render_windows": windows} if windows else {}), "stale_temp_removed": len(out.stale_removed),
               "timings": timings.summary(),
               "skipped_stages": [{"frame": f, "stage": s, "why": w} for f, s, w in timings.skipped],
               "scene_cuts": {"mode": scene_cuts, "candidates": timings.cuts,
                              "cuts": [c["frame"] for c in timings.cuts if c["cut"]]},
               "command": command, "device": device, "backend": backend, "scale": scale,
               **({"gbuffer_only_inputs": list(getattr(reader, "gbuffer_only", []))}
                  if getattr(reader, "gbuffer_only", None) else {}),
               **({"jitter_missing": rec.no_jitter} if rec is not None and rec.no_jitter
                  else {}),
               **({"sr_history_reset_at_cuts": rec.cuts} if rec is not None and rec.cuts
                  else {}),
               "kernel_load_ms": None if kernel_load_s is None else round(kernel_load_s * 1e3, 1)}
    name = "fgen-run.json" if chunk is None else f"fgen-run.chunk-{chunk[0]}-of-{chunk[1]}.json"
    atomic.write_text(os.path.join(out.path, name), json.dumps(summary, indent=1))
    return summary
