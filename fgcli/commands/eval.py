import click

from fgcli.io.options import input_options


@click.command("eval")
@click.argument("in_dir", type=click.Path(file_okay=False))
@click.option("--gt", "gt_dir", type=click.Path(file_okay=False), default=None,
              help="Ground-truth frames on the same frame-number timeline as IN.")
@click.option("--factor", type=int, default=None,
              help="IN is full-rate: keep every N-th frame as input, score the rest.")
@click.option("--pipeline", "-p", "pipelines", default="all", show_default=True,
              help="Comma-separated pipelines, or 'all'.")
@click.option("--variant", "variants", multiple=True, metavar="PIPE:OPT=V[,OPT=V]",
              help="Also run a variant, e.g. mob-fgsr:motion=linear or mob-fgsr:gap_fill=off.")
@click.option("--mode", type=click.Choice(["interp", "extrap"]), default="interp", show_default=True)
@click.option("--json", "json_out", type=click.Path(dir_okay=False), default=None,
              help="Write the scores as JSON.")
@click.option("--report", "report_dir", type=click.Path(file_okay=False), default=None,
              help="Write PNG plots (quality vs time, stage times, worst-frame crops).")
@click.option("--device", default="cpu", show_default=True)
@click.option("--no-hdr-flip", is_flag=True, help="Skip HDR-FLIP (the slowest metric).")
@click.option("--no-progress", is_flag=True)
@input_options
def cmd(in_dir, gt_dir, factor, pipelines, variants, mode, json_out, report_dir, device,
        no_hdr_flip, no_progress, **in_kw):
    """Score pipelines against ground truth (DESIGN.md section 4).

    \b
    fgen eval IN --gt GT       IN = rendered input, GT = reference frames between/after
    fgen eval FULL --factor 2  keep every 2nd frame, chain MVs, score the dropped ones
    fgen eval SCENE            a folder with input/ and gt/ (the bundled sample scenes)

    Color is scored display-referred: sRGB OETF of clip(linear, 0, 1) for PSNR, SSIM and
    LDR-FLIP; HDR-FLIP on linear color. Masked scores: disoccluded = ground-truth pixels
    whose surface is not visible in the source input frame; moving = pixels that moved
    more than 0.5 px since it.
    """
    import json
    import math
    import os

    from fgcli import evaluate as ev
    from fgcli import pipeline as pl
    from fgcli.errors import UsageError
    from fgcli.io.options import open_input

    if gt_dir and factor:
        raise UsageError("use either --gt or --factor")
    if not gt_dir and not factor:
        if os.path.isdir(os.path.join(in_dir, "input")) and os.path.isdir(os.path.join(in_dir, "gt")):
            in_dir, gt_dir = os.path.join(in_dir, "input"), os.path.join(in_dir, "gt")
        else:
            factor = 2
    if gt_dir:
        src = ev.GTSource(open_input(in_dir, **in_kw), open_input(gt_dir, **in_kw))
    else:
        src = ev.HeldOutSource(open_input(in_dir, **in_kw), factor)
    names = [n.strip() for n in pipelines.split(",") if n.strip()] if pipelines else []
    if names == ["all"]:
        names = list(pl.available())
    pipes = []
    for n in names:
        p = pl.load(n)
        if mode in p.modes:
            pipes.append(p)
        elif pipelines != "all":
            raise UsageError(f"pipeline '{n}' does not support mode '{mode}'")
    for v in variants:
        pipes.append(pl.load(v))
    result = ev.evaluate(src, pipes, mode, progress=not no_progress, device=device,
                         hdr_flip=not no_hdr_flip, keep_worst=report_dir is not None)
    worst = result.pop("_worst")
    click.echo(f"# fgen eval: {mode}, {result['frames']} ground-truth frames, inputs "
               f"{src.inputs[0]}..{src.inputs[-1]}")
    click.echo(f"# color: {result['display']}")
    click.echo(ev.markdown_table(result))
    if json_out:
        def clean(o):
            if isinstance(o, float) and (math.isnan(o) or math.isinf(o)):
                return None
            if isinstance(o, dict):
                return {k: clean(v) for k, v in o.items()}
            if isinstance(o, list):
                return [clean(v) for v in o]
            return o
        with open(json_out, "w") as fh:
            json.dump(clean(result), fh, indent=1)
    if report_dir:
        from fgcli.report import write_report

        files = write_report(result, worst, report_dir)
        click.echo(f"# report: {', '.join(files)}", err=True)
