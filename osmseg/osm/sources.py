"""``--osm SPEC`` to an OSM source.

=========================================  ===============================================
SPEC                                       source
=========================================  ===============================================
``api``                                    OSM API 0.6 ``map`` call (:mod:`osmseg.osm.api`)
``api:URL``                                another API 0.6 root, e.g. the dev server
``overpass``                               overpass-api.de (:mod:`osmseg.osm.overpass`)
``overpass:URL``                           another Overpass interpreter endpoint
``PATH.osm.pbf`` / ``.pbf`` / ``.osm`` /   a local file read with osmium
``.osm.bz2`` / ``.osm.gz`` / ``.xml``      (:mod:`osmseg.osm.localfile`)
``geojson:PATH[:key=value[,key=value]]``   GeoJSON features with these tags, default
                                           ``building=yes`` (:mod:`osmseg.osm.geojson`)
=========================================  ===============================================

>>> parse_spec("overpass:https://overpass.kumi.systems/api/interpreter")
('overpass', 'https://overpass.kumi.systems/api/interpreter', {})
>>> parse_spec("geojson:data/footprints.geojson:building=yes")
('geojson', 'data/footprints.geojson', {'building': 'yes'})
>>> parse_spec("berlin-latest.osm.pbf")
('file', 'berlin-latest.osm.pbf', {})
"""

from __future__ import annotations

import re
from pathlib import Path

from osmseg.classes import ClassTable
from osmseg.errors import ConfigError
from osmseg.net.http import HttpClient
from osmseg.osm.api import DEFAULT_API_URL, OsmApiSource
from osmseg.osm.base import OsmSource
from osmseg.osm.geojson import GeoJsonSource, parse_tags
from osmseg.osm.localfile import OSM_SUFFIXES, LocalFileSource, is_osm_path
from osmseg.osm.overpass import DEFAULT_OVERPASS_URL, OverpassSource

#: Tags given to GeoJSON features when the spec names none.
DEFAULT_GEOJSON_TAGS = {"building": "yes"}
_TAGS = re.compile(r"^[^=/\\:,]+=[^/\\:,]+(,[^=/\\:,]+=[^/\\:,]+)*$")
_USAGE = ("'api', 'overpass', 'overpass:URL', an .osm/.osm.pbf/.osm.bz2 path, "
          "or 'geojson:PATH[:key=value]'")


def parse_spec(spec: str) -> tuple[str, str, dict[str, str]]:
    """``(kind, target, tags)`` for a ``--osm`` value; ConfigError for anything else.

    kind is "api", "overpass", "file" or "geojson"; target is the URL or path.

    >>> parse_spec("api")
    ('api', 'https://api.openstreetmap.org/api/0.6', {})
    >>> parse_spec("geojson:x.geojson")
    ('geojson', 'x.geojson', {'building': 'yes'})
    """
    text = spec.strip()
    kind, sep, rest = text.partition(":")
    if text == "api" or (kind == "api" and sep and rest.startswith(("http://", "https://"))):
        return "api", rest or DEFAULT_API_URL, {}
    if text == "overpass" or (kind == "overpass" and sep and rest.startswith(("http://", "https://"))):
        return "overpass", rest or DEFAULT_OVERPASS_URL, {}
    if kind == "geojson" and sep and rest:
        path, colon, tail = rest.rpartition(":")
        if colon and _TAGS.match(tail):
            return "geojson", path, parse_tags(tail)
        if colon and path and not Path(rest).expanduser().exists() and Path(path).expanduser().exists():
            raise ConfigError(f"--osm {spec}: {tail!r} is not key=value tags; write e.g. "
                              f"geojson:{path}:building=yes (several: key=value,key=value)")
        return "geojson", rest, dict(DEFAULT_GEOJSON_TAGS)
    if is_osm_path(text):
        return "file", text, {}
    raise ConfigError(f"--osm {spec}: unknown OSM source; give {_USAGE}")


def make_osm_source(spec: str, client: HttpClient, workdir: Path, table: ClassTable) -> OsmSource:
    """The OSM source a ``--osm`` value names, keeping its downloads/extracts in ``workdir``.

    ``table`` decides what the Overpass query asks for.  Local paths must exist.
    """
    kind, target, tags = parse_spec(spec)
    workdir = Path(workdir)
    if kind == "api":
        return OsmApiSource(client, workdir, base_url=target)
    if kind == "overpass":
        return OverpassSource(client, workdir, table=table, url=target)
    if kind == "geojson":
        if all(table.classify(tags, kind) is None for kind in ("area", "line", "point")):
            # every feature would be read and none drawn: an all-unlabeled mask, said up front
            given = ",".join(f"{k}={v}" for k, v in sorted(tags.items()))
            raise ConfigError(f"--osm geojson:{target}:{given}: no class of {table.name} has a rule for these tags, "
                              "so nothing would be drawn; give tags a class uses, e.g. :building=yes or "
                              ":landuse=grass")
        return GeoJsonSource(Path(target).expanduser(), workdir, tags)
    path = Path(target).expanduser()
    if not path.is_file():
        raise ConfigError(f"--osm {target}: file not found; give an .osm/.osm.pbf path, 'api' or 'overpass'")
    return LocalFileSource(path, workdir)


__all__ = ["DEFAULT_GEOJSON_TAGS", "OSM_SUFFIXES", "make_osm_source", "parse_spec"]
