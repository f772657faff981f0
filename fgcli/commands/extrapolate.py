import click

from fgcli.commands._generate import common, run, split_kwargs
from fgcli.commands._help import SectionedCommand


@click.command("extrapolate", cls=SectionedCommand)
@click.argument("in_dirs", nargs=-1, required=True, type=click.Path(),
                metavar="IN_DIR... OUT_DIR")
@click.option("--alpha", default="0.5", show_default=True,
              help="Time past each rendered frame, in input frame intervals (comma list allowed).")
@click.option("--count", type=click.IntRange(min=1), default=1, show_default=True,
              help="Frames per rendered frame, at alpha, 2*alpha, ... (alpha*count < 1).")
@click.option("--emit", type=click.Choice(["generated", "all"]), default="generated", show_default=True,
              help="'all' writes the merged higher-rate sequence with rendered frames copied through.")
@common
def cmd(in_dirs, alpha, count, emit, pipeline, sets, device, no_progress, json_out, chunk,
        executor, scheduler, workers, scene_cuts, cut_threshold, **kw):
    """Generate frames past each rendered frame of IN_DIR, from that frame and its history only.

    Several input folders (or a --pattern matching several sequences) write into
    OUT_DIR/<name>/. --chunk K/N writes one farm chunk; --executor dask spreads sequences
    and chunks over a Dask cluster.
    """
    from fgcli.errors import UsageError
    from fgcli.runner import parse_alphas

    if count < 1:
        raise UsageError("--count must be >= 1")
    if len(in_dirs) < 2:
        raise UsageError("give the input folder(s) and the output folder")
    in_kw, out_kw = split_kwargs(kw)
    run("extrap", list(in_dirs[:-1]), in_dirs[-1], pipeline, sets, device, no_progress, json_out,
        parse_alphas(alpha, None, "extrap"), emit, count, in_kw, out_kw, chunk, executor,
        scheduler, workers, scene_cuts, cut_threshold)
