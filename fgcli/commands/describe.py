import click


@click.command("describe")
@click.argument("name")
@click.option("--set", "sets", multiple=True, metavar="STAGE.OPTION=VALUE",
              help="Show the pipeline with these overrides applied.")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
def cmd(name, sets, as_json):
    """Print a pipeline's stages (with resolved options) or a stage's option table.

    NAME is a pipeline (mob-fgsr, a variant like mob-fgsr:motion=linear, or a .toml path)
    or a stage name (splat, warp, ...).
    """
    import json

    from fgcli import pipeline as pl
    from fgcli.errors import UsageError
    from fgcli.stages.base import load_all

    reg = load_all()
    base = name.partition(":")[0]
    if base in pl.available() or base.endswith(".toml"):
        p = pl.load(name)
        if sets:
            p = p.with_overrides(list(sets), label=p.label, origin="--set")
        d = pl.describe(p)
        if as_json:
            click.echo(json.dumps(d, indent=1))
            return
        click.echo(f"{d['name']}  modes: {', '.join(d['modes'])}  ({d['file']})")
        if d["description"]:
            click.echo(f"  {d['description']}")
        for i, s in enumerate(d["stages"], 1):
            state = "" if s["enabled"] else "  [off]"
            click.echo(f"  {i}. {s['id']} ({s['use']}) modes={','.join(s['modes'])}{state}")
            for k, v in s["options"].items():
                click.echo(f"       {k} = {v!r}")
        for mode, rows in d.get("flow", {}).items():
            click.echo(f"  data flow ({mode}):")
            for r in rows:
                ins = ", ".join(f"{k} <- {src}" for k, src in r["inputs"])
                click.echo(f"    {r['id']}: {ins} -> {', '.join(r['outputs'])}")
        return
    if name in reg:
        cls = reg[name]
        if as_json:
            click.echo(json.dumps({"name": cls.name, "help": cls.help, "inputs": list(cls.inputs),
                                   "optional_inputs": list(cls.optional_inputs),
                                   "outputs": list(cls.outputs),
                                   "options": [{"name": o.name, "type": o.type, "default": o.default,
                                                "range": o.range, "choices": o.choices,
                                                "help": o.help} for o in cls.options]}, indent=1))
            return
        click.echo(f"stage {cls.name}: {cls.help}")
        click.echo(f"  inputs : {', '.join(cls.inputs)}"
                   + (f" (optional: {', '.join(cls.optional_inputs)})" if cls.optional_inputs else ""))
        click.echo(f"  outputs: {', '.join(cls.outputs)}")
        click.echo("  options:" if cls.options else "  options: none")
        for o in cls.options:
            click.echo(f"    {o.describe()}")
        return
    raise UsageError(f"'{name}' is neither a pipeline ({', '.join(pl.available())}) nor a stage "
                     f"({', '.join(sorted(reg))})")
