"""How output frames are numbered (`--numbering`), on top of fgcli.runner.plan_outputs.

Every output frame has a place x on the input's frame-number timeline (a rendered frame n:
x = n; a generated one: a + alpha (b - a), or b + alpha * step when extrapolating).

- `scaled` (default): x times the smallest integer m that makes every x of the run an
  integer (the timeline scale; 1 when they already are): a rendered frame n becomes n*m.
  Input 0, 2, 4 with --factor 2: m = 1, outputs 1, 3 (the input's own numbers); with
  --factor 4: m = 2, generated frames 1, 2, 3, 5, ... and rendered frame 2 becomes 4.
- `input`: x itself; refused (usage error) when some x is not an integer.
- `sequential`: consecutive numbers in time order from the first input frame's number.

Output numbers never repeat, so names in one output folder never collide; with `scaled`
numbering and m > 1 a generated frame may take a number an input frame has (at another
time): the run says so, and every header carries `fgen:input_frame` (x) and
`fgen:numbering`.
"""
from __future__ import annotations

from fractions import Fraction

from fgcli.errors import UsageError

CHOICES = ("scaled", "input", "sequential")


def _place(job, mode: str, step: int) -> Fraction:
    a, b, t, _, _ = job
    if mode == "interp":
        return Fraction(a) + Fraction(t) * (b - a)
    return Fraction(b) + Fraction(t) * step


def renumber(plan: dict, numbering: str = "scaled", mode: str = "interp",
             emit: str = "generated") -> dict:
    """The plan with its output numbers under `numbering`; adds "numbering", "places"
    (output number -> x on the input timeline, a Fraction) and "note" (a sentence for the
    log when the numbers differ from the input's, else None). The same for every chunk of
    a run (numbers come from the whole run's outputs)."""
    if numbering not in CHOICES:
        raise UsageError(f"unknown --numbering '{numbering}' (one of {', '.join(CHOICES)})")
    m, step = plan["m"], plan["step"]
    places = {j[3]: _place(j, mode, step) for j in plan["jobs"]}
    if emit == "all":
        places.update({n * m: Fraction(n) for n in plan["numbers"]})
    all_scaled = sorted(places)
    if numbering == "scaled":
        new = {on: on for on in all_scaled}
    elif numbering == "input":
        bad = [places[on] for on in all_scaled if places[on].denominator != 1]
        if bad:
            raise UsageError(
                f"--numbering input: generated frames fall between input frame numbers "
                f"(e.g. at {float(bad[0]):g}; input step {step}); use --numbering scaled "
                f"(x{m}: input frame n becomes n*{m}) or --numbering sequential")
        new = {on: int(places[on]) for on in all_scaled}
    else:
        first = plan["numbers"][0]
        new = {on: first + i for i, on in enumerate(all_scaled)}
    if len(set(new.values())) != len(new):  # pragma: no cover - by construction
        raise UsageError("output frame numbers would collide")
    out = dict(plan)
    out["jobs"] = [(a, b, t, new[on], p) for a, b, t, on, p in plan["jobs"]]
    out["copies"] = [(n, new[on]) for n, on in plan["copies"]]
    out["outputs"] = [new[on] for on in plan["outputs"]]
    out["places"] = {new[on]: places[on] for on in all_scaled}
    out["numbering"] = numbering
    out["note"] = note(numbering, m)
    return out


def note(numbering: str, m: int) -> str | None:
    if numbering == "scaled" and m != 1:
        return (f"output frames are numbered on the input's timeline x{m} (generated frames "
                f"fall between input frame numbers): input frame n is output frame n*{m}; "
                f"--numbering sequential numbers them 1 apart, fgen:input_frame in each "
                f"header gives its place on the input's timeline")
    if numbering == "sequential":
        return ("output frames are numbered consecutively in time order from the first input "
                "frame's number (--numbering sequential); fgen:input_frame in each header "
                "gives its place on the input's timeline")
    return None
