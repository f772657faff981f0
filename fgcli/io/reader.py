"""SequenceReader: one object a command uses to walk a sequence in the internal convention."""
from __future__ import annotations

import sys

from fgcli.errors import InputError
from fgcli.frame import Frame
from fgcli.io import exr, layouts, sequence
from fgcli.io.frames import load_sidecar_cameras


class SequenceReader:
    def __init__(self, folder: str, pattern: str | None = None, frames: str | None = None,
                 allow_gaps: bool = False, layout=None, view: str | None = None,
                 fields: set[str] | None = None):
        self.seq = sequence.discover(folder, pattern, frames, allow_gaps)
        self.folder = folder
        self.numbers = self.seq.frames
        first = self.seq.files[self.numbers[0]]
        self.header0 = exr.read_header(first)
        self.layout = layouts.resolve(layout, self.header0)
        self.view = view
        self.fields = fields
        self.width, self.height = self.header0.width, self.header0.height
        self.sidecar = load_sidecar_cameras(folder)
        self.nonfinite: dict = {}
        self._warned = False

    @property
    def step(self) -> int:
        return self.seq.step

    def path(self, n: int) -> str:
        return self.seq.files[n]

    def read(self, n: int) -> Frame:
        if n not in self.seq.files:
            raise InputError("frame not in sequence", file=self.folder, frame=n)
        path = self.seq.files[n]
        header = exr.read_header(path)
        if (header.width, header.height) != (self.width, self.height):
            raise InputError(f"frame size {header.width}x{header.height} differs from the "
                             f"sequence's {self.width}x{self.height}", file=path, frame=n)
        f = self.layout.read(header, n, view=self.view, fields=self.fields,
                             nonfinite=self.nonfinite)
        if f.camera is None and n in self.sidecar:
            f.camera = self.sidecar[n]
        return f

    @property
    def has_camera(self) -> bool:
        if self.sidecar:
            return True
        return layouts.camera_from_header(self.header0) is not None

    def warn_nonfinite(self) -> None:
        """One warning per sequence naming the frames where NaN/Inf were replaced."""
        if self.nonfinite and not self._warned:
            self._warned = True
            for fld, items in self.nonfinite.items():
                frames = sorted({n for n, _ in items})
                count = sum(c for _, c in items)
                print(f"warning: {self.folder}: {count} NaN/Inf values in {fld} replaced with "
                      f"finite values, frames {', '.join(map(str, frames))}", file=sys.stderr)
