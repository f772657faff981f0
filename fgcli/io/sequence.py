"""Sequence discovery: frame numbers from file names, oiiotool-style frame ranges, gaps."""
from __future__ import annotations

import fnmatch
import math
import os
import re
from dataclasses import dataclass
from functools import reduce

from fgcli.errors import InputError, UsageError

# name.1001.exr, name_0001.exr, frame_0001.exr, 0001.exr, name-0001.exr; a minus sign
# counts only right after '.' or '_' or at the start (name.-001.exr = frame -1)
_NAME_RE = re.compile(r"^(?P<prefix>.*?)(?P<num>\d+)\.(?P<ext>exr)$", re.IGNORECASE)


def parse_name(fn: str) -> tuple[str, str, int] | None:
    """(prefix, digits, frame number) of a frame file name, or None."""
    m = _NAME_RE.match(fn)
    if not m:
        return None
    prefix, digits = m.group("prefix"), m.group("num")
    n = int(digits)
    if prefix.endswith("-") and (len(prefix) == 1 or prefix[-2] in "._"):
        prefix, n = prefix[:-1], -n
    return prefix, digits, n


def _group(entries: list[tuple[str, str, int, str]]) -> dict[tuple[str, int], dict[int, str]]:
    """Group (prefix, digits, number, path) into sequences keyed by (prefix, padding).
    Zero-padded names fix a padding; unpadded numbers longer than a padding belong to it
    (frame 10000 of a 4-digit sequence); a folder of unpadded names is one sequence."""
    by_prefix: dict[str, list] = {}
    for e in entries:
        by_prefix.setdefault(e[0], []).append(e)
    groups: dict[tuple[str, int], dict[int, str]] = {}
    for prefix, es in by_prefix.items():
        pads = sorted({len(d) for _, d, _, _ in es if len(d) > 1 and d.startswith("0")})
        for _, d, n, path in es:
            if len(d) > 1 and d.startswith("0"):
                pad = len(d)
            else:
                fits = [p for p in pads if p <= len(d)]
                pad = fits[-1] if fits else min(len(x) for _, x, _, _ in es
                                                if not (len(x) > 1 and x.startswith("0")))
            groups.setdefault((prefix, pad), {})[n] = path
    return groups


@dataclass
class Sequence:
    folder: str
    prefix: str  # everything before the digits, e.g. "shot." or "frame_"
    padding: int
    files: dict[int, str]  # frame number -> path

    @property
    def frames(self) -> list[int]:
        return sorted(self.files)

    @property
    def step(self) -> int:
        f = self.frames
        if len(f) < 2:
            return 1
        return reduce(math.gcd, [b - a for a, b in zip(f, f[1:])]) or 1

    @property
    def pattern(self) -> str:
        return f"{self.prefix}{'#' * self.padding}.exr"

    def path_for(self, number: int, folder: str | None = None, prefix: str | None = None) -> str:
        p = self.prefix if prefix is None else prefix
        n = f"{number:0{self.padding}d}" if number >= 0 else f"-{-number:0{self.padding}d}"
        return os.path.join(folder or self.folder, f"{p}{n}.exr")

    def missing(self) -> list[int]:
        f = self.frames
        if len(f) < 2:
            return []
        have = set(f)
        return [n for n in range(f[0], f[-1] + 1, self.step) if n not in have]


def parse_frames(spec: str) -> list[int]:
    """oiiotool-style frame list: '1001-1100x2', '1,3,5-9', '10-1' (descending), '7'."""
    out: list[int] = []
    for item in spec.split(","):
        item = item.strip()
        if not item:
            continue
        m = re.fullmatch(r"(-?\d+)(?:-(-?\d+)(?:x(\d+))?)?", item)
        if not m:
            raise UsageError(f"bad frame range '{item}' (use e.g. 1001-1100x2 or 1,3,5-9)")
        a = int(m.group(1))
        if m.group(2) is None:
            out.append(a)
            continue
        b = int(m.group(2))
        step = int(m.group(3) or 1)
        if step <= 0:
            raise UsageError(f"bad frame step in '{item}'")
        out.extend(range(a, b + 1, step) if b >= a else range(a, b - 1, -step))
    return out


def find_sequences(folder: str, pattern: str | None = None) -> list[Sequence]:
    """Every EXR sequence in `folder` that `pattern` matches (all when None), in name order.
    pattern: a glob on file names ('shot.*.exr'), a prefix ('shot.') or the '#'-padded
    pattern of a sequence ('shot.####.exr')."""
    folder = str(folder)
    if not os.path.isdir(folder):
        raise InputError("not a folder", file=folder)
    entries = []
    for fn in sorted(os.listdir(folder)):
        if fn.startswith(".fgen-tmp-") or not os.path.isfile(os.path.join(folder, fn)):
            continue
        parsed = parse_name(fn)
        if parsed:
            entries.append((*parsed, os.path.join(folder, fn)))
    groups = _group(entries)
    if not groups:
        raise InputError("no EXR frames found (expected names like name.1001.exr or "
                         "frame_0001.exr)", file=folder)
    seqs = [Sequence(folder, p, pad, files) for (p, pad), files in groups.items()]
    if pattern:
        def ok(s: Sequence) -> bool:
            names = [os.path.basename(x) for x in s.files.values()]
            return (pattern == s.pattern or pattern == s.prefix
                    or any(fnmatch.fnmatch(n, pattern) for n in names))
        seqs = [s for s in seqs if ok(s)]
        if not seqs:
            raise InputError(f"no sequence matches --pattern '{pattern}'", file=folder)
    return sorted(seqs, key=lambda q: (q.prefix, q.padding))


def discover(folder: str, pattern: str | None = None, frames: str | None = None,
             allow_gaps: bool = False) -> Sequence:
    """Find the one EXR sequence in `folder`.

    pattern: picks a sequence when there are several: a glob on file names ('shot.*.exr'),
    or a prefix ('shot.'), or the '#'-padded pattern printed in the error ('shot.####.exr').
    """
    seqs = find_sequences(folder, pattern)
    if len(seqs) > 1:
        listing = "; ".join(f"{s.pattern} ({len(s.files)} frames {s.frames[0]}-{s.frames[-1]})"
                            for s in seqs)
        raise InputError(f"several sequences in one folder: {listing}. Pick one with --pattern",
                         file=folder)
    seq = seqs[0]
    if frames:
        want = parse_frames(frames)
        absent = [n for n in want if n not in seq.files]
        if absent:
            raise InputError(f"--frames asks for frames not on disk: {_fmt(absent)}", file=folder)
        seq = Sequence(seq.folder, seq.prefix, seq.padding, {n: seq.files[n] for n in want})
    elif not allow_gaps:
        miss = seq.missing()
        if miss:
            raise InputError(f"gap in frame numbering (step {seq.step}), missing frames: "
                             f"{_fmt(miss)}. Use --allow-gaps to accept", file=folder)
    return seq


def _fmt(nums: list[int], limit: int = 20) -> str:
    s = ", ".join(str(n) for n in nums[:limit])
    return s + (f", ... ({len(nums)} in all)" if len(nums) > limit else "")
