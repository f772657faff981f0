"""Output folders: validation, naming, no-clobber / resume, atomic frame writes, provenance.

    out = OutputFolder("out/", input_folder="shots/sq010", overwrite=False, resume=False)
    path = out.path_for(1001)                # out/frame.1001.exr (prefix/padding settable)
    if out.should_write(path):
        out.write(path, frame, attributes=fgen_attributes(pipeline="mv-interp", alpha=0.5,
                                                          source_frames=[1001, 1002]))
"""
from __future__ import annotations

import os
import sys

from fgcli import __version__
from fgcli.errors import InputError, OutputError
from fgcli.frame import Frame
from fgcli.io import atomic, exr
from fgcli.io.frames import write_frame


def fgen_attributes(pipeline: str | None = None, alpha: float | None = None,
                    source_frames=None, command_line: str | None = None,
                    **extra) -> dict:
    """The `fgen:*` provenance attributes of a written frame.

    pipeline: pipeline name; alpha: the generated frame's offset from its first source frame;
    source_frames: the input frame numbers it was made from; command_line defaults to
    " ".join(sys.argv). Extra keyword arguments become `fgen:<key>` attributes.
    """
    attrs = {"fgen:version": __version__,
             "fgen:command_line": command_line if command_line is not None
             else " ".join(sys.argv)}
    if pipeline is not None:
        attrs["fgen:pipeline"] = str(pipeline)
    if alpha is not None:
        attrs["fgen:alpha"] = float(alpha)
    if source_frames is not None:
        attrs["fgen:source_frames"] = ",".join(str(int(n)) for n in source_frames)
    for k, v in extra.items():
        if v is not None:
            attrs[k if k.startswith("fgen:") else f"fgen:{k}"] = v
    return attrs


def is_complete(path: str) -> bool:
    """True when `path` opens as an EXR, its header reads, and the file is long enough to
    hold the pixels the header describes (a truncated copy is not complete); no pixel is
    decoded."""
    try:
        h = exr.read_header(path)
        size, header_end = exr._check_file(path)
    except InputError:
        return False
    if getattr(h, "data_bytes", 0) < getattr(h, "least_bytes", 0):
        return False
    if len(h.parts) != 1 or h.parts[0].tiled or header_end <= 0:
        return True  # what fgen writes is single-part scanline; others: header only
    return _chunks_inside(path, size, header_end)


def _chunks_inside(path: str, size: int, header_end: int) -> bool:
    """A single-part scanline EXR: the offset table follows the header (its first entry
    tells its length) and every chunk, header and data, lies inside the file."""
    import struct

    try:
        with open(path, "rb") as fh:
            fh.seek(header_end)
            first = fh.read(8)
            if len(first) < 8:
                return False
            (off0,) = struct.unpack("<Q", first)
            n = (off0 - header_end) // 8
            if off0 <= header_end or off0 > size or (off0 - header_end) % 8 or n > 1 << 24:
                return False
            table = first + fh.read(8 * (n - 1))
            if len(table) < 8 * n:
                return False
            offs = struct.unpack(f"<{n}Q", table)
            last = max(offs)
            if min(offs) < off0 or last + 8 > size:
                return False
            fh.seek(last)
            _, nbytes = struct.unpack("<ii", fh.read(8))
            return nbytes >= 0 and last + 8 + nbytes <= size
    except OSError:
        return False


def _same_folder(a: str, b: str) -> bool:
    try:
        if os.path.exists(a) and os.path.exists(b):
            return os.path.samefile(a, b)
    except OSError:
        pass
    return os.path.realpath(a) == os.path.realpath(b)


class OutputFolder:
    """An output folder: refuses the input folder itself, is created when missing, must be
    writable (OutputError, exit 3 otherwise). Existing outputs: an OutputError naming them,
    unless overwrite (write again) or resume (skip complete ones, rewrite others).

    layout / half / compression are the defaults of write() (a layout name, a .toml path or
    a layout object); prefix / padding name numbered outputs (path_for(1001)).
    """

    def __init__(self, path: str, input_folder: str | None = None, overwrite: bool = False,
                 resume: bool = False, *, layout="fgen", half: bool = True,
                 compression: str = "zip", prefix: str = "frame.", padding: int = 4):
        self.path = str(path)
        self.input_folder = None if input_folder is None else str(input_folder)
        self.overwrite = bool(overwrite)
        self.resume = bool(resume)
        self.layout = layout
        self.half = half
        self.compression = compression
        self.prefix = prefix
        self.padding = padding
        self.skipped: list[str] = []
        self.written: list[str] = []
        if self.input_folder is not None and _same_folder(self.path, self.input_folder):
            raise OutputError("refusing to write into the input folder; choose another "
                              "output folder", file=self.path)
        if os.path.exists(self.path) and not os.path.isdir(self.path):
            raise OutputError("output path exists and is not a folder", file=self.path)
        try:
            os.makedirs(self.path, exist_ok=True)
        except OSError as e:
            raise OutputError(f"cannot create output folder: {e.strerror}",
                              file=self.path) from None
        self._check_writable()
        # temporary files of killed runs into this folder (their writer is gone): remove
        self.stale_removed = atomic.remove_stale(self.path)

    def _check_writable(self) -> None:
        try:
            os.unlink(atomic.make_temp(self.path, suffix=".probe"))
        except OSError as e:
            raise OutputError(f"output folder is not writable: {e.strerror}",
                              file=self.path) from None

    def path_for(self, name_or_number) -> str:
        """A path in the folder: a frame number -> `<prefix><number padded>.exr`; a name ->
        that name (`.exr` appended when it has no extension)."""
        if isinstance(name_or_number, bool):
            raise TypeError("path_for takes a frame number or a file name")
        if isinstance(name_or_number, int):
            n = int(name_or_number)
            num = f"{n:0{self.padding}d}" if n >= 0 else f"-{-n:0{self.padding}d}"
            return os.path.join(self.path, f"{self.prefix}{num}.exr")
        name = os.path.basename(str(name_or_number))
        if not os.path.splitext(name)[1]:
            name += ".exr"
        return os.path.join(self.path, name)

    def should_write(self, path: str) -> bool:
        """False when resuming and `path` is complete; True when it is missing (or may be
        replaced); OutputError naming it when it exists and neither overwrite nor resume."""
        if not os.path.exists(path):
            return True
        if self.resume:
            if is_complete(path):
                self.skipped.append(path)
                return False
            return True
        if self.overwrite:
            return True
        raise OutputError("output exists; pass --overwrite to replace it or --resume to keep "
                          "complete outputs", file=path)

    def check_all(self, paths) -> None:
        """Fail before any work when outputs exist and neither overwrite nor resume; the
        error names the existing files."""
        if self.overwrite or self.resume:
            return
        existing = [p for p in paths if os.path.exists(p)]
        if existing:
            names = ", ".join(os.path.basename(p) for p in existing[:10])
            more = f" and {len(existing) - 10} more" if len(existing) > 10 else ""
            raise OutputError(f"outputs exist: {names}{more}; pass --overwrite to replace "
                              "them or --resume to keep complete ones", file=self.path)

    def write(self, path: str, frame: Frame, layout=None, half: bool | None = None,
              compression: str | None = None, attributes: dict | None = None) -> str:
        """Write `frame` atomically (temporary name in this folder, then rename)."""
        path = str(path)
        if not os.path.dirname(path):
            path = self.path_for(path)
        elif not _same_folder(os.path.dirname(os.path.abspath(path)), self.path):
            raise OutputError(f"not inside the output folder {self.path}", file=path)
        write_frame(path, frame, layout=self.layout if layout is None else layout,
                    half=self.half if half is None else half,
                    compression=self.compression if compression is None else compression,
                    attributes=attributes)
        self.written.append(path)
        return path
