"""Batch runs: several sequences, farm chunks, and the task an executor runs.

A RunTask is everything one `run_sequence` call needs, as plain picklable data, so the same
task runs in this process (the default executor) or on a Dask worker (fgcli.executor).
No torch or Dask import at module level.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field, replace

from fgcli.errors import FgenError, InputError, UsageError


@dataclass(frozen=True)
class RunTask:
    mode: str  # "interp" | "extrap"
    folder: str
    pattern: str | None
    out_dir: str
    pipeline: str
    sets: tuple = ()
    device: str = "cpu"
    times: tuple = ()
    emit: str = "generated"
    count: int = 1
    in_kw: dict = field(default_factory=dict)
    out_kw: dict = field(default_factory=dict)
    command: str = ""
    chunk: tuple | None = None  # (K, N)
    name: str = ""  # the sequence's name in messages
    scene_cuts: str = "auto"
    cut_threshold: float | None = None
    backend: str = "auto"  # --backend: auto | torch | numba
    scale: int = 1  # --scale: output resolution / input resolution
    numbering: str = "scaled"  # --numbering: scaled | input | sequential (fgcli.numbering)

    def label(self) -> str:
        c = f" chunk {self.chunk[0]}/{self.chunk[1]}" if self.chunk else ""
        return f"{self.name or self.folder}{c}"


def _seq_name(prefix: str) -> str:
    return re.sub(r"[._\-]+$", "", prefix)


def expand_inputs(in_dirs, out_dir: str, in_kw: dict) -> list[tuple[str, str, str | None, str]]:
    """(name, folder, pattern, output folder) per input sequence. One sequence writes into
    OUT itself; several (several input folders, or a --pattern matching several sequences
    in a folder) write into OUT/<name>/, name = the folder's name and/or the sequence's
    file prefix."""
    from fgcli.io.sequence import find_sequences

    if isinstance(in_dirs, str):
        in_dirs = [in_dirs]
    pattern = in_kw.get("pattern")
    found = []
    for folder in in_dirs:
        if pattern is None:  # one sequence per folder, as a plain run expects
            found.append((folder, None, [None]))
            continue
        seqs = find_sequences(folder, pattern)
        found.append((folder, pattern, [s.pattern for s in seqs] if len(seqs) > 1 else [pattern]))
    out = []
    several = len(in_dirs) > 1 or any(len(p) > 1 for _, _, p in found)
    for folder, pattern, pats in found:
        base = os.path.basename(os.path.normpath(folder))
        for p in pats:
            if not several:
                out.append((base, folder, p, out_dir))
                continue
            parts = []
            if len(in_dirs) > 1:
                parts.append(base)
            if len(pats) > 1:
                parts.append(_seq_name(p.split("#")[0]) or "seq")
            name = "/".join(parts)
            out.append((name, folder, p, os.path.join(out_dir, *parts)))
    dests = [o[3] for o in out]
    dup = sorted({d for d in dests if dests.count(d) > 1})
    if dup:
        raise UsageError(f"several inputs would write into one output folder: {dup[0]} "
                         "(give the input folders distinct names)")
    return out


def open_task(task: RunTask):
    """The reader, output folder and pipeline of a task."""
    from fgcli import pipeline as pl
    from fgcli.io.options import open_input, open_output

    p = pl.load(task.pipeline)
    if task.sets:
        p = p.with_overrides(list(task.sets), label=p.label, origin="--set")
    reader = open_input(task.folder, fields=set(p.requires), pattern=task.pattern,
                        gbuffer_frames=task.scale > 1, **task.in_kw)
    out = open_output(task.out_dir, reader, **task.out_kw)
    return reader, out, p


def plan_task(task: RunTask, reader=None) -> dict:
    """The task's plan (fgcli.runner.plan_outputs), reading headers only (none when the
    sequence's reader is given)."""
    from fgcli.numbering import renumber
    from fgcli.runner import plan_outputs

    if reader is None:
        reader = open_task(task)[0]
    return renumber(plan_outputs(reader.numbers, reader.step, task.mode, list(task.times),
                                 task.count, task.emit, task.chunk),
                    task.numbering, task.mode, task.emit)


def execute(task: RunTask, progress: bool = False, on_frame=None) -> dict:
    """Run one task in this process; the run summary."""
    from fgcli.runner import run_sequence

    reader, out, p = open_task(task)
    summary = run_sequence(reader, out, p, task.mode, list(task.times), emit=task.emit,
                           device=task.device, progress=progress, count=task.count,
                           out_layout=out.layout, half=out.half, compression=out.compression,
                           command=task.command, chunk=task.chunk, on_frame=on_frame,
                           scene_cuts=task.scene_cuts, cut_threshold=task.cut_threshold,
                           backend=task.backend, scale=task.scale, numbering=task.numbering)
    summary["task"] = task.label()
    return summary


def run_local(tasks: list[RunTask], progress: bool = True) -> list[tuple[RunTask, dict]]:
    """The default executor: the tasks one after another in this process."""
    return [(t, execute(t, progress=progress)) for t in tasks]


def split_chunks(tasks: list[RunTask], per_sequence: int) -> list[RunTask]:
    """Each task as `per_sequence` chunks (a task already chunked stays as it is)."""
    out = []
    for t in tasks:
        if t.chunk is not None or per_sequence <= 1:
            out.append(t)
        else:
            out.extend(replace(t, chunk=(k, per_sequence)) for k in range(1, per_sequence + 1))
    return out


def error_result(task, err: BaseException) -> dict:
    """A failed task (RunTask or EvalTask), as data an executor can send back (exceptions with extra fields do
    not always survive pickling)."""
    code = err.exit_code if isinstance(err, FgenError) else 1
    msg = err.format_message() if isinstance(err, FgenError) else f"{type(err).__name__}: {err}"
    return {"error": msg, "exit_code": code, "task": task.label()}


@dataclass(frozen=True)
class EvalTask:
    """One `fgen eval` of one sequence (picklable, for an executor)."""

    in_dir: str
    gt_dir: str | None
    factor: int | None
    pipelines: tuple  # pipeline names / variants, resolved
    mode: str
    in_kw: dict
    device: str = "cpu"
    hdr_flip: bool = True
    keep_worst: bool = False
    name: str = ""
    scene_cuts: str = "auto"
    cut_threshold: float | None = None
    backend: str = "auto"  # --backend: auto | torch | numba
    region: str = "data"  # --region: data | display
    scale: int = 1  # --scale: output resolution / input resolution

    def label(self) -> str:
        return self.name or self.in_dir


def eval_source(in_dir: str, gt_dir: str | None, factor: int | None, in_kw: dict,
                scale: int = 1):
    """The frames to score: IN + GT, IN held out by FACTOR, or a folder with input/ and gt/
    (the bundled scenes); FACTOR 2 when nothing says otherwise. scale > 1: IN is a
    low-resolution render and GT its ground truth at scale x its size (--gt, or a folder
    with input/ and gt/)."""
    from fgcli import evaluate as ev
    from fgcli.io.options import open_input

    if gt_dir and factor:
        raise UsageError("use either --gt or --factor")
    if scale > 1:
        if factor:
            raise UsageError("--scale needs a ground truth at the output resolution: use --gt")
        if not gt_dir:
            if os.path.isdir(os.path.join(in_dir, "input")) and \
                    os.path.isdir(os.path.join(in_dir, "gt")):
                in_dir, gt_dir = os.path.join(in_dir, "input"), os.path.join(in_dir, "gt")
            else:
                raise UsageError("--scale needs --gt GT (the ground truth at the output "
                                 "resolution, on the input's frame numbers)")
        from fgcli.sr import ScaledGTSource

        return ScaledGTSource(open_input(in_dir, gbuffer_frames=True, **in_kw),
                              open_input(gt_dir, **in_kw), scale)
    if not gt_dir and not factor:
        if os.path.isdir(os.path.join(in_dir, "input")) and os.path.isdir(os.path.join(in_dir, "gt")):
            in_dir, gt_dir = os.path.join(in_dir, "input"), os.path.join(in_dir, "gt")
        else:
            factor = 2
    if gt_dir:
        rin = open_input(in_dir, **input_selection(in_dir, in_kw))
        return ev.GTSource(rin, open_input(gt_dir, **gt_selection(rin, gt_dir, in_kw)))
    return ev.HeldOutSource(open_input(in_dir, **in_kw), factor)


def input_selection(in_dir: str, in_kw: dict) -> dict:
    """The input options for the input folder of an input/gt pair: --frames keeps the
    input frames it names that are on disk (1-9 on input 1, 3, .., 9: all five)."""
    if not in_kw.get("frames"):
        return in_kw
    from fgcli.io.options import open_input
    from fgcli.io.sequence import parse_frames

    want = set(parse_frames(in_kw["frames"]))
    every = open_input(in_dir, **{k: v for k, v in in_kw.items() if k != "frames"}).numbers
    keep = [n for n in every if n in want]
    if len(keep) < 2:
        raise InputError(f"--frames {in_kw['frames']} selects {len(keep)} input frame(s) "
                         f"(input frames: {every[0]}..{every[-1]}); evaluation needs two",
                         file=in_dir)
    return {**in_kw, "frames": ",".join(str(n) for n in keep)}


def gt_selection(reader_in, gt_dir: str, in_kw: dict) -> dict:
    """The input options for the ground-truth folder of an input/gt pair: --frames selects
    input frames; the ground truth keeps the frames from the first selected input frame to
    one input step past the last (the interpolation and extrapolation targets of that
    selection)."""
    if not in_kw.get("frames"):
        return in_kw
    from fgcli.io.options import open_input

    kw = {k: v for k, v in in_kw.items() if k != "frames"}
    nums = reader_in.numbers
    lo, hi = nums[0], nums[-1] + (reader_in.step or 1)
    every = open_input(gt_dir, **kw).numbers
    keep = [n for n in every if lo <= n < hi]
    if not keep:
        raise InputError(f"no ground-truth frames between input frames {lo} and {hi} "
                         f"(--frames {in_kw['frames']})", file=gt_dir)
    return {**kw, "frames": ",".join(str(n) for n in keep)}


def execute_eval(task: EvalTask, progress: bool = True, on_frame=None) -> dict:
    """Score one sequence; the result of fgcli.evaluate.evaluate plus its source's range."""
    from fgcli import evaluate as ev
    from fgcli import pipeline as pl

    src = eval_source(task.in_dir, task.gt_dir, task.factor, task.in_kw, task.scale)
    pipes = [pl.load(n) for n in task.pipelines]
    if task.scale > 1:
        from fgcli.sr import evaluate_scaled

        res = evaluate_scaled(src, pipes, task.mode, progress=progress, device=task.device,
                              hdr_flip=task.hdr_flip, keep_worst=task.keep_worst,
                              on_frame=on_frame, scene_cuts=task.scene_cuts,
                              cut_threshold=task.cut_threshold, backend=task.backend,
                              region=task.region)
        res["sequence"] = task.label()
        return res
    res = ev.evaluate(src, pipes, task.mode, progress=progress,
                      device=task.device, hdr_flip=task.hdr_flip, keep_worst=task.keep_worst,
                      on_frame=on_frame, scene_cuts=task.scene_cuts,
                      cut_threshold=task.cut_threshold, backend=task.backend,
                      region=task.region)
    res["sequence"] = task.label()
    return res
