import click


@click.command("pipelines")
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
def cmd(as_json):
    """List the available pipelines (files in pipelines/)."""
    import json

    from fgcli import pipeline as pl

    rows = []
    for name, path in pl.available().items():
        p = pl.load_pipeline_file(path)
        rows.append({"name": name, "modes": list(p.modes), "stages": [s.id for s in p.stages],
                     "description": p.description, "file": path})
    if as_json:
        click.echo(json.dumps(rows, indent=1))
        return
    w = max(len(r["name"]) for r in rows) if rows else 4
    for r in rows:
        click.echo(f"{r['name']:<{w}}  [{'/'.join(r['modes'])}]  {' -> '.join(r['stages'])}")
        if r["description"]:
            click.echo(f"{'':<{w}}  {r['description']}")
