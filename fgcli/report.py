"""PNG plots for `fgen eval --report`: quality vs time, per-stage time bars, worst crops."""
from __future__ import annotations

import os


def _display(x):
    import numpy as np

    from fgcli.ops.color import srgb_oetf

    return np.clip(srgb_oetf(x.float()).permute(1, 2, 0).numpy(), 0, 1)


def write_report(result: dict, worst: dict, out_dir: str) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    os.makedirs(out_dir, exist_ok=True)
    files = []
    pipes = result["pipelines"]
    # 1. quality vs time
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for name, r in pipes.items():
        for ax, key, lab in ((axes[0], "psnr", "PSNR (dB, higher is better)"),
                             (axes[1], "flip", "LDR-FLIP (lower is better)")):
            ax.scatter([r["ms_per_frame"]], [r[key]])
            ax.annotate(name, (r["ms_per_frame"], r[key]), fontsize=7)
            ax.set_xlabel("ms per generated frame")
            ax.set_ylabel(lab)
    fig.suptitle(f"quality vs time ({result['mode']}, {result['frames']} frames)")
    fig.tight_layout()
    p = os.path.join(out_dir, "quality_vs_time.png")
    fig.savefig(p, dpi=100)
    plt.close(fig)
    files.append(p)
    # 2. per-stage time bars (stacked)
    fig, ax = plt.subplots(figsize=(10, 0.5 + 0.45 * len(pipes)))
    for i, (name, r) in enumerate(pipes.items()):
        left = 0.0
        for sid, ms in r["stages"].items():
            ax.barh(i, ms, left=left)
            if ms > 0.5:
                ax.text(left + ms / 2, i, sid, ha="center", va="center", fontsize=6)
            left += ms
    ax.set_yticks(range(len(pipes)))
    ax.set_yticklabels(list(pipes))
    ax.set_xlabel("median ms per generated frame, by stage")
    fig.tight_layout()
    p = os.path.join(out_dir, "stage_times.png")
    fig.savefig(p, dpi=100)
    plt.close(fig)
    files.append(p)
    # 3. worst frame per pipeline: output next to ground truth, with an error crop
    for name, w in worst.items():
        out, gt = _display(w["out"]), _display(w["gt"])
        err = np.abs(out - gt).mean(axis=2)
        H, W = err.shape
        ch, cw = max(1, H // 2), max(1, W // 2)
        # crop around the largest error
        s = np.cumsum(np.cumsum(np.pad(err, ((1, 0), (1, 0))), 0), 1)
        box = s[ch:, cw:] - s[:-ch, cw:] - s[ch:, :-cw] + s[:-ch, :-cw]
        y, x = np.unravel_index(np.argmax(box), box.shape)
        fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
        for ax, im, t in ((axes[0], out[y:y + ch, x:x + cw], f"{name} frame {w['frame']}"),
                          (axes[1], gt[y:y + ch, x:x + cw], "ground truth"),
                          (axes[2], err[y:y + ch, x:x + cw], f"|error| (PSNR {w['psnr']:.2f} dB)")):
            ax.imshow(im, interpolation="nearest")
            ax.set_title(t, fontsize=8)
            ax.axis("off")
        fig.tight_layout()
        safe = "".join(c if c.isalnum() or c in "-_" else "_" for c in name)
        p = os.path.join(out_dir, f"worst_{safe}.png")
        fig.savefig(p, dpi=100)
        plt.close(fig)
        files.append(p)
    return files
