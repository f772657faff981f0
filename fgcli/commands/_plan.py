"""`--dry-run`: the frame plan of interpolate / extrapolate, from headers only."""
from __future__ import annotations

import os

import click


def _name(prefix: str, padding: int, n: int) -> str:
    num = f"{n:0{padding}d}" if n >= 0 else f"-{-n:0{padding}d}"
    return f"{prefix}{num}.exr"


def plan_lines(task, reader) -> list[str]:
    """The plan of one task (one sequence, one chunk or all of it), one line per output."""
    from fgcli.batch import plan_task

    plan = plan_task(task, reader)
    prefix, padding = reader.seq.prefix or "frame.", reader.seq.padding or 4
    where = task.out_dir
    chunk = f"chunk {task.chunk[0]}/{task.chunk[1]}" if task.chunk else "all outputs"
    alphas = ", ".join(str(t) for t in plan["times"])
    lines = [f"{task.name or task.folder}: {task.mode} with {task.pipeline}, alphas {alphas}; "
             f"{len(plan['numbers'])} input frames {plan['numbers'][0]}..{plan['numbers'][-1]} "
             f"(step {plan['step']}) in {task.folder}; numbering {plan['numbering']}"
             + (f" (x{plan['m']})" if plan["numbering"] == "scaled" and plan["m"] != 1 else "")
             + f"; {chunk}: {len(plan['outputs'])} of {plan['total_outputs']} output frames "
               f"into {where}"]
    if plan.get("note"):
        lines.append(f"  note: {plan['note']}")
    rows = []
    for n, on in plan["copies"]:
        rows.append((on, f"  {_name(prefix, padding, on)}  <- copy of input frame {n}"))
    for i in plan["mine"]:
        a, b, t, on, _ = plan["jobs"][i]
        x = plan["places"][on]
        src = f"input frames {a}, {b}" if a is not None else f"input frame {b}"
        rows.append((on, f"  {_name(prefix, padding, on)}  <- {src} (alpha {t}; at input "
                         f"frame {float(x):g})"))
    lines += [r for _, r in sorted(rows)]
    return lines


def print_plans(tasks, executor: str = "local", workers: int | None = None) -> None:
    from fgcli.batch import split_chunks

    if executor == "dask":  # as fgcli.executor splits them: one chunk per worker
        try:
            cores = len(os.sched_getaffinity(0))
        except (AttributeError, OSError):  # pragma: no cover - non-Linux
            cores = os.cpu_count() or 1
        tasks = split_chunks(tasks, workers or cores)
    from fgcli.errors import OutputError

    readers = {}
    for t in tasks:
        if os.path.exists(t.out_dir) and not os.path.isdir(t.out_dir):
            raise OutputError("output path exists and is not a folder", file=t.out_dir)
        key = (t.folder, t.pattern)
        if key not in readers:
            from fgcli import pipeline as pl
            from fgcli.io.options import open_input

            p = pl.load(t.pipeline)
            readers[key] = open_input(t.folder, fields=set(p.requires), pattern=t.pattern,
                                      **t.in_kw)
        for line in plan_lines(t, readers[key]):
            click.echo(line)


def check_plans(tasks) -> None:
    """Plan every task from headers only (before any output folder is made), so that a
    plan that cannot be (--numbering input between input frames) fails first."""
    from fgcli import pipeline as pl
    from fgcli.batch import plan_task
    from fgcli.io.options import open_input

    for t in tasks:
        p = pl.load(t.pipeline)
        plan_task(t, open_input(t.folder, fields=set(p.requires), pattern=t.pattern, **t.in_kw))
