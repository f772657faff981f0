"""Help that reads like a manual (options in sections, the pipeline first) and the small
stream rules the commands share (`--json -` is stdout). No torch import here."""
from __future__ import annotations

import json

import click

SECTIONS = ("Pipeline", "Input", "Output", "Execution")
# parameter name -> section; anything else lands in "Other"
SECTION_OF = {
    "pipeline": "Pipeline", "pipelines": "Pipeline", "sets": "Pipeline",
    "variants": "Pipeline", "factor": "Pipeline", "alpha": "Pipeline", "count": "Pipeline",
    "mode": "Pipeline", "scene_cuts": "Pipeline", "cut_threshold": "Pipeline",
    "pattern": "Input", "frames": "Input", "allow_gaps": "Input", "layout": "Input",
    "view": "Input", "gt_dir": "Input", "region": "Input",
    "emit": "Output", "numbering": "Output", "out_layout": "Output", "use_float": "Output",
    "compression": "Output", "overwrite": "Output", "resume": "Output", "scale": "Output",
    "json_out": "Output", "report_dir": "Output", "no_hdr_flip": "Output",
    "device": "Execution", "backend": "Execution", "threads": "Execution",
    "chunk": "Execution", "executor": "Execution", "scheduler": "Execution",
    "workers": "Execution", "repeat": "Execution", "dry_run": "Execution",
    "no_progress": "Execution",
}


class SectionedCommand(click.Command):
    """A command whose --help lists its options in sections: Pipeline (the pipeline
    first), Input, Output, Execution, then the rest."""

    def format_options(self, ctx, formatter):
        groups: dict[str, list] = {}
        for p in self.get_params(ctx):
            rv = p.get_help_record(ctx)
            if rv is None:
                continue
            sec = SECTION_OF.get(p.name, "Other")
            groups.setdefault(sec, []).append((p.name, rv))
        for sec in SECTIONS + ("Other",):
            rows = groups.get(sec)
            if not rows:
                continue
            if sec == "Pipeline":  # --pipeline leads, then its overrides
                lead = {"pipeline": 0, "pipelines": 0, "sets": 1, "variants": 1}
                rows.sort(key=lambda r: lead.get(r[0], 2))
            with formatter.section(f"{sec} options"):
                formatter.write_dl([rv for _, rv in rows])


def check_json_path(path: str | None) -> None:
    """Fail before any work when --json names a folder (an output problem, exit 3)."""
    import os

    from fgcli.errors import OutputError

    if path and path != "-" and os.path.isdir(path):
        raise OutputError("--json names a folder, not a file", file=path)


def write_json(path: str | None, data) -> None:
    """Write `data` as JSON to `path`; '-' = stdout."""
    if not path:
        return
    text = json.dumps(data, indent=1)
    if path == "-":
        click.echo(text)
        return
    from fgcli.errors import OutputError

    try:
        with open(path, "w") as fh:
            fh.write(text)
    except OSError as e:
        raise OutputError(f"cannot write JSON: {e.strerror}", file=path) from None


def threads_option(f):
    return click.option("--threads", type=click.IntRange(min=1), default=None, metavar="N",
                        help="Compute threads (torch, numba, OpenMP); default: the cores less "
                             "one while EXR reads and writes run beside the compute.")(f)


def apply_threads(n: int | None) -> None:
    """--threads N: before the compute libraries load (and for those already loaded)."""
    if not n:
        return
    import os
    import sys

    os.environ["FGEN_COMPUTE_THREADS"] = str(n)
    os.environ["OMP_NUM_THREADS"] = str(n)
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - non-Linux
        cores = os.cpu_count() or 1
    os.environ["NUMBA_NUM_THREADS"] = str(max(1, min(n, cores)))
    if "torch" in sys.modules:
        import torch

        torch.set_num_threads(n)
