import click

from fgcli.commands._generate import common, run, split_kwargs


@click.command("extrapolate")
@click.argument("in_dir", type=click.Path(file_okay=False))
@click.argument("out_dir", type=click.Path(file_okay=False))
@click.option("--alpha", default="0.5", show_default=True,
              help="Time past each rendered frame, in input frame intervals (comma list allowed).")
@click.option("--count", type=int, default=1, show_default=True,
              help="Frames per rendered frame, at alpha, 2*alpha, ... (alpha*count < 1).")
@click.option("--emit", type=click.Choice(["generated", "all"]), default="generated", show_default=True)
@common
def cmd(in_dir, out_dir, alpha, count, emit, pipeline, sets, device, no_progress, json_out, **kw):
    """Generate frames past each rendered frame of IN_DIR, from that frame and its history only."""
    from fgcli.errors import UsageError
    from fgcli.runner import parse_alphas

    if count < 1:
        raise UsageError("--count must be >= 1")
    in_kw, out_kw = split_kwargs(kw)
    run("extrap", in_dir, out_dir, pipeline, sets, device, no_progress, json_out,
        parse_alphas(alpha, None, "extrap"), emit, count, in_kw, out_kw)
