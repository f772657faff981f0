"""fgen train: render training data from random scenes and train a network."""
from __future__ import annotations

import os

import click

from fgcli.errors import UsageError

NETWORKS = ("mv-interp",)


def _widths(ctx, param, value):
    if value is None:
        return None
    try:
        w = tuple(int(x) for x in value.split(","))
    except ValueError:
        raise click.BadParameter("four integers, e.g. 16,24,32,48") from None
    if len(w) != 4 or min(w) < 4:
        raise click.BadParameter("four integers >= 4, e.g. 16,24,32,48")
    return w


@click.command("train")
@click.argument("network", type=click.Choice(NETWORKS))
@click.option("--data", "data_dir", type=click.Path(file_okay=False), required=True,
              help="Training data folder: train/ and val/ samples are rendered here from "
                   "random scenes (fgen synth --random) where missing.")
@click.option("--run", "run_dir", type=click.Path(file_okay=False), required=True,
              help="Run folder: checkpoints (last.pt, best.pt), loss.csv, val.csv. An "
                   "existing run continues from its last checkpoint.")
@click.option("--scenes", type=click.IntRange(min=1), default=800, show_default=True,
              help="Random training scenes (seeds 0 .. N-1), one sample each.")
@click.option("--val-scenes", type=click.IntRange(min=1), default=64, show_default=True,
              help="Held-out random scenes (seeds from 1,000,000).")
@click.option("--steps", type=click.IntRange(min=1), default=8000, show_default=True,
              help="Optimiser steps in all (a continued run counts the steps it has done).")
@click.option("--lr", type=click.FloatRange(min=0, min_open=True), default=1e-3,
              show_default=True, help="Learning rate (Adam).")
@click.option("--batch", type=click.IntRange(min=1), default=8, show_default=True,
              help="Samples per step.")
@click.option("--patch", type=click.IntRange(min=32), default=128, show_default=True,
              help="Side of the square training crops, in pixels.")
@click.option("--widths", callback=_widths, help="Encoder widths per level "
              "(default 16,24,32,48).")
@click.option("--no-guides", is_flag=True, help="Train without guiding flows (zero guides "
              "and cue channels): the plain IFRNet-style ablation of the paper; run it with "
              "--variant mv-interp:guide=off,weights=<exported name>.")
@click.option("--name", default="mv-interp", show_default=True,
              help="File name of the exported weights (fgcli/nets/weights/<name>.onnx/.pt).")
@click.option("--light-scenes", type=click.IntRange(min=0), default=0, show_default=True,
              help="Also render and train on this many shading-only random scenes (static "
                   "geometry and camera, moving lights; seeds from 2,000,000).")
@click.option("--hole-weight", type=click.FloatRange(min=0), default=0.0, show_default=True,
              help="Extra Charbonnier weight on guide-hole pixels (the splat left them "
                   "empty: the network alone chooses the frame there); 0 = plain mean.")
@click.option("--occlusion-weight", type=click.FloatRange(min=0), default=0.0,
              show_default=True,
              help="Extra Charbonnier weight where the two guided samples are different "
                   "surfaces (depths differ by 22 % or more: one is an occluder and the "
                   "merge mask alone picks the frame); 0 = plain mean.")
@click.option("--init", type=click.Path(dir_okay=False, exists=True),
              help="Start a new run from this checkpoint's weights (fine-tuning).")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Random seed of the crops, batches and initial weights.")
@click.option("--threads", type=click.IntRange(min=1), help="CPU threads (default: all).")
@click.option("--export", "export_dir", type=click.Path(file_okay=False),
              help="After training, export best.pt (ONNX + state dict) into this folder "
                   "(the shipped weights live in fgcli/nets/weights/).")
@click.option("--no-progress", is_flag=True, help="No progress bars.")
def cmd(network, data_dir, run_dir, scenes, val_scenes, steps, lr, batch, patch, widths,
        no_guides, name, light_scenes, hole_weight, occlusion_weight, init, seed, threads,
        export_dir, no_progress):
    """Train NETWORK on data rendered from random scenes (never the evaluation scenes).

    \b
    fgen train mv-interp --data work/mvi --run work/run1 --steps 8000
    fgen train mv-interp --data work/mvi --run work/run1 --steps 8000   # continues
    fgen train mv-interp --data work/mvi --run work/run1 --steps 8000 --export fgcli/nets/weights

    Recipe and wall times: docs/training.md.
    """
    import torch

    from fgcli.nets.data import HELDOUT_SEEDS, make_samples
    from fgcli.nets.train import train

    if threads:
        torch.set_num_threads(threads)
    if os.path.abspath(run_dir) == os.path.abspath(data_dir):
        raise UsageError("--run and --data need different folders")
    tr, va = os.path.join(data_dir, "train"), os.path.join(data_dir, "val")
    make_samples(va, range(HELDOUT_SEEDS[0], HELDOUT_SEEDS[0] + val_scenes),
                 progress=not no_progress)
    make_samples(tr, range(scenes), progress=not no_progress)
    extra = []
    if light_scenes:
        from fgcli.nets.data import LIGHT_SEEDS

        extra.append(os.path.join(data_dir, "train_light"))
        make_samples(extra[0], range(LIGHT_SEEDS[0], LIGHT_SEEDS[0] + light_scenes),
                     progress=not no_progress)
    from fgcli.nets.mvinterp_train import MVInterpTask

    task = MVInterpTask(tr, va, widths=widths, patch=patch, batch=batch, limit=scenes,
                        val_limit=val_scenes, seed=seed, guides=not no_guides,
                        extra_dirs=extra, hole_weight=hole_weight,
                        occlusion_weight=occlusion_weight)
    res = train(task, run_dir, steps, lr=lr, seed=seed, progress=not no_progress,
                log=lambda m: click.echo(m, err=True), init=init)
    click.echo(f"trained {res['steps']} steps in {res['seconds']:.0f} s; best validation "
               f"PSNR {res['best']:.3f} dB")
    if export_dir:
        from fgcli.nets.export import export_mvinterp

        info = export_mvinterp(os.path.join(run_dir, "best.pt"), export_dir, name=name)
        click.echo(f"exported step {info['step']} to {info['onnx']} "
                   f"({info['onnx_bytes'] / 1e6:.1f} MB) and {info['pt']}")
