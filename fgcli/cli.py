"""fgen command line. Commands live in fgcli/commands/<name>.py and load on use, so
`fgen --help` never imports torch."""
from __future__ import annotations

import importlib
import os
import sys

import click

# torch's OpenMP threads spin while waiting by default; with the EXR prefetch/writer threads
# on a 2-core box that slows compute 5-10x. Must be set before torch is first imported.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from fgcli import __version__

COMMANDS = {
    "info": "Describe a sequence: layout, size, frames, channels, cameras.",
    "convert": "Rewrite a sequence into another layout.",
    "synth": "Render a procedural scene (input frames and ground truth).",
    "interpolate": "Generate frames between rendered frames.",
    "extrapolate": "Generate frames past each rendered frame.",
    "eval": "Score pipelines against ground truth: quality and milliseconds.",
    "train": "Train a network on data rendered from random scenes.",
    "pipelines": "List the available pipelines.",
    "describe": "Show a pipeline's stages or a stage's options.",
}


class LazyGroup(click.Group):
    def list_commands(self, ctx):
        return list(COMMANDS)

    def get_command(self, ctx, name):
        if name not in COMMANDS:
            return None
        mod = importlib.import_module(f"fgcli.commands.{name}")
        return mod.cmd

    def format_commands(self, ctx, formatter):
        # short help without importing the command modules
        with formatter.section("Commands"):
            formatter.write_dl([(n, h) for n, h in COMMANDS.items()])


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="fgen")
@click.option("--debug", is_flag=True, help="Show Python tracebacks on errors.")
@click.pass_context
def cli(ctx, debug):
    """fgen: more frames from rendered OpenEXR sequences, with what each method costs.

    Exit codes: 0 ok, 1 bad input or failed check, 2 usage error, 3 output problem.
    """
    from fgcli.sysutil import tune_allocator

    tune_allocator()  # keep freed frame-sized buffers: page faults cost more than the maths
    ctx.ensure_object(dict)
    ctx.obj["debug"] = debug
    if debug:
        os.environ["FGEN_DEBUG"] = "1"


def main(argv=None):
    debug = "--debug" in (argv if argv is not None else sys.argv[1:])
    try:
        cli.main(args=argv, prog_name="fgen", standalone_mode=False)
    except click.UsageError as e:  # click's own (bad option or value): one line, as ours
        if debug:
            raise
        where = e.ctx.command_path if e.ctx is not None else "fgen"
        msg = " ".join(e.format_message().split())
        click.echo(f"Error: {msg} (see '{where} --help')", err=True)
        sys.exit(e.exit_code)
    except click.ClickException as e:
        if debug:
            raise
        e.show()
        sys.exit(e.exit_code)
    except click.exceptions.Abort:
        click.echo("Aborted.", err=True)
        sys.exit(1)
    except click.exceptions.Exit as e:
        sys.exit(e.exit_code)
    except KeyboardInterrupt:
        click.echo("Interrupted; rerun with --resume to continue.", err=True)
        sys.exit(130)
    except Exception as e:  # unexpected: one line unless --debug
        if debug:
            raise
        click.echo(f"Error: internal error: {type(e).__name__}: {e} (rerun with --debug for "
                   "a traceback)", err=True)
        sys.exit(1)
    sys.exit(0)
