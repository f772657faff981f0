"""`fgen eval --report DIR`: a report to publish.

DIR/index.html      one self-contained page (every image inlined as base64, no network):
                    the table, per-frame PSNR, quality vs time, stage times, and the same
                    crop of the hardest frame for the ground truth and every pipeline, at
                    1:1 and zoomed, with the error on one shared scale and its colour bar
DIR/summary.md      the table and the figures, in Markdown
DIR/*.png           the same figures; DIR/crops/*.png the crops at 1:1 and zoomed
DIR/.fgen-report.json  what the report wrote: the next report into DIR removes those
                    files first (and nothing else)

Timings: with `--repeat N` each pipeline's ms per frame is the median of the N runs'
medians, with the runs' min-max as its spread (merge_repeats).
"""
from __future__ import annotations

import base64
import html
import json
import math
import os

from fgcli.errors import OutputError

MANIFEST = ".fgen-report.json"
ZOOM = 4
CROP = 64  # crop side in pixels (smaller frames: the whole side)


# ----------------------------------------------------------------------------- evaluate hooks


def keep_hardest(cur, target: int, gt, outs: dict):
    """The frame to show in the report's crops: the one with the lowest mean PSNR over the
    pipelines, with every pipeline's output of it. outs: label -> (color, psnr)."""
    if not outs:
        return cur
    vals = [p for _, p in outs.values() if math.isfinite(p)]
    mean = sum(vals) / len(vals) if vals else float("inf")
    if cur is not None and not mean < cur["mean_psnr"]:
        return cur
    return {"frame": target, "gt": gt.detach().cpu().clone(), "mean_psnr": mean,
            "outs": {k: v[0] for k, v in outs.items()}, "psnr": {k: v[1] for k, v in outs.items()}}


def merge_repeats(runs: list[dict]) -> dict:
    """One result from `--repeat N` runs of the same evaluation: the first run's scores;
    per pipeline ms_per_frame = the median of the runs', ms_per_frame_runs = each run's,
    ms_per_frame_spread = [min, max]; per-stage medians likewise."""
    import statistics

    base = runs[0]
    base["repeats"] = len(runs)
    if len(runs) == 1:
        return base
    for name, r in base["pipelines"].items():
        ms = [run["pipelines"][name]["ms_per_frame"] for run in runs]
        r["ms_per_frame"] = statistics.median(ms)
        r["ms_per_frame_runs"] = ms
        r["ms_per_frame_spread"] = [min(ms), max(ms)]
        for sid in list(r["stages"]):
            r["stages"][sid] = statistics.median(
                run["pipelines"][name]["stages"].get(sid, 0.0) for run in runs)
    return base


# ----------------------------------------------------------------------------- the folder


def check_report_dir(path: str) -> None:
    """The report folder exists (or is made) and is writable; OutputError (exit 3) if not."""
    if os.path.exists(path) and not os.path.isdir(path):
        raise OutputError("report path exists and is not a folder", file=path)
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as e:
        raise OutputError(f"cannot create report folder: {e.strerror}", file=path) from None
    if not os.access(path, os.W_OK):
        raise OutputError("report folder is not writable", file=path)


def clear_previous(out_dir: str) -> list[str]:
    """Remove what an earlier report wrote into out_dir (its manifest's files, and the
    worst_*.png of reports that had no manifest); nothing else. The names removed."""
    gone = []
    names = []
    mf = os.path.join(out_dir, MANIFEST)
    if os.path.isfile(mf):
        try:
            with open(mf) as fh:
                names = list(json.load(fh).get("files", []))
        except (OSError, ValueError, AttributeError):
            names = []
    else:
        names = [n for n in os.listdir(out_dir) if n.startswith("worst_") and n.endswith(".png")]
    for n in names:
        p = os.path.normpath(os.path.join(out_dir, n))
        if os.path.dirname(p).startswith(os.path.normpath(out_dir)) and os.path.isfile(p):
            os.unlink(p)
            gone.append(n)
    crops = os.path.join(out_dir, "crops")
    if os.path.isdir(crops) and not os.listdir(crops):
        os.rmdir(crops)
    return gone


# ----------------------------------------------------------------------------- figures


def _display(x):
    import numpy as np

    from fgcli.ops.color import srgb_oetf

    return np.clip(srgb_oetf(x.float()).permute(1, 2, 0).numpy(), 0, 1)


def _colors(names):
    """A distinct colour per name, the same for a name in every figure."""
    import matplotlib

    if len(names) <= 10:
        pal = list(matplotlib.colormaps["tab10"].colors)
    else:  # up to 60 distinct ones
        pal = [c for m in ("tab20", "tab20b", "tab20c") for c in matplotlib.colormaps[m].colors]
    return {n: pal[i % len(pal)] for i, n in enumerate(names)}


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name)


def _fig_quality(result, colors, path):
    import matplotlib.pyplot as plt

    pipes = result["pipelines"]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, key, lab in ((axes[0], "psnr", "PSNR (dB, higher is better)"),
                         (axes[1], "flip", "LDR-FLIP (lower is better)")):
        for name, r in pipes.items():
            x, y = r["ms_per_frame"], r[key]
            sp = r.get("ms_per_frame_spread")
            xerr = [[x - sp[0]], [sp[1] - x]] if sp else None
            ax.errorbar([x], [y], xerr=xerr, fmt="o", color=colors[name], capsize=3,
                        label=name)
        ax.set_xlabel("ms per generated frame" + (" (median, min-max of runs)"
                                                  if result.get("repeats", 1) > 1 else ""))
        ax.set_ylabel(lab)
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=7, loc="best")
    fig.suptitle(f"quality vs time ({result['mode']}, {result['frames']} frames)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _fig_per_frame(result, colors, path):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 3.6))
    for name, r in result["pipelines"].items():
        pf = r.get("per_frame") or []
        ax.plot([p["frame"] for p in pf], [p["psnr"] for p in pf], marker=".", label=name,
                color=colors[name])
    ax.set_xlabel("ground-truth frame")
    ax.set_ylabel("PSNR (dB)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.0, 0.5))
    ax.set_title("PSNR per frame")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _fig_stages(result, path):
    import matplotlib.pyplot as plt

    pipes = result["pipelines"]
    sids = []
    for r in pipes.values():
        for sid in r["stages"]:
            if sid not in sids:
                sids.append(sid)
    scol = _colors(sids)
    fig, ax = plt.subplots(figsize=(10, 1.2 + 0.45 * len(pipes)))
    names = list(pipes)
    for i, name in enumerate(names):
        left = 0.0
        for sid, ms in pipes[name]["stages"].items():
            ax.barh(i, ms, left=left, color=scol[sid], edgecolor="white", linewidth=0.5)
            left += ms
        ax.text(left, i, f" {left:.1f} ms", va="center", fontsize=7)
    ax.set_yticks(range(len(names)))
    ax.set_yticklabels(names, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("median ms per generated frame, by stage")
    ax.set_xlim(0, max([sum(r["stages"].values()) for r in pipes.values()] + [1.0]) * 1.18)
    handles = [plt.Rectangle((0, 0), 1, 1, color=scol[s]) for s in sids]
    ax.legend(handles, sids, fontsize=7, loc="center left", bbox_to_anchor=(1.0, 0.5),
              title="stage", title_fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def crop_box(gt, outs: dict, size: int = CROP) -> tuple[int, int, int, int]:
    """(x, y, w, h) of the size x size region with the largest error summed over the
    pipelines (display-referred colour)."""
    import numpy as np

    g = _display(gt)
    err = sum(np.abs(_display(o) - g).mean(axis=2) for o in outs.values())
    H, W = err.shape
    ch, cw = min(size, H), min(size, W)
    s = np.cumsum(np.cumsum(np.pad(err, ((1, 0), (1, 0))), 0), 1)
    box = s[ch:, cw:] - s[:-ch, cw:] - s[ch:, :-cw] + s[:-ch, :-cw]
    y, x = np.unravel_index(np.argmax(box), box.shape)
    return int(x), int(y), int(cw), int(ch)


def _fig_crops(compare, out_dir, files) -> dict:
    """The crops (1:1, zoomed, error zoomed) as PNGs under crops/, a colour bar and the
    combined figure crops.png; returns what the page needs."""
    import matplotlib.pyplot as plt
    import numpy as np

    gt = _display(compare["gt"])
    outs = {k: _display(v) for k, v in compare["outs"].items()}
    x, y, w, h = crop_box(compare["gt"], compare["outs"])
    errs = {k: np.abs(o - gt).mean(axis=2)[y:y + h, x:x + w] for k, o in outs.items()}
    vmax = max([float(np.percentile(e, 99.5)) for e in errs.values()] + [1e-3])
    vmax = float(np.ceil(vmax * 100) / 100)  # a round shared scale
    cmap = plt.get_cmap("magma")
    os.makedirs(os.path.join(out_dir, "crops"), exist_ok=True)

    def save(rel, img, **kw):
        plt.imsave(os.path.join(out_dir, rel), img, **kw)
        files.append(rel)

    def zoom(a):
        return np.repeat(np.repeat(a, ZOOM, 0), ZOOM, 1)

    # the whole frame with the crop outlined, 1:1
    full = gt.copy()
    full[y, x:x + w] = full[y + h - 1, x:x + w] = (1.0, 0.1, 0.1)
    full[y:y + h, x] = full[y:y + h, x + w - 1] = (1.0, 0.1, 0.1)
    save("crops/frame.png", full)
    cells = [("ground truth", "gt", gt[y:y + h, x:x + w], None, None)]
    for k, o in outs.items():
        cells.append((k, _safe(k), o[y:y + h, x:x + w], errs[k], compare["psnr"][k]))
    page = {"frame": compare["frame"], "box": (x, y, w, h), "vmax": vmax, "zoom": ZOOM,
            "cells": []}
    for label, key, img, err, psnr in cells:
        c = {"label": label, "psnr": psnr, "crop": f"crops/{key}.png",
             "zoomed": f"crops/{key}_x{ZOOM}.png"}
        save(c["crop"], img)
        save(c["zoomed"], zoom(img))
        if err is not None:
            c["error"] = f"crops/{key}_error_x{ZOOM}.png"
            save(c["error"], zoom(err), cmap=cmap, vmin=0.0, vmax=vmax)
        page["cells"].append(c)
    # the shared colour bar
    fig, ax = plt.subplots(figsize=(6, 0.9))
    fig.colorbar(plt.cm.ScalarMappable(norm=plt.Normalize(0, vmax), cmap=cmap), cax=ax,
                 orientation="horizontal",
                 label="|error|, display-referred (sRGB of clip(x, 0, 1)), same scale for all")
    fig.tight_layout()
    fig.savefig(os.path.join(out_dir, "colorbar.png"), dpi=100)
    plt.close(fig)
    files.append("colorbar.png")
    # the combined figure (a paper's): rows = ground truth + pipelines; crop, error
    n = len(cells)
    fig, axes = plt.subplots(2, n, figsize=(1.9 * n, 4.4), squeeze=False)
    for j, (label, _, img, err, psnr) in enumerate(cells):
        axes[0, j].imshow(img, interpolation="nearest")
        axes[0, j].set_title(label + ("" if psnr is None else f"\n{psnr:.2f} dB"), fontsize=7)
        if err is not None:
            im = axes[1, j].imshow(err, cmap=cmap, vmin=0, vmax=vmax, interpolation="nearest")
        for r in (0, 1):
            axes[r, j].axis("off")
    fig.colorbar(im, ax=axes[1, :].tolist(), orientation="horizontal", fraction=0.08,
                 pad=0.04, label="|error| (shared scale)")
    fig.suptitle(f"frame {compare['frame']}, region x={x} y={y} {w}x{h}", fontsize=8)
    fig.savefig(os.path.join(out_dir, "crops.png"), dpi=110)
    plt.close(fig)
    files.append("crops.png")
    return page


# ----------------------------------------------------------------------------- text


COLUMNS = [("psnr", "PSNR dB", "{:.2f}"), ("ssim", "SSIM", "{:.4f}"),
           ("flip", "LDR-FLIP", "{:.4f}"), ("flip_hdr", "HDR-FLIP", "{:.4f}"),
           ("psnr_disoccluded", "PSNR disocc", "{:.2f}"),
           ("psnr_moving", "PSNR moving", "{:.2f}")]


def _fmt(v, f):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    return f.format(v)


def _ms(r) -> str:
    sp = r.get("ms_per_frame_spread")
    s = f"{r['ms_per_frame']:.1f}"
    return s + (f" ({sp[0]:.1f}-{sp[1]:.1f})" if sp else "")


def table_rows(result) -> tuple[list[str], list[list[str]]]:
    head = ["pipeline"] + [c[1] for c in COLUMNS] + ["ms/frame"]
    rows = []
    for name, r in result["pipelines"].items():
        rows.append([name] + [_fmt(r.get(k), f) for k, _, f in COLUMNS] + [_ms(r)])
    return head, rows


def _timing_note(result) -> str:
    n = result.get("repeats", 1)
    if n > 1:
        return (f"ms/frame: median over frames of each run, median of {n} runs (min-max of "
                f"the runs in brackets); warm-up excluded.")
    return "ms/frame: median over frames of one run (--repeat N gives the spread over runs)."


def _markdown(result, page, figs) -> str:
    head, rows = table_rows(result)
    lines = [f"# fgen eval: {result.get('sequence', '')} ({result['mode']})", "",
             f"{result['frames']} ground-truth frames; color: {result['display']}; "
             f"backend: {result.get('backend')}.", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    lines += ["", _timing_note(result), ""]
    for title, f in figs:
        lines += [f"## {title}", "", f"![{title}]({f})", ""]
    if page:
        x, y, w, h = page["box"]
        lines += [f"Crops: frame {page['frame']} (the lowest mean PSNR over the pipelines), "
                  f"region x={x} y={y} {w}x{h}; 1:1 and x{page['zoom']} PNGs in crops/, "
                  f"error on one scale 0-{page['vmax']:g} (colorbar.png).", ""]
    return "\n".join(lines)


def _img(out_dir, rel, alt, cls="") -> str:
    with open(os.path.join(out_dir, rel), "rb") as fh:
        b64 = base64.b64encode(fh.read()).decode("ascii")
    c = f' class="{cls}"' if cls else ""
    return f'<img{c} alt="{html.escape(alt)}" src="data:image/png;base64,{b64}">'


CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:24px;
color:#1d1d1f;background:#fff;max-width:1200px}
h1{font-size:22px;margin:0 0 4px}h2{font-size:17px;margin:28px 0 8px}
p.meta{color:#555;margin:2px 0 10px;font-size:13px}
table{border-collapse:collapse;font-size:13px}th,td{padding:4px 10px;border-bottom:1px solid #ddd;
text-align:right}th:first-child,td:first-child{text-align:left}th{background:#f4f4f6}
td.best{font-weight:700}
figure{margin:8px 0 18px}figure img{max-width:100%;border:1px solid #eee}
figcaption{font-size:12px;color:#555}
.crops{display:grid;gap:10px 14px;align-items:start}
.cell{font-size:12px}.cell .lab{font-weight:600;margin-bottom:3px}
img.px{image-rendering:pixelated;image-rendering:crisp-edges;display:block;margin:2px 0;
border:1px solid #ccc}
"""

LOADED_JS = """
window.addEventListener('load',function(){var im=document.images,ok=0;
for(var i=0;i<im.length;i++){if(im[i].complete&&im[i].naturalWidth>0)ok++;}
document.body.setAttribute('data-images',im.length);
document.body.setAttribute('data-images-shown',ok);});
"""


def _html(result, page, figs, out_dir) -> str:
    head, rows = table_rows(result)
    # the best value of each score column in bold
    best = {}
    for j, (k, _, _) in enumerate(COLUMNS, start=1):
        vals = [(r.get(k), i) for i, r in enumerate(result["pipelines"].values())
                if isinstance(r.get(k), (int, float)) and math.isfinite(r.get(k))]
        if vals:
            pick = min if k.startswith("flip") else max
            best[j] = pick(vals)[1]
    trs = ["<tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>"]
    for i, r in enumerate(rows):
        tds = "".join(f'<td{" class=best" if best.get(j) == i else ""}>{html.escape(v)}</td>'
                      for j, v in enumerate(r))
        trs.append(f"<tr>{tds}</tr>")
    parts = ["<!doctype html><html lang=en><head><meta charset=utf-8>",
             f"<title>fgen eval: {html.escape(str(result.get('sequence', '')))}</title>",
             f"<style>{CSS}</style><script>{LOADED_JS}</script></head><body>",
             f"<h1>fgen eval: {html.escape(str(result.get('sequence', '')))} "
             f"({html.escape(result['mode'])})</h1>",
             f"<p class=meta>{result['frames']} ground-truth frames; color: "
             f"{html.escape(result['display'])}; backend: "
             f"{html.escape(str(result.get('backend')))}</p>",
             "<h2>Scores</h2><table>" + "".join(trs) + "</table>",
             f"<p class=meta>{html.escape(_timing_note(result))} Best score of each column "
             f"in bold.</p>"]
    for title, f in figs:
        parts.append(f"<h2>{html.escape(title)}</h2><figure>{_img(out_dir, f, title)}"
                     f"<figcaption>{html.escape(f)}</figcaption></figure>")
    if page:
        x, y, w, h = page["box"]
        z = page["zoom"]
        parts.append(f"<h2>Same region, every pipeline</h2><p class=meta>Frame "
                     f"{page['frame']} (the lowest mean PSNR over the pipelines), region "
                     f"x={x} y={y} {w}x{h}, outlined below. One row per image: the crop at "
                     f"1:1, zoomed x{z} (nearest), and |error| zoomed x{z} on one shared "
                     f"scale (colour bar below).</p>")
        parts.append(f"<figure>{_img(out_dir, 'crops/frame.png', 'the frame', 'px')}"
                     f"<figcaption>ground truth, frame {page['frame']}, 1:1</figcaption>"
                     f"</figure>")
        cells = ["<div class=lab>image</div><div class=lab>1:1</div>"
                 f"<div class=lab>x{z}</div><div class=lab>|error| x{z}</div>"]
        for c in page["cells"]:
            lab = html.escape(c["label"]) + ("" if c["psnr"] is None
                                             else f"<br>{c['psnr']:.2f} dB")
            err = (_img(out_dir, c["error"], f"{c['label']} error", "px") if "error" in c
                   else "<div class=meta>(reference)</div>")
            cells.append(f"<div class='cell lab'>{lab}</div>"
                         f"<div>{_img(out_dir, c['crop'], c['label'] + ' 1:1', 'px')}</div>"
                         f"<div>{_img(out_dir, c['zoomed'], c['label'] + ' zoomed', 'px')}"
                         f"</div><div>{err}</div>")
        parts.append('<div class=crops style="grid-template-columns:10em repeat(3,'
                     'max-content)">' + "".join(cells) + "</div>")
        parts.append(f"<figure>{_img(out_dir, 'colorbar.png', 'colour bar')}<figcaption>"
                     f"error scale 0-{page['vmax']:g}, shared by every pipeline</figcaption>"
                     f"</figure>")
    parts.append("</body></html>")
    return "\n".join(parts)


# ----------------------------------------------------------------------------- entry


def write_report(result: dict, worst: dict, out_dir: str, compare: dict | None = None
                 ) -> list[str]:
    """Write the report (module doc) into out_dir; the paths written. worst: the per
    pipeline worst frames (unused when `compare`, the hardest frame of all, is given)."""
    import matplotlib

    matplotlib.use("Agg")

    check_report_dir(out_dir)
    clear_previous(out_dir)
    files: list[str] = []
    names = list(result["pipelines"])
    colors = _colors(names)
    figs = []
    for title, rel, fn in (("Quality vs time", "quality_vs_time.png",
                            lambda p: _fig_quality(result, colors, p)),
                           ("PSNR per frame", "per_frame_psnr.png",
                            lambda p: _fig_per_frame(result, colors, p)),
                           ("Time per stage", "stage_times.png",
                            lambda p: _fig_stages(result, p))):
        fn(os.path.join(out_dir, rel))
        files.append(rel)
        figs.append((title, rel))
    if compare is None and worst:  # no shared frame kept: the first pipeline's worst
        k = next(iter(worst))
        w = worst[k]
        compare = {"frame": w["frame"], "gt": w["gt"], "outs": {k: w["out"]},
                   "psnr": {k: w["psnr"]}}
    page = _fig_crops(compare, out_dir, files) if compare else None
    if page:
        figs_md = figs + [("Same region, every pipeline", "crops.png")]
    else:
        figs_md = figs
    with open(os.path.join(out_dir, "summary.md"), "w") as fh:
        fh.write(_markdown(result, page, figs_md))
    files.append("summary.md")
    with open(os.path.join(out_dir, "index.html"), "w") as fh:
        fh.write(_html(result, page, figs, out_dir))
    files.append("index.html")
    with open(os.path.join(out_dir, MANIFEST), "w") as fh:
        json.dump({"files": files}, fh, indent=1)
    return [os.path.join(out_dir, f) for f in files]
