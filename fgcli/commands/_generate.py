"""Shared body of `fgen interpolate` and `fgen extrapolate`: inputs (one or several
sequences), farm chunks, and the executor (in-process, or Dask distributed)."""
from __future__ import annotations

import sys

import click

from fgcli.io.options import INPUT_KEYS, OUTPUT_KEYS, input_options, output_options

# options that change how a run is carried out, never what it writes: left out of the
# command line recorded in every output header, so a chunked, resumed or cluster run
# writes the same bytes as one plain run
EXECUTION_ONLY = {"--chunk": 1, "--executor": 1, "--scheduler": 1, "--workers": 1,
                  "--resume": 0, "--overwrite": 0, "--no-progress": 0, "--json": 1,
                  "--threads": 1, "--dry-run": 0}


def recorded_command(argv: list[str]) -> str:
    """`fgen ...` as recorded in outputs: argv without the execution-only options."""
    out, skip = [], 0
    for a in argv:
        if skip:
            skip -= 1
            continue
        name = a.split("=", 1)[0]
        if name in EXECUTION_ONLY:
            skip = EXECUTION_ONLY[name] if "=" not in a else 0
            continue
        out.append(a)
    return " ".join(["fgen"] + out)


def common(f):
    from fgcli.commands._help import threads_option
    from fgcli.numbering import CHOICES

    f = click.option("--pipeline", "-p", default="mob-fgsr", show_default=True,
                     help="Pipeline name, variant (mob-fgsr:motion=linear) or .toml path "
                          "(fgen pipelines lists them).")(f)
    f = click.option("--set", "sets", multiple=True, metavar="STAGE.OPTION=VALUE",
                     help="Override a stage option (repeatable; fgen describe PIPELINE "
                          "shows them).")(f)
    f = click.option("--numbering", type=click.Choice(CHOICES), default="scaled",
                     show_default=True,
                     help="Output frame numbers. scaled: the input's numbers times the "
                          "smallest factor that makes every generated frame's an integer "
                          "(said when it is not 1); input: the input's own numbers (refused "
                          "when generated frames fall between them); sequential: 1 apart in "
                          "time order from the first input frame.")(f)
    f = click.option("--dry-run", is_flag=True,
                     help="Print the frame plan (which input frames make which output "
                          "files, per chunk) and exit; reads headers only, writes nothing.")(f)
    f = click.option("--device", default="cpu", show_default=True,
                     help="Compute device: cpu or cuda[:N].")(f)
    f = backend_option(f)
    f = click.option("--scale", type=click.IntRange(1, 8), default=1, show_default=True,
                     help="Output resolution / input resolution: the input is a (jittered) "
                          "low-resolution render; every output frame is written at SCALE x "
                          "its size (pipelines with super-resolution stages reconstruct the "
                          "rendered frames and generate at that size; the others generate "
                          "at the input size and upscale). G-buffer-only input frames (no "
                          "colour) are never read as colour sources.")(f)
    f = threads_option(f)
    f = click.option("--no-progress", is_flag=True,
                     help="No progress bar (or, when stderr is not a terminal, no periodic "
                          "progress line; FGEN_PROGRESS_SECONDS sets its period, default "
                          "30).")(f)
    f = click.option("--json", "json_out", type=click.Path(allow_dash=True),
                     default=None, metavar="FILE|-",
                     help="Also write the run summary (timings, skips) to this JSON file "
                          "('-': stdout).")(f)
    f = click.option("--chunk", default=None, metavar="K/N",
                     help="Farm chunk: write only part K of N contiguous parts of the output "
                          "frames (reads the inputs they need); N runs = one run.")(f)
    f = executor_options(f)
    f = scene_cut_options(f)
    f = output_options(f)
    f = input_options(f)
    return f


def backend_option(f):
    return click.option("--backend", type=click.Choice(["auto", "torch", "numba"]),
                        default="auto", show_default=True,
                        help="Per-pixel kernels: numba (compiled CPU kernels), torch (the "
                             "reference ops; the CUDA path); auto = numba on the CPU for "
                             "frames of 0.5 Mpx and up, torch below that and on CUDA "
                             "(docs/performance.md).")(f)


def scene_cut_options(f):
    f = click.option("--scene-cuts", type=click.Choice(["auto", "off"]), default="auto",
                     show_default=True,
                     help="auto: detect camera cuts (histogram candidates confirmed when no "
                          "motion explains the new frame) and repeat the nearest frame there.")(f)
    f = click.option("--scene-cut-threshold", "cut_threshold",
                     type=click.FloatRange(min=0, min_open=True), default=None,
                     metavar="KL",
                     help="Histogram score (symmetric KL) that makes a cut candidate "
                          "(default 0.45, FSR 3's).")(f)
    return f


def executor_options(f):
    f = click.option("--executor", type=click.Choice(["local", "dask"]), default="local",
                     show_default=True,
                     help="local: this process. dask: spread sequences and chunks over Dask "
                          "distributed workers.")(f)
    f = click.option("--scheduler", default=None, metavar="ADDRESS",
                     help="Dask scheduler (tcp://host:8786); default: a local cluster.")(f)
    f = click.option("--workers", type=click.IntRange(min=1), default=None,
                     help="Workers of the local Dask cluster (default: one per core).")(f)
    return f


def split_kwargs(kw):
    return ({k: kw[k] for k in INPUT_KEYS if k in kw}, {k: kw[k] for k in OUTPUT_KEYS if k in kw})


def check_executor(executor, scheduler, workers, chunk=None):
    from fgcli.errors import UsageError

    if executor != "dask" and (scheduler or workers):
        raise UsageError("--scheduler and --workers need --executor dask")
    if executor == "dask" and chunk:
        raise UsageError("--chunk and --executor dask do not combine: the executor makes "
                         "its own chunks")
    if workers is not None and workers < 1:
        raise UsageError("--workers must be >= 1")


def run(mode, in_dirs, out_dir, pipeline, sets, device, no_progress, json_out, times, emit,
        count, in_kw, out_kw, chunk=None, executor="local", scheduler=None, workers=None,
        scene_cuts="auto", cut_threshold=None):
    from fgcli.commands._help import apply_threads, check_json_path, write_json

    from fgcli import pipeline as pl
    from fgcli.batch import RunTask, expand_inputs, run_local
    from fgcli.runner import parse_chunk

    from fgcli.kernels import resolve

    check_executor(executor, scheduler, workers, chunk)
    check_json_path(json_out)
    # --backend (backend_option) is read here, not passed by each command
    params = click.get_current_context().params
    backend = params.get("backend") or "auto"
    scale = int(params.get("scale") or 1)  # --scale, alike
    apply_threads(params.get("threads"))
    resolve(backend, device)  # fail early (numba missing, numba with cuda)
    p = pl.load(pipeline)  # fail early on a bad pipeline or option
    if sets:
        p.with_overrides(list(sets), label=p.label, origin="--set")
    if p.scale_only and scale == 1:
        from fgcli.errors import UsageError

        raise UsageError(f"pipeline '{p.name}' is a super-resolution method: it needs "
                         "--scale 2 (or more)")
    ch = parse_chunk(chunk)
    seqs = expand_inputs(in_dirs, out_dir, in_kw)
    command = recorded_command(sys.argv[1:])
    tasks = [RunTask(mode=mode, folder=folder, pattern=pattern, out_dir=od, pipeline=pipeline,
                     sets=tuple(sets), device=device, times=tuple(times), emit=emit, count=count,
                     in_kw={k: v for k, v in in_kw.items() if k != "pattern"}, out_kw=out_kw,
                     command=command, chunk=ch, name=name, scene_cuts=scene_cuts,
                     cut_threshold=cut_threshold, backend=backend, scale=scale,
                     numbering=params.get("numbering") or "scaled")
             for name, folder, pattern, od in seqs]
    if params.get("numbering") == "input":  # refused before any folder is made
        from fgcli.commands._plan import check_plans

        check_plans(tasks)
    if params.get("dry_run"):
        from fgcli.commands._plan import print_plans

        print_plans(tasks, executor, workers)
        return
    if executor == "dask":
        from fgcli.executor import run_dask

        results = run_dask(tasks, scheduler=scheduler, workers=workers,
                           progress=not no_progress)
    else:
        results = run_local(tasks, progress=not no_progress)
    summaries = [s for _, s in results]
    for task, summary in results:
        t = summary["timings"]
        stages = ", ".join(f"{k} {v:.1f}" for k, v in t["stages"].items())
        where = task.out_dir + (f" (chunk {summary['chunk']})" if summary.get("chunk") else "")
        click.echo(f"{summary['written']} frames written to {where} "
                   f"({summary['skipped_existing']} already complete); "
                   f"{t['ms_per_frame']:.1f} ms/frame compute ({summary.get('backend')}) "
                   f"[{stages}], "
                   f"read {t['io_read_ms']:.1f} ms, write {t['io_write_ms']:.1f} ms per frame",
                   err=True)
        if t["skipped"]:
            click.echo(f"skipped {t['skipped']} stage runs where not needed "
                       f"(saving ~{t['ms_saved_per_frame']:.1f} ms/frame); see fgen-run.json",
                       err=True)
        nb = summary.get("no_backward_vectors")
        if nb:
            click.echo(f"frames {', '.join(str(n) for n in nb['frames'])} of {task.folder}: no "
                       f"usable backward vectors (forward-only files, no earlier file to derive "
                       f"them from); {nb['effect']}", err=True)
        sc = summary.get("scene_cuts") or {}
        if sc.get("cuts"):
            click.echo(f"scene cuts (nearest frame repeated, no blending) at output frames "
                       f"{', '.join(str(c) for c in sc['cuts'])}; scores in fgen-run.json",
                       err=True)
        if summary.get("numbering_note") and summary.get("written"):
            click.echo(f"note: {summary['numbering_note']}", err=True)
        if summary.get("stale_temp_removed"):
            click.echo(f"removed {summary['stale_temp_removed']} temporary files left by a "
                       "killed run", err=True)
    write_json(json_out, summaries[0] if len(summaries) == 1 else summaries)
