import click

from fgcli.commands._generate import executor_options, scene_cut_options
from fgcli.commands._help import SectionedCommand, threads_option
from fgcli.io.options import input_options


@click.command("eval", cls=SectionedCommand)
@click.argument("in_dirs", nargs=-1, required=True, type=click.Path(), metavar="IN_DIR...")
@click.option("--gt", "gt_dir", type=click.Path(), default=None, metavar="GT_DIR",
              help="Ground-truth frames on the same frame-number timeline as IN.")
@click.option("--factor", type=click.IntRange(min=2), default=None, metavar="N",
              help="IN is full-rate: keep every N-th frame as input, score the rest.")
@click.option("--pipeline", "-p", "pipelines", default="all", show_default=True,
              help="Comma-separated pipelines, or 'all'.")
@click.option("--variant", "variants", multiple=True, metavar="PIPE:OPT=V[,OPT=V]",
              help="Also run a variant, e.g. mob-fgsr:motion=linear or mob-fgsr:gap_fill=off.")
@click.option("--mode", type=click.Choice(["interp", "extrap"]), default="interp", show_default=True,
              help="interp: score frames between input frames; extrap: frames after each "
                   "input frame, made from it and its history only.")
@click.option("--scale", type=click.IntRange(1, 8), default=1, show_default=True,
              help="Output resolution / input resolution: IN is a (jittered) low-resolution "
                   "render, GT its ground truth at SCALE x its size on the same frame "
                   "numbers; scores SS frames (the rendered times, reconstructed) and ESS "
                   "frames (the generated times) separately.")
@click.option("--json", "json_out", type=click.Path(allow_dash=True),
              default=None, metavar="FILE|-",
              help="Write the scores as JSON ('-': stdout; the table then goes to stderr).")
@click.option("--report", "report_dir", type=click.Path(), default=None, metavar="DIR",
              help="Write a report: index.html (self-contained), summary.md and the figures "
                   "as PNG (table, per-frame PSNR, quality vs time, stage times, the same "
                   "crop of every pipeline and the ground truth with a shared error scale).")
@click.option("--repeat", type=click.IntRange(min=1), default=1, show_default=True,
              metavar="N",
              help="Run the evaluation N times: timings are the median of the N runs, with "
                   "their spread (min-max); the scores are the first run's (they repeat).")
@click.option("--device", default="cpu", show_default=True,
              help="Compute device: cpu or cuda[:N].")
@click.option("--region", type=click.Choice(["data", "display"]), default="data",
              show_default=True,
              help="data: score the bounding box of the data windows of the target and its "
                   "inputs (padding carries no data); display: the whole frame.")
@click.option("--backend", type=click.Choice(["auto", "torch", "numba"]), default="auto",
              show_default=True,
              help="Per-pixel kernels: numba (compiled CPU kernels), torch (reference ops, "
                   "the CUDA path); auto = numba on the CPU for frames of 0.5 Mpx and up, "
                   "torch below that and on CUDA (docs/performance.md).")
@click.option("--no-hdr-flip", is_flag=True, help="Skip HDR-FLIP (the slowest metric).")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
@threads_option
@executor_options
@scene_cut_options
@input_options
def cmd(in_dirs, gt_dir, factor, pipelines, variants, mode, scale, json_out, report_dir, repeat,
        device, region, backend, no_hdr_flip, no_progress, threads, executor, scheduler, workers,
        scene_cuts, cut_threshold, **in_kw):
    """Score pipelines against ground truth (the protocol: docs/evaluation.md).

    \b
    fgen eval IN --gt GT       IN = rendered input, GT = reference frames between/after
    fgen eval FULL --factor 2  keep every 2nd frame, chain MVs, score the dropped ones
    fgen eval SCENE            a folder with input/ and gt/ (the bundled sample scenes)
    fgen eval A B C            several sequences (one table each; --executor dask
                               scores them on a Dask cluster)

    Color is scored display-referred: sRGB OETF of clip(linear, 0, 1) for PSNR, SSIM and
    LDR-FLIP; HDR-FLIP on linear color. Masked scores: disoccluded = ground-truth pixels
    whose surface is not visible in the source input frame; moving = pixels that moved
    more than 0.5 px since it.
    """
    import math
    import os

    from fgcli import pipeline as pl
    from fgcli.batch import EvalTask, eval_source, execute_eval
    from fgcli.commands._generate import check_executor
    from fgcli.errors import UsageError

    from fgcli.kernels import resolve

    from fgcli.commands._help import apply_threads, check_json_path, write_json
    from fgcli.report import check_report_dir, merge_repeats

    check_executor(executor, scheduler, workers)
    check_json_path(json_out)
    apply_threads(threads)
    resolve(backend, device)  # fail early
    if report_dir:
        check_report_dir(report_dir)  # an output problem (exit 3) before any work
    if len(in_dirs) > 1 and gt_dir:
        raise UsageError("--gt takes one input sequence; for several, give folders with "
                         "input/ and gt/ each, or use --factor")
    names = [n.strip() for n in pipelines.split(",") if n.strip()] if pipelines else []
    if names == ["all"]:
        names = list(pl.available())
    chosen = []
    for n in names:
        p = pl.load(n)
        if p.scale_only and scale == 1:
            if pipelines != "all":
                raise UsageError(f"pipeline '{n}' is a super-resolution method: it needs "
                                 f"--scale 2 (or more)")
            continue
        if mode in p.modes:
            chosen.append(n)
        elif pipelines != "all":
            raise UsageError(f"pipeline '{n}' does not support mode '{mode}'")
    for v in variants:
        pl.load(v)
        chosen.append(v)
    labels = [os.path.basename(os.path.normpath(d)) for d in in_dirs]
    if len(set(labels)) < len(labels):
        labels = list(in_dirs)
    tasks = [EvalTask(in_dir=d, gt_dir=gt_dir, factor=factor, pipelines=tuple(chosen), mode=mode,
                      in_kw=in_kw, device=device, hdr_flip=not no_hdr_flip,
                      keep_worst=report_dir is not None, name=lab, scene_cuts=scene_cuts,
                      cut_threshold=cut_threshold, backend=backend, region=region,
                      scale=scale)
             for d, lab in zip(in_dirs, labels)]
    srcs = [eval_source(t.in_dir, t.gt_dir, t.factor, t.in_kw, t.scale)
            for t in tasks]  # fail early
    if executor == "dask":
        from fgcli.evaluate import make_tasks
        from fgcli.executor import eval_dask

        frames = sum(len(make_tasks(s, mode)) for s in srcs) * len(chosen)
        runs = eval_dask([t for t in tasks for _ in range(repeat)], scheduler, workers,
                         progress=not no_progress, total_frames=frames * repeat)
        results = [merge_repeats(runs[i * repeat:(i + 1) * repeat])
                   for i in range(len(tasks))]
    else:
        results = [merge_repeats([execute_eval(t, progress=not no_progress)
                                  for _ in range(repeat)]) for t in tasks]

    def clean(o):
        if isinstance(o, float) and (math.isnan(o) or math.isinf(o)):
            return None
        if isinstance(o, dict):
            return {k: clean(v) for k, v in o.items()}
        if isinstance(o, list):
            return [clean(v) for v in o]
        return o

    from fgcli import evaluate as ev

    # --json -: stdout carries the JSON alone, the table goes to stderr
    echo = click.echo if json_out != "-" else (lambda *a, **k: click.echo(*a, err=True))
    for t, src, result in zip(tasks, srcs, results):
        worst = result.pop("_worst")
        compare = result.pop("_compare", None)
        if len(tasks) > 1:
            echo(f"## {t.label()}")
        echo(f"# fgen eval: {mode}, {result['frames']} ground-truth frames, inputs "
                   f"{src.inputs[0]}..{src.inputs[-1]}")
        echo(f"# color: {result['display']}; backend: {result.get('backend')}")
        reg = result["region"]
        if reg["scored_fraction"] < 1.0:
            echo(f"# scored: {reg['what']} ({100 * reg['scored_fraction']:.0f}% of the "
                       f"display window; --region display scores all of it)")
        else:
            echo(f"# scored: {reg['what']}")
        if result["scene_cuts"]["cuts"]:
            echo(f"# scene cuts (nearest frame repeated) at frames "
                       f"{', '.join(str(c) for c in result['scene_cuts']['cuts'])}")
        if scale > 1:
            from fgcli.sr import markdown_tables

            echo(f"# x{scale}: SS frames {len(result['ss_frames'])}, ESS frames "
                 f"{len(result['ess_frames'])}"
                 + (f" ({len(result['gbuffer_only_inputs'])} of them G-buffer-only "
                    f"input frames)" if result["gbuffer_only_inputs"] else ""))
            echo(markdown_tables(result))
            echo(f"## all scored frames, x{scale}")
        echo(ev.markdown_table(result))
        if report_dir:
            from fgcli.report import write_report

            where = report_dir if len(tasks) == 1 else os.path.join(report_dir, t.label())
            files = write_report(result, worst, where, compare=compare)
            click.echo(f"# report: {', '.join(files)}", err=True)
    if json_out:
        data = results[0] if len(results) == 1 else {
            "sequences": {t.label(): r for t, r in zip(tasks, results)}}
        write_json(json_out, clean(data))
