"""SequenceReader: one object a command uses to walk a sequence in the internal convention.

It discovers the sequence, resolves the layout and view from the first frame, checks every
frame against the first one's size, reads only the fields asked for, attaches cameras (header
or sidecar `cameras.json`), derives backward vectors when a file carries only forward ones
(Nuke renders), and counts NaN/Inf values for one warning per sequence.
"""
from __future__ import annotations

import sys

import numpy as np

from fgcli.errors import InputError
from fgcli.frame import Frame
from fgcli.io import cameras, exr, layouts, sequence
from fgcli.io.derive import backward_from_forward
from fgcli.io.frames import load_sidecar_cameras, load_sidecar_jitter


class SequenceReader:
    """Walk a sequence folder.

    fields: Frame fields needed (e.g. {"color", "depth", "mv"}); None reads all present.
    optional: fields read when present but not required (alpha is always optional).
    Attributes: numbers, layout, view, views, width, height, step, info (LayoutInfo of the
    first frame), notes (facts worth telling the user), camera_source.
    """

    def __init__(self, folder: str, pattern: str | None = None, frames: str | None = None,
                 allow_gaps: bool = False, layout=None, view: str | None = None,
                 fields: set[str] | None = None, optional: set[str] | None = None,
                 gbuffer_frames: bool = False):
        self.folder = str(folder)
        self.seq = sequence.discover(self.folder, pattern, frames, allow_gaps)
        # every frame on disk (for the previous frame of a forward-vector derivation)
        self.all_files = (sequence.discover(self.folder, pattern, None, True).files
                          if frames else dict(self.seq.files))
        self.disk_step = sequence.Sequence(self.folder, "", 0, self.all_files).step
        self.numbers = self.seq.frames
        # G-buffer-only frames (depth, vectors, normals, albedo but no colour: frames an
        # engine did not shade): found when asked for; the layout comes from a shaded frame
        self.gbuffer_only: list[int] = []
        first = self.seq.files[self.numbers[0]]
        if gbuffer_frames:
            self.gbuffer_only, first = _gbuffer_only(self.seq, layout, view)
            if self.gbuffer_only:  # the sequence is its shaded frames
                from dataclasses import replace

                skip = set(self.gbuffer_only)
                self.gbuffer_files = {n: self.seq.files[n] for n in self.gbuffer_only}
                self.seq = replace(self.seq, files={n: p for n, p in self.seq.files.items()
                                                    if n not in skip})
                self.numbers = self.seq.frames
        try:
            self.header0 = exr.read_header(first)
            self.layout = layouts.resolve(layout, self.header0)
            self.info = self.layout.describe(self.header0, view)
        except InputError as e:
            raise e.with_frame(self.numbers[0]) from None
        self.view = self.info.view
        self.views = self.info.views
        self.fields = None if fields is None else set(fields)
        self.optional = set(optional or ())
        self.width, self.height = self.header0.width, self.header0.height
        self.sidecar = load_sidecar_cameras(self.folder)
        self.sidecar_jitter = load_sidecar_jitter(self.folder)
        self.nonfinite: dict = {}
        self._warned = False
        self._derive = (self.info.mv_source == "forward"
                        and (self.fields is None or "mv" in self.fields))
        self._prev_fwd = None  # (number, fwd (2,H,W), depth (1,H,W) or None, valid or None)
        self.notes: list[str] = list(self.info.notes)
        if self.info.mv_source == "forward" and not self._derive:
            self.notes = [n for n in self.notes if not n.startswith("backward vectors derived")]

    # -- facts ----------------------------------------------------------------------------
    @property
    def step(self) -> int:
        return self.seq.step

    def path(self, n: int) -> str:
        return self.seq.files[n]

    @property
    def camera_source(self) -> str | None:
        """'fgen header', 'worldToCamera/worldToNDC', 'cameras.json' or None."""
        part = self.info.part_of("color") if "color" in self.info.names else 0
        _, src = cameras.from_header_attributes(self.header0.parts[part].attributes)
        if src:
            return src
        return "cameras.json" if self.sidecar else None

    @property
    def has_camera(self) -> bool:
        return self.camera_source is not None

    @property
    def mv_derived(self) -> bool:
        """True when backward vectors are derived from forward vectors."""
        return self.info.mv_source == "forward"

    def frames_without_backward(self) -> list[int]:
        """Selected frames whose backward vectors cannot be derived (forward-only files with
        no file before them on disk): the reader gives them zero vectors, flagged invalid."""
        if not self.mv_derived:
            return []
        return [n for n in self.numbers if n - self.disk_step not in self.all_files]

    NO_BACKWARD_EFFECT = ("interpolation from such a frame uses linear motion from the next "
                          "frame's vectors (its own vectors are not used); extrapolation past "
                          "it sees no motion and repeats it")

    def check_sizes(self) -> None:
        """Read every frame's header; InputError naming the first frame whose size differs."""
        for n in self.numbers:
            self._header(n)

    # -- reading --------------------------------------------------------------------------
    def _header(self, n: int, path: str | None = None) -> exr.Header:
        path = path or self.seq.files[n]
        try:
            header = exr.read_header(path)
        except InputError as e:
            raise e.with_frame(n) from None
        if (header.width, header.height) != (self.width, self.height):
            # which of the two is wrong cannot be told: name both files
            raise InputError(f"frame size {header.width}x{header.height} differs from the "
                             f"sequence's {self.width}x{self.height} (frame "
                             f"{self.numbers[0]}, {self.header0.path})", file=path, frame=n)
        return header

    def read_raw(self, n: int) -> layouts.RawFrame:
        if n not in self.seq.files:
            raise InputError("frame not in sequence", file=self.folder, frame=n)
        header = self._header(n)
        optional = self.optional | ({"depth"} if self._derive else set())
        try:
            raw = self.layout.read_raw(header, n, view=self.view, fields=self.fields,
                                       nonfinite=self.nonfinite, optional=optional)
            if self._derive:
                self._derive_mv(raw)
        except InputError as e:
            raise e.with_frame(n) from None
        if self._derive:
            if self.fields is not None and "depth" not in self.fields | self.optional:
                raw.helpers.add("depth")
        if raw.camera is None and n in self.sidecar:
            raw.camera = self.sidecar[n]
        if n in self.sidecar_jitter and "fgen:jitter_x" not in raw.attributes:
            raw.attributes["fgen:jitter_x"], raw.attributes["fgen:jitter_y"] = \
                self.sidecar_jitter[n]
        win = self._window_of(header)
        raw.data_mask, raw.data_window = (None, None) if win is None else win
        self._fill_sky_vectors(raw)
        if not self._depth_checked and raw.arrays.get("depth") is not None:
            self._depth_checked = True
            why = depth_suspicion(raw.arrays["depth"])
            if why:
                print(f"warning: {path_of(self, n)}: frame {n}: channel depth: {why}; fgen "
                      "expects linear view depth (+inf for sky). Depth tests will be wrong: "
                      "convert it, or describe it in a layout TOML (depth_kind, depth_scale, "
                      "sky_depth)", file=sys.stderr)
        return raw

    def read(self, n: int) -> Frame:
        return self.finish(self.read_raw(n))

    def finish(self, raw: layouts.RawFrame) -> Frame:
        """The Frame (torch tensors, sharing the arrays' memory) of a frame read_raw() read:
        padding outside the data window flagged, vectors chained across skipped files.
        read() = read_raw() + finish(); read_raw() needs numpy only (no torch import), so
        a reader thread can decode frames while torch is still being imported. finish()
        may read other files (vector chaining): not concurrently with read_raw()."""
        f = raw.to_frame()
        if raw.data_window is not None:  # padding carries no data: say so explicitly
            import torch

            mask = torch.from_numpy(raw.data_mask[None])
            alpha = mask.float() if f.alpha is None else f.alpha * mask
            kw = {"alpha": alpha, "data_window": raw.data_window}
            if f.mv is not None:  # derived vectors too: none where this frame has no data
                kw["mv"] = torch.where(mask, f.mv, torch.zeros_like(f.mv))
                kw["mv_valid"] = mask if f.mv_valid is None else f.mv_valid & mask
            f = f.replace(**kw)
        return self._span_gap(f)

    @staticmethod
    def _window_of(header) -> tuple | None:
        """Union of the parts' data windows on the display window, as (mask (H, W) bool,
        bounding box (x, y, w, h)); None when every part covers the display window."""
        if all(p.full_data_window for p in header.parts):
            return None
        mask = np.zeros((header.height, header.width), bool)
        for p in header.parts:
            mask |= p.data_mask()
        ys, xs = np.nonzero(mask.any(1))[0], np.nonzero(mask.any(0))[0]
        if len(ys) == 0:
            return mask, (0, 0, 0, 0)
        return mask, (int(xs[0]), int(ys[0]), int(xs[-1] - xs[0] + 1), int(ys[-1] - ys[0] + 1))

    # -- vectors that span the selected step ------------------------------------------------
    def gap_before(self, n: int) -> int:
        """Frames between n and the selected frame before it (the sequence's step for the
        first one): the interval frame n's vectors must span."""
        i = self.numbers.index(n)
        return n - self.numbers[i - 1] if i > 0 else self.step

    def finish_reads(self, n: int) -> bool:
        """Whether finish() of frame n may read other files (its vectors chained through
        skipped files): only then must it not run beside read_raw() on another thread."""
        gap, s = self.gap_before(n), self.disk_step
        return gap > s and gap % s == 0

    def _span_gap(self, f: Frame) -> Frame:
        """With --frames selecting every k-th file on disk, a file's vectors span one step on
        disk, not the gap to the previous selected frame: chain them through the skipped
        files (b(p) = mv_n(p) + mv_{n-1}(p + mv_n(p)) + ..., as eval --factor does; derived
        backward vectors likewise). Where a skipped file is missing, the vectors are taken to
        span the selected gap as they are."""
        gap, s = self.gap_before(f.number), self.disk_step
        if f.mv is None or gap <= s or gap % s:
            return f
        between = list(range(f.number - s, f.number - gap, -s))
        first_on_disk = f.number == min(self.all_files)
        if not first_on_disk and not all(k in self.all_files for k in between):
            return f
        from fgcli.ops import chain_mv

        if first_on_disk:  # nothing earlier on disk: constant velocity, as eval --factor
            mvs = [f.mv * float(gap // s)]
        else:
            mvs = [f.mv] + [self._disk_mv(k) for k in between]
        if not self._chain_noted:
            self._chain_noted = True
            note = (f"vectors chained through the {len(between)} file(s) on disk between "
                    f"selected frames (gap {gap}, files every {s}) so they span the selected "
                    "interval")
            self.notes.append(note)
            print(f"note: {self.folder}: {note}", file=sys.stderr)
        return f.replace(mv=chain_mv(mvs))

    def _disk_mv(self, k: int):
        """Backward vectors (torch (2, H, W)) of file k on disk, selected or not."""
        import torch

        header = self._header(k, self.all_files[k])
        try:
            # a skipped file may be G-buffer-only (no colour): only its vectors are read
            raw = self.layout.read_raw(header, k, view=self.view, fields={"mv"},
                                       optional={"depth", "color"})
            if self._derive:
                self._derive_mv(raw)
        except InputError as e:
            raise e.with_frame(k) from None
        if raw.camera is None and k in self.sidecar:
            raw.camera = self.sidecar[k]
        self._fill_sky_vectors(raw)
        return torch.from_numpy(np.ascontiguousarray(raw.arrays["mv"], dtype=np.float32))

    _chain_noted = False

    def _derive_mv(self, raw: layouts.RawFrame) -> None:
        n = raw.number
        h, w = self.height, self.width
        fwd_here = raw.arrays.get("mv_fwd")
        prev = n - self.disk_step
        src = None
        if self._prev_fwd is not None and self._prev_fwd[0] == prev:
            src = self._prev_fwd[1:]
        elif prev in self.all_files:
            header = self._header(prev, self.all_files[prev])
            p = self.layout.read_raw(header, prev, view=self.view,
                                     fields={"mv_fwd", "depth"}, optional={"depth"})
            if "mv_fwd" in p.arrays:
                src = (p.arrays["mv_fwd"], p.arrays.get("depth"), p.valid.get("mv_fwd"))
        if src is not None:
            mv, valid = backward_from_forward(*src)
            here = raw.arrays.get("depth")
            if here is not None and not valid.all():
                # no surface here (sky, empty space of an element render) and nothing of
                # frame t-1 landed: a neighbour's surface motion is not this pixel's
                empty = ~valid & ~np.isfinite(here.reshape(1, h, w))
                if empty.any():
                    mv = np.where(empty, 0.0, mv).astype(np.float32)
        else:  # first frame on disk: nothing to derive from
            mv = np.zeros((2, h, w), np.float32)
            valid = np.zeros((1, h, w), bool)
        raw.arrays["mv"] = mv
        if not valid.all():
            raw.valid["mv"] = valid
        if fwd_here is not None:
            self._prev_fwd = (n, fwd_here, raw.arrays.get("depth"), raw.valid.get("mv_fwd"))
        if self.fields is not None and "mv_fwd" not in self.fields and \
                "mv_fwd" not in self.optional:
            raw.helpers.add("mv_fwd")

    def nonfinite_summary(self) -> str | None:
        """One line naming the fields, counts and frames where NaN/Inf were replaced."""
        if not self.nonfinite:
            return None
        parts, all_frames = [], set()
        for fld, items in self.nonfinite.items():
            frames = sorted({n for n, _ in items})
            all_frames.update(frames)
            count = sum(c for _, c in items)
            what = "+inf" if fld == "depth" else "0"
            parts.append(f"{fld}: {count} -> {what} (frames {sequence._fmt(frames)})")
        return (f"{self.folder}: NaN/Inf values replaced with finite values in frames "
                f"{sequence._fmt(sorted(all_frames))}; " + "; ".join(parts))

    _depth_checked = False
    _sky_note = False

    def camera_of(self, n: int):
        """Camera of frame n on disk (header attributes or cameras.json), or None."""
        if n in self.sidecar:
            return self.sidecar[n]
        if n not in self.all_files:
            return None
        header = self._header(n, self.all_files[n])
        part = self.info.part_of("color") if "color" in self.info.names else 0
        cam, _ = cameras.from_header_attributes(header.parts[part].attributes)
        return cam

    def _fill_sky_vectors(self, raw) -> None:
        """Flagged sky vectors (Blender writes 0 there even when the camera moves) are
        recomputed from the two cameras when both are known (cameras.sky_motion)."""
        valid = raw.valid.get("mv")
        depth = raw.arrays.get("depth")
        if valid is None or depth is None or raw.camera is None or "mv" not in raw.arrays:
            return
        sky = ~valid & ~np.isfinite(depth)
        if not sky.any():
            return
        cam_prev = self.camera_of(raw.number - self.disk_step)
        if cam_prev is None:
            return
        mv = cameras.sky_motion(raw.camera, cam_prev, self.width, self.height)
        raw.arrays["mv"] = np.where(sky, mv, raw.arrays["mv"]).astype(np.float32)
        valid = valid | sky
        if valid.all():
            raw.valid.pop("mv")
        else:
            raw.valid["mv"] = valid
        if not self._sky_note:
            self._sky_note = True
            self.notes.append("sky vectors (flagged by the layout) computed from the cameras")

    def warn_nonfinite(self) -> None:
        """One warning per sequence naming the frames where NaN/Inf were replaced."""
        msg = self.nonfinite_summary()
        if msg and not self._warned:
            self._warned = True
            print(f"warning: {msg}", file=sys.stderr)


def _gbuffer_only(seq, layout, view) -> tuple[list[int], str]:
    """(numbers of the frames without colour channels, path of the first frame with them).
    The layout is the one given, else the one detected on the shaded frames (a frame
    without colour may not tell its layout by itself); a sequence whose layout cannot be
    told raises as it would anyway; with no shaded frame at all, nothing is set apart
    (reading then names the missing colour channels)."""
    headers = {}
    lay, err = None, None
    for n in seq.frames:
        try:
            headers[n] = exr.read_header(seq.files[n])
        except InputError as e:
            raise e.with_frame(n) from None
        if lay is None:
            try:
                lay = layouts.resolve(layout, headers[n])
            except InputError as e:
                err = err or e.with_frame(n)
    if lay is None:
        raise err
    gbuf, first = [], None
    for n in seq.frames:
        try:
            has = "color" in lay.describe(headers[n], view).names
        except InputError as e:
            raise e.with_frame(n) from None
        if has:
            first = first or seq.files[n]
        else:
            gbuf.append(n)
    if first is None:
        return [], seq.files[seq.frames[0]]
    return gbuf, first


def path_of(reader, n: int) -> str:
    return reader.seq.files.get(n, reader.folder)


def depth_suspicion(depth) -> str | None:
    """Why a depth buffer looks like something other than linear view depth, or None.

    Normalised device depth sits in [0, 1] with no +inf sky and crowds towards the far
    end: near 1 for the conventional mapping, near 0 for reversed-Z. Linear depth of a
    real scene seldom stays inside one unit everywhere without any sky.
    """
    import numpy as np

    d = np.asarray(depth, dtype=np.float32)
    fin = d[np.isfinite(d)]
    if fin.size == 0:
        return None
    if (fin <= 0).mean() > 0.5:
        return f"{(fin <= 0).mean():.0%} of the values are <= 0"
    if np.isinf(d).any() or fin.max() > 1.0 or fin.min() < 0.0:
        return None
    med = float(np.median(fin))
    if med > 0.9:
        return f"all values lie in [0, 1] (median {med:.3f}): looks like normalized device depth"
    if med < 0.1:
        return f"all values lie in [0, 1] (median {med:.3f}): looks like reversed-Z device depth"
    return None

