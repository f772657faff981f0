"""Click options every command shares, and the two calls that turn them into objects.

    @click.command()
    @click.argument("input_dir")
    @click.argument("output_dir")
    @input_options
    @output_options
    def cmd(input_dir, output_dir, **kw):
        reader = open_input(input_dir, fields={"color", "depth", "mv"}, **kw)
        out = open_output(output_dir, reader, **kw)

Input options (keyword names): pattern, frames, allow_gaps, layout, view.
Output options: out_layout, use_float, compression, overwrite, resume.
No torch import here.
"""
from __future__ import annotations

import click

from fgcli.errors import UsageError
from fgcli.io.exr import COMPRESSIONS

INPUT_KEYS = ("pattern", "frames", "allow_gaps", "layout", "view")
OUTPUT_KEYS = ("out_layout", "use_float", "compression", "overwrite", "resume")


def _apply(f, opts):
    for o in reversed(opts):
        f = o(f)
    return f


def input_options(f):
    """--pattern, --frames, --allow-gaps, --layout, --view."""
    return _apply(f, [
        click.option("--pattern", default=None, metavar="GLOB",
                     help="Pick one sequence when the folder holds several: a glob "
                          "('shot.*.exr'), a prefix ('shot.') or 'shot.####.exr'."),
        click.option("--frames", default=None, metavar="RANGE",
                     help="Frames to use, oiiotool style: 1001-1100x2, 1,3,5-9."),
        click.option("--allow-gaps", is_flag=True, default=False,
                     help="Accept missing frame numbers in the sequence."),
        click.option("--layout", default=None, metavar="NAME|FILE.toml",
                     help="Input layout: fgen, blender, nuke or a TOML mapping "
                          "(default: detected from the channel names)."),
        click.option("--view", default=None, metavar="NAME",
                     help="View of a multi-view (stereo) file (default: the file's first)."),
    ])


def output_options(f):
    """--out-layout, --float, --compression, --overwrite, --resume."""
    return _apply(f, [
        click.option("--out-layout", default="fgen", show_default=True,
                     metavar="fgen|blender|nuke|input|FILE.toml",
                     help="Layout of the written EXRs; 'input' = the input's layout."),
        click.option("--float", "use_float", is_flag=True, default=False,
                     help="Write every channel as 32-bit float (default: half for color, "
                          "float for depth and vectors)."),
        click.option("--compression", default="zip", show_default=True,
                     type=click.Choice(COMPRESSIONS),
                     help="EXR compression (pxr24, b44*, dwa* are lossy; zstd is lossless, "
                          "about half zip's size and faster on depth and vectors, but needs "
                          "OpenEXR 3.4+ to read)."),
        click.option("--overwrite", is_flag=True, default=False,
                     help="Replace existing outputs."),
        click.option("--resume", is_flag=True, default=False,
                     help="Skip outputs that are already complete; write the rest."),
    ])


def open_input(folder: str, fields: set[str] | None = None, optional: set[str] | None = None,
               pattern: str | None = None, frames: str | None = None,
               allow_gaps: bool = False, layout: str | None = None, view: str | None = None,
               gbuffer_frames: bool = False, **_other):
    """A SequenceReader for `folder` from the input options (other keyword arguments, e.g.
    a command's remaining options, are ignored)."""
    from fgcli.io.reader import SequenceReader

    return SequenceReader(folder, pattern=pattern, frames=frames, allow_gaps=allow_gaps,
                          layout=layout, view=view, fields=fields, optional=optional,
                          gbuffer_frames=gbuffer_frames)


def resolve_out_layout(out_layout, reader=None):
    """The layout object for --out-layout ('input' = the reader's layout)."""
    from fgcli.io import layouts

    if out_layout in (None, ""):
        out_layout = "fgen"
    if out_layout == "input":
        if reader is None:
            raise UsageError("--out-layout input needs an input sequence")
        return reader.layout
    return layouts.get(out_layout)


def open_output(folder: str, reader=None, out_layout="fgen", use_float: bool = False,
                compression: str = "zip", overwrite: bool = False, resume: bool = False,
                input_folder: str | None = None, prefix: str | None = None,
                padding: int | None = None, **_other):
    """An OutputFolder from the output options. `reader` (a SequenceReader) supplies the
    input folder to refuse, the 'input' layout and the naming (prefix, padding) of
    numbered outputs."""
    from fgcli.io.output import OutputFolder

    lay = resolve_out_layout(out_layout, reader)
    if reader is not None:
        input_folder = input_folder or reader.folder
        prefix = reader.seq.prefix if prefix is None else prefix
        padding = reader.seq.padding if padding is None else padding
    return OutputFolder(folder, input_folder, overwrite=overwrite, resume=resume,
                        layout=lay, half=not use_float, compression=compression,
                        prefix="frame." if prefix is None else prefix,
                        padding=4 if padding is None else padding)
