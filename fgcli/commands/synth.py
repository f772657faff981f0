"""fgen synth: render a procedural scene into an input sequence (and its ground truth)."""
from __future__ import annotations

import os

import click

from fgcli.errors import InputError, UsageError


def _size(ctx, param, value):
    if value is None:
        return None
    from fgcli.synth.scene import parse_size

    try:
        return parse_size(value)
    except UsageError as e:
        raise click.BadParameter(e.message) from None


def _scene_files(paths) -> list[str]:
    """Scene files from the arguments: files as given, folders as their *.toml (sorted)."""
    out = []
    for p in paths:
        if os.path.isdir(p):
            found = sorted(os.path.join(p, f) for f in os.listdir(p) if f.endswith(".toml"))
            if not found:
                raise InputError("no scene files (*.toml) in folder", file=p)
            out += found
        else:
            out.append(p)
    return out


@click.command("synth")
@click.argument("paths", nargs=-1, required=True, metavar="SCENE.toml OUT/")
@click.option("--size", callback=_size, metavar="WxH", help="Override the scene's resolution.")
@click.option("--frames", type=click.IntRange(min=1), help="Number of input frames.")
@click.option("--fps", type=click.FloatRange(min=0, min_open=True),
              help="Input frame rate (scene motion is in seconds, so this sets motion per frame).")
@click.option("--gt", "gt_dir", type=click.Path(file_okay=False),
              help="Also render the ground-truth frames between (and after) input frames here.")
@click.option("--gt-factor", type=click.IntRange(min=2), default=2, show_default=True,
              help="Fine-rate frames per input interval (input numbered 0, K, 2K, ...).")
@click.option("--spp", type=click.IntRange(1, 16),
              help="Supersamples per pixel axis (default: the scene's, 3 if unset).")
@click.option("--overwrite", is_flag=True, help="Write into non-empty output folders.")
@click.option("--preview", "preview", type=click.Path(dir_okay=False),
              help="Write a PNG contact sheet of the given scenes (files or folders of "
                   "*.toml) instead of rendering sequences.")
@click.option("--random", "random_seed", type=click.IntRange(min=0), metavar="SEED",
              help="Render the random scene SEED (random objects, textures, motions, camera "
                   "path, lights; what `fgen train` renders its data from) instead of a scene "
                   "file: `fgen synth --random 7 OUT/`. Default size 256x144.")
@click.option("--jitter", is_flag=True,
              help="Add the `jitter` effect: the input is a low-resolution render (the "
                   "scene's jitter_scale, default 0.5) with a Halton sub-pixel jitter per "
                   "frame (fgen:jitter_x/y), and the ground truth also holds the "
                   "full-resolution frame at every input time (super-resolution data).")
@click.option("--gbuffer-only", type=click.Choice(["none", "odd"]), default="none",
              show_default=True,
              help="odd: write every odd input frame without colour (depth, vectors, normals, "
                   "albedo only), as an engine that shades every other frame writes them.")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
def cmd(paths, size, frames, fps, gt_dir, gt_factor, spp, overwrite, preview, random_seed,
        jitter, gbuffer_only, no_progress):
    """Render procedural scene SCENE.toml into OUT/ (fgen layout + cameras.json).

    Frame numbers live on one timeline at the finer rate: with --gt and --gt-factor K the
    input frames are 0, K, 2K, ... (motion vectors spanning one input interval) and the
    ground truth holds the K-1 frames between them and after the last one, so
    `fgen eval OUT --gt GT` pairs them.

    \b
    fgen synth sample_data/scenes/orbit.toml out/orbit --gt out/orbit_gt
    fgen synth --preview sheet.png sample_data/scenes/
    fgen synth --random 7 out/random7 --gt out/random7_gt
    """
    from fgcli.synth import load_scene

    if preview:
        from fgcli.synth.preview import write_contact_sheet

        files = _scene_files(paths)
        scenes = [load_scene(f, size=size, fps=fps, frames=frames) for f in files]
        w, h = write_contact_sheet(scenes, preview, spp=spp)
        click.echo(f"wrote {preview} ({w}x{h}, {len(scenes)} scene(s))")
        return
    if random_seed is not None:
        if len(paths) != 1:
            raise UsageError("with --random give only OUT/")
        from fgcli.synth import random_scene

        out = paths[0]
        scene = load_scene(random_scene(random_seed, size=size or (256, 144)), fps=fps,
                           frames=frames, add_effects=("jitter",) if jitter else ())
    else:
        if len(paths) != 2:
            raise UsageError("expected SCENE.toml and OUT/ (or --preview PNG with scene files)")
        scene_path, out = paths
        if os.path.isdir(scene_path):
            raise InputError("expected a scene file, got a folder", file=scene_path)
        scene = load_scene(scene_path, size=size, fps=fps, frames=frames,
                           add_effects=("jitter",) if jitter else ())
    from fgcli.synth.sequence import render_sequence

    res = render_sequence(scene, out, gt_dir=gt_dir, gt_factor=gt_factor,
                          progress=not no_progress, overwrite=overwrite, spp=spp,
                          gbuffer_only=gbuffer_only)
    n = res["input"] + res["gt"]
    msg = f"{scene.name}: {res['input']} input frames -> {out}"
    if gt_dir:
        msg += f", {res['gt']} ground-truth frames -> {gt_dir}"
    click.echo(f"{msg} ({scene.width}x{scene.height}, {res['seconds'] / max(n, 1) * 1000:.0f} "
               "ms/frame)")
