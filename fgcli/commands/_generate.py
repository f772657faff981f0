"""Shared body of `fgen interpolate` and `fgen extrapolate`."""
from __future__ import annotations

import sys

import click

from fgcli.io.options import INPUT_KEYS, OUTPUT_KEYS, input_options, output_options


def common(f):
    f = click.option("--pipeline", "-p", default="mob-fgsr", show_default=True,
                     help="Pipeline name, variant (mob-fgsr:motion=linear) or .toml path.")(f)
    f = click.option("--set", "sets", multiple=True, metavar="STAGE.OPTION=VALUE",
                     help="Override a stage option (repeatable).")(f)
    f = click.option("--device", default="cpu", show_default=True, help="cpu or cuda.")(f)
    f = click.option("--no-progress", is_flag=True, help="Hide the progress bar.")(f)
    f = click.option("--json", "json_out", type=click.Path(dir_okay=False), default=None,
                     help="Also write the run summary (timings, skips) to this JSON file.")(f)
    f = output_options(f)
    f = input_options(f)
    return f


def split_kwargs(kw):
    return ({k: kw[k] for k in INPUT_KEYS if k in kw}, {k: kw[k] for k in OUTPUT_KEYS if k in kw})


def run(mode, in_dir, out_dir, pipeline, sets, device, no_progress, json_out, times, emit,
        count, in_kw, out_kw):
    import json

    from fgcli import pipeline as pl
    from fgcli.io.options import open_input, open_output
    from fgcli.runner import run_sequence

    p = pl.load(pipeline)
    if sets:
        p = p.with_overrides(list(sets), label=p.label)
    fields = set(p.requires)
    reader = open_input(in_dir, fields=fields, **in_kw)
    out = open_output(out_dir, reader, **out_kw)
    summary = run_sequence(reader, out, p, mode, times, emit=emit, device=device,
                           progress=not no_progress, count=count,
                           out_layout=out.layout, half=out.half, compression=out.compression,
                           command=" ".join(["fgen"] + sys.argv[1:]))
    t = summary["timings"]
    stages = ", ".join(f"{k} {v:.1f}" for k, v in t["stages"].items())
    click.echo(f"{summary['written']} frames written to {out_dir} "
               f"({summary['skipped_existing']} already complete); "
               f"{t['ms_per_frame']:.1f} ms/frame compute [{stages}], "
               f"read {t['io_read_ms']:.1f} ms, write {t['io_write_ms']:.1f} ms per frame", err=True)
    if t["skipped"]:
        click.echo(f"skipped {t['skipped']} stage runs where not needed "
                   f"(saving ~{t['ms_saved_per_frame']:.1f} ms/frame); see fgen-run.json", err=True)
    if json_out:
        with open(json_out, "w") as fh:
            json.dump(summary, fh, indent=1)
