import click

from fgcli.commands._generate import common, run, split_kwargs
from fgcli.commands._help import SectionedCommand


@click.command("interpolate", cls=SectionedCommand)
@click.argument("in_dirs", nargs=-1, required=True, type=click.Path(),
                metavar="IN_DIR... OUT_DIR")
@click.option("--factor", type=click.IntRange(min=2), default=None, metavar="N",
              help="Frame-rate factor: N-1 frames between each rendered pair (default 2).")
@click.option("--alpha", default=None, metavar="A[,A...]",
              help="Times between each rendered pair, in (0,1), e.g. 0.25,0.5,0.75 "
                   "(instead of --factor).")
@click.option("--emit", type=click.Choice(["generated", "all"]), default="generated", show_default=True,
              help="'all' writes the merged higher-rate sequence with rendered frames copied through.")
@common
def cmd(in_dirs, factor, alpha, emit, pipeline, sets, device, no_progress, json_out, chunk,
        executor, scheduler, workers, scene_cuts, cut_threshold, **kw):
    """Generate frames between rendered frames of IN_DIR into OUT_DIR.

    Several input folders (or a --pattern matching several sequences) write into
    OUT_DIR/<name>/. --chunk K/N writes one farm chunk; --executor dask spreads sequences
    and chunks over a Dask cluster.
    """
    from fgcli.errors import UsageError
    from fgcli.runner import parse_alphas

    if factor is not None and alpha is not None:
        raise UsageError("use either --factor or --alpha")
    if len(in_dirs) < 2:
        raise UsageError("give the input folder(s) and the output folder")
    in_kw, out_kw = split_kwargs(kw)
    run("interp", list(in_dirs[:-1]), in_dirs[-1], pipeline, sets, device, no_progress, json_out,
        parse_alphas(alpha, factor, "interp"), emit, 1, in_kw, out_kw, chunk, executor, scheduler,
        workers, scene_cuts, cut_threshold)
