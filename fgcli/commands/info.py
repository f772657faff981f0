"""fgen info DIR: layout, resolution, frames, channels, cameras, derived facts, NaN/Inf scan.

Works without importing torch (headers and numpy only).
"""
from __future__ import annotations

import json

import click
import numpy as np

from fgcli.io.options import input_options


def _channels(header, info) -> list[dict]:
    out = []
    multi = len(header.parts) > 1
    for p in header.parts:
        for c, f in zip(p.channels, p.formats):
            d = {"name": c, "type": f}
            if multi:
                d["part"] = p.index
                if p.name:
                    d["part_name"] = p.name
            if p.view:
                d["view"] = p.view
            out.append(d)
    return out


def _channel_key(header, part, ch) -> str:
    if len(header.parts) == 1:
        return ch
    return f"{part.name or part.index}:{ch}"


def scan(reader) -> dict:
    """Count NaN/Inf per channel over every frame: {channel: {"count": n, "frames": [...]}}
    (depth channels: NaN and -Inf only; +Inf is sky)."""
    from fgcli.errors import InputError
    from fgcli.io import exr

    depth_names = {n for f, ns in reader.info.names.items() if f == "depth" for n in ns}
    depth_refs = {reader.info.space[n] for n in depth_names}
    result: dict[str, dict] = {}
    for n in reader.numbers:
        path = reader.path(n)
        header = reader._header(n)
        refs = [(p.index, c) for p in header.parts for c in p.channels]
        try:
            arrays = exr.read_channels(path, refs, header)
        except InputError as e:
            raise e.with_frame(n) from None
        for (pi, c), a in arrays.items():
            key = _channel_key(header, header.parts[pi], c)
            if (pi, c) in depth_refs:
                bad = int((np.isnan(a) | np.isneginf(a)).sum())
            else:
                bad = int((~np.isfinite(a)).sum())
            r = result.setdefault(key, {"count": 0, "frames": []})
            if bad:
                r["count"] += bad
                r["frames"].append(n)
    return result


def describe(reader, do_scan: bool = False, layout_option=None) -> dict:
    h = reader.header0
    info = reader.info
    nums = reader.numbers
    d = {
        "folder": reader.folder,
        "layout": reader.layout.name,
        "layout_detected": layout_option in (None, "auto"),
        "width": reader.width,
        "height": reader.height,
        "frames": nums,
        "count": len(nums),
        "first": nums[0],
        "last": nums[-1],
        "step": reader.step,
        "pattern": reader.seq.pattern,
        "views": info.views,
        "view": info.view,
        "parts": len(h.parts),
        "channels": _channels(h, info),
        "fields": {f: ns for f, ns in info.names.items()},
        "mv_source": info.mv_source,
        "mv_derived": reader.mv_derived,
        "has_camera": reader.has_camera,
        "camera_source": reader.camera_source,
        "notes": reader.notes,
        "no_backward_vectors": reader.frames_without_backward(),
        # frames with G-buffers and no colour (not shaded): not among "frames"
        "gbuffer_only": list(getattr(reader, "gbuffer_only", []) or []),
        "jitter": all(k in h.parts[0].attributes for k in ("fgen:jitter_x", "fgen:jitter_y"))
        or bool(getattr(reader, "sidecar_jitter", None)),
        "tiled": any(p.tiled for p in h.parts),
        "data_window_smaller": any(not p.full_data_window and not p.overscan
                                   for p in h.parts),
        "overscan": [(p.x, p.y, p.data_width, p.data_height) for p in h.parts if p.overscan],
    }
    from fgcli.io.metadata import fgen_metadata

    # fgen's own metadata (time, provenance, synth facts) of the first frame
    d["fgen"] = fgen_metadata(h.parts[0].attributes)
    if do_scan:
        d["nonfinite"] = scan(reader)
    return d


def _text(d: dict) -> str:
    lines = [f"folder:      {d['folder']}",
             f"layout:      {d['layout']}" + (" (detected)" if d["layout_detected"] else ""),
             f"resolution:  {d['width']}x{d['height']}",
             f"frames:      {d['first']}-{d['last']} ({d['count']} frames, step {d['step']})"
             f"  {d['pattern']}"]
    if d.get("gbuffer_only"):
        g = d["gbuffer_only"]
        lines.append(f"G-buffer-only: {len(g)} frames without colour (depth, vectors, "
                     f"G-buffers only; never read as colour): "
                     f"{', '.join(map(str, g[:12]))}{', ...' if len(g) > 12 else ''}")
    if d.get("jitter"):
        lines.append("jitter:      per-frame sub-pixel jitter (a render for --scale)")
    if d["views"]:
        lines.append(f"view:        {d['view']} (views: {', '.join(d['views'])})")
    names = [f for f in d["fields"] if f != "mv_valid"]
    if d["mv_derived"]:
        names.insert(0 if "color" not in names else 1 + names.index("color"),
                     "mv (backward vectors derived from forward vectors)")
    fields = ", ".join(names)
    lines.append(f"fields:      {fields}")
    if d.get("no_backward_vectors"):
        from fgcli.io.reader import SequenceReader

        lines.append(f"no backward vectors: frames {', '.join(map(str, d['no_backward_vectors']))}"
                     f" (nothing before them to derive from); {SequenceReader.NO_BACKWARD_EFFECT}")
    lines.append(f"cameras:     {d['camera_source'] or 'none'}")
    extra = []
    if d["parts"] > 1:
        extra.append(f"{d['parts']} parts")
    if d["tiled"]:
        extra.append("tiled")
    if d["data_window_smaller"]:
        extra.append("data window smaller than display window (padded)")
    if d["overscan"]:
        x, y, w, h = d["overscan"][0]
        extra.append(f"overscan: data window {w}x{h} at ({x}, {y}) beyond the display "
                     f"window (the border is kept for gffe-extrap's hole fill)")
    if extra:
        lines.append(f"file:        {', '.join(extra)}")
    lines.append("channels:")
    for c in d["channels"]:
        where = ""
        if "part" in c:
            where = f"  [part {c['part']}" + (f" {c['part_name']}" if c.get("part_name") else "")
            where += (f", view {c['view']}]" if c.get("view") else "]")
        lines.append(f"  {c['name']:<24} {c['type']}{where}")
    if d.get("fgen"):
        lines.append(f"fgen metadata (frame {d['first']}):")
        for k, v in d["fgen"].items():
            text = v if isinstance(v, str) else json.dumps(v)
            if len(text) > 100:
                text = text[:97] + "..."
            lines.append(f"  fgen:{k:<22} {text}")
    for n in d["notes"]:
        if not n.startswith("view '"):  # already on the view line
            lines.append(f"note: {n}")
    if "nonfinite" in d:
        bad = {k: v for k, v in d["nonfinite"].items() if v["count"]}
        if not bad:
            lines.append("NaN/Inf:     none")
        else:
            lines.append("NaN/Inf:")
            for k, v in bad.items():
                fr = ", ".join(map(str, v["frames"][:10])) + (", ..." if len(v["frames"]) > 10
                                                              else "")
                lines.append(f"  {k:<24} {v['count']} (frames {fr})")
    return "\n".join(lines)


@click.command(help="Describe a sequence: layout, resolution, frames, channels with types, "
                    "cameras, derived vectors; --scan counts NaN/Inf per channel.")
@click.argument("folder", type=click.Path())
@input_options
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
@click.option("--scan", "do_scan", is_flag=True,
              help="Read every frame and count NaN/Inf values per channel.")
def cmd(folder, as_json, do_scan, **kw):
    from fgcli.io.options import open_input

    reader = open_input(folder, gbuffer_frames=True, **kw)
    reader.check_sizes()
    d = describe(reader, do_scan, kw.get("layout"))
    if as_json:
        click.echo(json.dumps(d))
    else:
        click.echo(_text(d))
