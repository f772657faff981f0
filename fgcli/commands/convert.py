"""fgen convert IN OUT: rewrite a sequence into another layout (fgen by default)."""
from __future__ import annotations

import click

from fgcli.io.options import input_options, output_options

# Frame fields a layout may be unable to hold
_CHECK = ("alpha", "depth", "mv", "normal", "albedo", "roughness")


@click.command(help="Rewrite a sequence into another layout: normalise Blender or Nuke "
                    "renders (or a TOML-described layout) to the fgen layout, or back. "
                    "Outputs keep the input's file names.")
@click.argument("input_dir", type=click.Path())
@click.argument("output_dir", type=click.Path())
@input_options
@output_options
def cmd(input_dir, output_dir, **kw):
    from fgcli.io.options import open_input, open_output
    from fgcli.io.output import fgen_attributes

    reader = open_input(input_dir, fields=None, **kw)
    out = open_output(output_dir, reader, **kw)
    reader.check_sizes()
    paths = {n: out.path_for(n) for n in reader.numbers}
    out.check_all(paths.values())
    lost: set[str] = set()
    written = 0
    for n in reader.numbers:
        p = paths[n]
        if not out.should_write(p):
            continue
        frame = reader.read(n)
        for f in _CHECK:
            if getattr(frame, f, None) is not None and not out.layout.can_encode(f):
                lost.add(f)
        attrs = fgen_attributes(source_frames=[n], converted_from=reader.layout.name)
        out.write(p, frame, attributes=attrs)
        written += 1
    reader.warn_nonfinite()
    for note in reader.notes:
        click.echo(f"note: {note}", err=True)
    if lost:
        click.echo(f"warning: layout '{out.layout.name}' has no channels for "
                   f"{', '.join(sorted(lost))}; not written", err=True)
    skipped = f" (skipped {len(out.skipped)} complete)" if out.skipped else ""
    click.echo(f"converted {written} frames from {reader.layout.name} to {out.layout.name}: "
               f"{out.path}{skipped}")
