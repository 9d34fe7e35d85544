"""OSM sources: the OSM API, Overpass, local files and GeoJSON all lead to the same masks.

Fixtures: ``tests/data/osm`` (made by its ``data.py``): one made-up OSM content and the
recorded answers of the OSM API and Overpass for it (vcrpy cassettes, replayed offline).
Fault tests talk to a real HTTP server on 127.0.0.1 (``tests/servers.py``).
"""

from __future__ import annotations

import importlib.util
import json
import logging
from dataclasses import replace
from pathlib import Path

import mercantile
import numpy as np
import osmium
import pytest
from conftest import TEST_DATA, shared_path
from servers import Reply, http_server  # noqa: F401  (pytest fixture)

from osmseg.classes import load_class_table
from osmseg.errors import ConfigError, NetworkError, OSMDataError, OSMLimitError, RetriesExhausted
from osmseg.grid import LngLatBBox, pad_bbox, sample_grid
from osmseg.net.http import HttpClient, HttpConfig
from osmseg.osm.api import OsmApiSource
from osmseg.osm.features import read_features
from osmseg.osm.geojson import GeoJsonSource
from osmseg.osm.localfile import LocalFileSource
from osmseg.osm.overpass import OverpassSource
from osmseg.osm.sources import make_osm_source
from osmseg.rasterize import rasterize

DATA = TEST_DATA / "osm"
SCENARIO = json.loads((DATA / "scenario.json").read_text())
TABLE = load_class_table("classes13.toml")
GRID = sample_grid(*SCENARIO["centre"], SCENARIO["zoom"])
BOX = LngLatBBox(*SCENARIO["fetch_bbox"])
IDS = {c.name: c.id for c in TABLE.classes}
FAST = HttpConfig(retries=1, backoff=0.0, timeout=5.0)


def mask(paths, grid=GRID) -> np.ndarray:
    """Class-index mask of OSM files on ``grid``: the project's real parser and rasteriser."""
    return rasterize(read_features(list(paths), grid, TABLE), grid, TABLE)


def write_pbf(src: Path, dst: Path) -> Path:
    """The same OSM content as ``src``, written as .osm.pbf by osmium."""
    with osmium.SimpleWriter(str(dst)) as writer:
        for obj in osmium.FileProcessor(str(src)):
            writer.add(obj)
    return dst


def replay(name: str, make_source, tmp_path: Path):
    """``make_source(client, workdir).fetch(BOX)`` with HTTP answered by cassette ``name``."""
    with HttpClient(replace(FAST, cassette=DATA / name)) as client:
        extract = make_source(client, tmp_path / name.split(".")[0]).fetch(BOX)
        assert client.transport.unplayed() == []  # every recorded answer was asked for
    return extract


# -- the requirement: same content, three ways, identical masks ---------------------------------


def test_same_content_three_ways_gives_identical_masks(tmp_path):
    reference = mask([DATA / "content.osm"])
    api = replay("api_map.yaml", lambda c, w: OsmApiSource(c, w), tmp_path)
    split = replay("api_split.yaml", lambda c, w: OsmApiSource(c, w), tmp_path)
    overpass = replay("overpass.yaml", lambda c, w: OverpassSource(c, w, TABLE), tmp_path)
    local = LocalFileSource(write_pbf(DATA / "content.osm", tmp_path / "content.osm.pbf"), tmp_path / "file").fetch(BOX)

    masks = {name: mask(ex.paths) for name, ex in
             [("api", api), ("api split", split), ("overpass", overpass), ("local pbf", local)]}
    for name, m in masks.items():
        assert np.array_equal(m, reference), f"{name}: {(m != reference).sum()} pixels differ from the content"

    present = set(np.unique(reference).tolist())
    expected = {"building", "highway", "dirt road", "footway", "park", "grass", "parking", "industrial",
                "construction", "water", "tree", "beach"}
    assert {IDS[n] for n in expected} <= present
    # the lake (its outer ring half outside the box: only complete thanks to relation/full)
    # is water around its island, which is a hole
    assert reference[pixel(200, -200)] == 0
    assert reference[pixel(150, -170)] == IDS["water"]
    assert reference[pixel(0, 230)] == IDS["water"]  # sea north of the coastline
    assert reference[pixel(-170, 70)] == 0 and reference[pixel(-195, 95)] == IDS["building"]  # courtyard

    # what each source reports
    assert api.timestamp == "2025-03-14T09:27:31Z" and split.timestamp == api.timestamp
    assert api.info["relations_completed"] == [SCENARIO["lake_relation"]]
    assert api.info["map_calls"] == 1 and split.info["map_calls"] == 10
    assert overpass.timestamp == SCENARIO["osm_base"]
    # no replication time in its header: the time of its newest edited element, not the copy's mtime
    assert local.info["timestamp_from"] == "newest element" and local.timestamp.startswith("20")


def pixel(x_m: float, y_m: float) -> tuple[int, int]:
    """(row, col) of a point given in metres east/north of the content's origin (the grid centre)."""
    b = GRID.bbox
    lat0 = (b.south + b.north) / 2
    lon = (b.west + b.east) / 2 + x_m / (111_320.0 * np.cos(np.radians(lat0)))
    lat = lat0 + y_m / 111_320.0
    return lonlat_pixel(lon, lat)


def lonlat_pixel(lon: float, lat: float, grid=GRID) -> tuple[int, int]:
    """(row, col) of a WGS84 point on ``grid``."""
    col, row = ~grid.transform @ mercantile.xy(lon, lat)
    return int(row), int(col)


def test_rerun_reuses_downloads_without_any_request(tmp_path):
    replay("api_map.yaml", lambda c, w: OsmApiSource(c, w), tmp_path)
    with HttpClient(replace(FAST, cassette=DATA / "api_map.yaml")) as client:
        again = OsmApiSource(client, tmp_path / "api_map").fetch(BOX)
        assert sum(client.transport.plays.values()) == 0
    assert all(p.is_file() for p in again.paths) and again.timestamp == "2025-03-14T09:27:31Z"


# -- faults, against a real server on 127.0.0.1 ------------------------------------------------------------

VALID = ('<?xml version="1.0" encoding="UTF-8"?>\n<osm version="0.6" generator="test">\n'
         ' <node id="1" version="1" timestamp="2020-01-01T00:00:00Z" lat="0.1" lon="0.1"/>\n</osm>\n')
XML = {"Content-Type": "text/xml; charset=utf-8", "Date": "Fri, 14 Mar 2025 09:27:31 GMT"}


def one_line(exc: pytest.ExceptionInfo) -> str:
    text = str(exc.value)
    assert "\n" not in text and "Traceback" not in text
    return text


def test_api_malformed_xml_is_retried_then_a_one_line_error_and_leaves_nothing(tmp_path, http_server):
    http_server.script("/api/0.6/map", Reply(200, '<?xml version="1.0"?>\n<osm version="0.6"><node id="1" lat=', XML))
    with HttpClient(FAST) as client, pytest.raises(RetriesExhausted) as exc:
        OsmApiSource(client, tmp_path, base_url=http_server.url("/api/0.6")).fetch(LngLatBBox(0, 0, 0.01, 0.01))
    assert "OSM API answer to map?bbox=" in one_line(exc) and "not valid OSM data" in str(exc.value)
    assert http_server.count("/api/0.6/map") == FAST.retries + 1  # a broken 200 is retried like a 5xx
    assert not [p for p in tmp_path.rglob("*") if p.is_file()]  # no half file, no done marker


def test_api_malformed_xml_once_is_fetched_again_and_kept(tmp_path, http_server):
    http_server.script("/api/0.6/map", Reply(200, '<?xml version="1.0"?>\n<osm version="0.6"><node id="1" lat=', XML),
                       Reply(200, VALID, XML))
    with HttpClient(FAST) as client:
        extract = OsmApiSource(client, tmp_path, base_url=http_server.url("/api/0.6")).fetch(LngLatBBox(0, 0, 0.01, 0.01))
    assert http_server.count("/api/0.6/map") == 2 and extract.paths[0].read_bytes() == VALID.encode()


def test_api_splits_on_node_limit_and_gives_up_after_depth(tmp_path, http_server):
    limit = "You requested too many nodes (limit is 50000). Either request a smaller area, or use planet.osm"
    http_server.script("/api/0.6/map", Reply(400, limit, {"Content-Type": "text/plain"}))
    with HttpClient(FAST) as client, pytest.raises(OSMLimitError) as exc:
        OsmApiSource(client, tmp_path, base_url=http_server.url("/api/0.6"), max_split_depth=2).fetch(
            LngLatBBox(0, 0, 0.04, 0.04))
    assert "after splitting it 2 times" in one_line(exc) and ".osm.pbf" in str(exc.value)
    boxes = [s.query for s in http_server.requests("/api/0.6/map")]
    assert len(boxes) == 3  # the box, its first quarter, that quarter's first quarter


def test_api_splits_large_areas_before_asking(tmp_path, http_server):
    http_server.script("/api/0.6/map", Reply(200, VALID, XML))
    with HttpClient(FAST) as client:
        extract = OsmApiSource(client, tmp_path, base_url=http_server.url("/api/0.6")).fetch(LngLatBBox(0, 0, 1.2, 1.2))
    sent = [s.query for s in http_server.requests("/api/0.6/map")]
    assert len(sent) == 16 and len(extract.paths) == 16
    for query in sent:
        w, s, e, n = map(float, query.split("=")[1].replace("%2C", ",").split(","))
        assert (e - w) * (n - s) <= 0.25


def test_api_bandwidth_limit_is_a_clear_network_error(tmp_path, http_server):
    http_server.script("/api/0.6/map", Reply(509, "You have downloaded too much data.", {"Content-Type": "text/plain"}))
    with HttpClient(FAST) as client, pytest.raises(NetworkError) as exc:
        OsmApiSource(client, tmp_path, base_url=http_server.url("/api/0.6")).fetch(LngLatBBox(0, 0, 0.01, 0.01))
    assert "509" in one_line(exc) and "wait" in str(exc.value)


def test_api_gone_relation_is_skipped_with_a_warning(tmp_path, http_server, caplog):
    body = VALID.replace("</osm>", ' <way id="5" version="1"><nd ref="1"/></way>\n'
                         ' <relation id="9" version="1"><member type="way" ref="5" role="outer"/>'
                         '<member type="way" ref="6" role="outer"/><tag k="type" v="multipolygon"/></relation>\n</osm>')
    http_server.script("/api/0.6/map", Reply(200, body, XML))
    http_server.script("/api/0.6/relation/9/full", Reply(410, "", {"Content-Type": "text/plain"}))
    with HttpClient(FAST) as client, caplog.at_level(logging.WARNING):
        extract = OsmApiSource(client, tmp_path, base_url=http_server.url("/api/0.6")).fetch(LngLatBBox(0, 0, 0.2, 0.2))
    assert len(extract.paths) == 1 and extract.info["relations_completed"] == []
    assert "relation 9 is gone" in caplog.text


def test_overpass_runtime_error_remark_is_not_taken_as_data(tmp_path, http_server):
    remark = ('<?xml version="1.0" encoding="UTF-8"?>\n<osm version="0.6" generator="Overpass API 0.7.62.5 1bd436f1">\n'
              '<meta osm_base="2025-03-14T09:27:02Z"/>\n\n  <node id="1" lat="0.1" lon="0.1"/>\n'
              '<remark> runtime error: Query timed out in "query" at line 3 after 181 seconds. </remark>\n\n</osm>\n')
    http_server.script("/api/interpreter", Reply(200, remark, {"Content-Type": "application/osm3s+xml"}))
    with HttpClient(FAST) as client, pytest.raises(OSMLimitError) as exc:
        OverpassSource(client, tmp_path, TABLE, url=http_server.url("/api/interpreter")).fetch(BOX)
    assert "Query timed out" in one_line(exc) and "smaller boxes" in str(exc.value)
    assert not list(tmp_path.glob("*"))


def test_overpass_malformed_xml_and_retry_after_429(tmp_path, http_server):
    url = http_server.url("/api/interpreter")
    http_server.script("/api/interpreter", Reply(429, "rate limited", {"Retry-After": "0"}),
                       Reply(200, "<osm><node id='1' lat='0' lon='0'>", {"Content-Type": "application/osm3s+xml"}))
    with HttpClient(FAST) as client, pytest.raises(RetriesExhausted) as exc:
        OverpassSource(client, tmp_path, TABLE, url=url).fetch(BOX)
    assert "Overpass" in one_line(exc) and "not valid OSM data" in str(exc.value)
    assert http_server.count("/api/interpreter") == FAST.retries + 1  # the 429, then the broken 200 again
    sent = http_server.requests("/api/interpreter")[-1]
    assert b"out%3Axml" in sent.body and b"building" in sent.body  # the class-table query


# -- local files ------------------------------------------------------------------------------------------


def test_local_extract_of_real_oakland_xml_matches_reading_the_whole_file(tmp_path):
    oakland = shared_path("oakland-osm", "west-oakland.osm")
    grid = sample_grid(-122.30136, 37.80765, 20)  # a 150 m sample in a 380 m file
    box = pad_bbox(grid.bbox, 20)
    extract = LocalFileSource(oakland, tmp_path / "a").fetch(box)
    whole, part = mask([oakland], grid), mask(extract.paths, grid)
    assert np.array_equal(part, whole)
    assert {IDS["building"], IDS["highway"], IDS["parking"]} <= set(np.unique(whole).tolist())
    assert extract.info["counts"]["w"] < sum(1 for _ in osmium.FileProcessor(str(oakland), osmium.osm.WAY))
    # here roads cross the sample with no node near it: node-in-box alone (reach 0) misses them
    bare = LocalFileSource(oakland, tmp_path / "b", reach=0).fetch(box)
    assert (mask(bare.paths, grid) != whole).sum() > 1000


def test_local_prepare_cuts_helsinki_once_for_three_boxes(tmp_path):
    helsinki = shared_path("helsinki-osm", "helsinki.osm.pbf")
    copy = tmp_path / "helsinki.osm.pbf"
    copy.write_bytes(helsinki.read_bytes())
    grids = [sample_grid(24.944, 60.170, 18), sample_grid(24.9385, 60.1665, 19), sample_grid(24.950, 60.176, 19)]
    boxes = [pad_bbox(g.bbox, 100) for g in grids]
    source = LocalFileSource(copy, tmp_path / "work")
    source.prepare(boxes)
    copy.unlink()  # from now on only the region file can be read: proves one pass over the input
    extracts = [source.fetch(b) for b in boxes]
    with pytest.raises(OSMDataError):  # a box nobody prepared needs the (gone) input file
        source.fetch(pad_bbox(sample_grid(24.9452, 60.1775, 19).bbox, 100))
    direct = LocalFileSource(helsinki, tmp_path / "direct")
    for grid, box, extract in zip(grids, boxes, extracts):
        got = mask(extract.paths, grid)
        assert np.array_equal(got, mask(direct.fetch(box).paths, grid))
        assert len(np.unique(got)) >= 3
    assert np.array_equal(mask(extracts[0].paths, grids[0]), mask([helsinki], grids[0]))


def test_local_extracts_of_broken_tinycity_match_reading_it_whole(tmp_path):
    """tinycity (tests/data/tinycity) has unclosed, self-intersecting and member-less objects."""
    spec = importlib.util.spec_from_file_location("tinycity_data", TEST_DATA / "tinycity" / "data.py")
    tiny = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tiny)
    pbf = write_pbf(TEST_DATA / "tinycity" / "tinycity.osm", tmp_path / "tinycity.osm.pbf")
    source = LocalFileSource(pbf, tmp_path / "work")
    for col, row in [(320, 320), (320, 960), (960, 960)]:  # z19 samples on quarters of the z18 town
        grid = sample_grid(*tiny.lonlat(col, row), tiny.ZOOM + 1)
        extract = source.fetch(pad_bbox(grid.bbox, 60))
        whole = mask([TEST_DATA / "tinycity" / "tinycity.osm"], grid)
        assert np.array_equal(mask(extract.paths, grid), whole)
        assert len(np.unique(whole)) >= 4


def test_local_file_errors_are_one_line(tmp_path):
    with pytest.raises(ConfigError) as exc:
        LocalFileSource(tmp_path / "nope.osm.pbf", tmp_path)
    assert "file not found" in one_line(exc)
    broken = tmp_path / "broken.osm"
    broken.write_text('<?xml version="1.0"?><osm version="0.6"><node id="1" lat="0" lon="0">')
    with pytest.raises(OSMDataError) as exc:
        LocalFileSource(broken, tmp_path / "w").fetch(LngLatBBox(-1, -1, 1, 1))
    assert "broken.osm" in one_line(exc)


def test_an_osm_xml_file_with_changesets_reads_its_map_data(tmp_path):
    """JOSM and the API's changeset downloads put <changeset> elements beside the map data."""
    osm = tmp_path / "with-changeset.osm"
    osm.write_text('<?xml version="1.0"?><osm version="0.6">'
                   '<changeset id="5" created_at="2020-01-01T00:00:00Z" closed_at="2020-01-01T00:00:00Z" open="false"/>'
                   '<node id="1" version="1" timestamp="2021-05-01T00:00:00Z" lat="0.001" lon="0.001"/>'
                   '<node id="2" version="1" timestamp="2021-05-01T00:00:00Z" lat="0.002" lon="0.001"/>'
                   '<node id="3" version="1" timestamp="2021-05-01T00:00:00Z" lat="0.002" lon="0.002"/>'
                   '<way id="7" version="1" timestamp="2021-06-01T00:00:00Z"><nd ref="1"/><nd ref="2"/><nd ref="3"/>'
                   '<nd ref="1"/><tag k="building" v="yes"/></way></osm>')
    grid = sample_grid(0.0015, 0.0015, 18)
    extract = LocalFileSource(osm, tmp_path / "w").fetch(pad_bbox(grid.bbox, 20))
    assert extract.info["counts"] == {"n": 3, "w": 1, "r": 0}
    assert np.array_equal(mask(extract.paths, grid), mask([osm], grid))
    assert (mask([osm], grid) == IDS["building"]).sum() > 1000


# -- GeoJSON -------------------------------------------------------------------------------------------------


def test_geojson_polygons_with_holes_lines_and_points_become_osm(tmp_path):
    lon0, lat0 = GRID.lon, GRID.lat
    d = 0.0008
    ring = [[lon0 - d, lat0 - d], [lon0 + d, lat0 - d], [lon0 + d, lat0 + d], [lon0 - d, lat0 + d], [lon0 - d, lat0 - d]]
    hole = [[lon0 - d / 2, lat0 - d / 2], [lon0 + d / 2, lat0 - d / 2], [lon0 + d / 2, lat0 + d / 2],
            [lon0 - d / 2, lat0 + d / 2], [lon0 - d / 2, lat0 - d / 2]]
    far = [[c[0] + 1, c[1]] for c in ring]
    fc = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [ring, hole]}},
        {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [far]}},
        {"type": "Feature", "properties": {}, "geometry": None},
    ]}
    path = tmp_path / "fc.geojson"
    path.write_text(json.dumps(fc))
    extract = GeoJsonSource(path, tmp_path / "w", {"building": "yes"}).fetch(BOX)
    assert extract.info["features"] == 1  # the far polygon and the empty feature are left out
    m = mask(extract.paths)
    assert m[lonlat_pixel(lon0, lat0)] == 0  # the hole
    assert m[lonlat_pixel(lon0 + 0.75 * d, lat0)] == IDS["building"]
    assert m[lonlat_pixel(lon0 + 1.25 * d, lat0)] == 0


def test_geojson_kampala_footprints_become_buildings(tmp_path):
    geojson = shared_path("kampala-oam", "osm-buildings.geojson")
    grid = sample_grid(32.5925, 0.3498, 19)
    extract = make_osm_source(f"geojson:{geojson}:building=yes", HttpClient(FAST), tmp_path, TABLE).fetch(
        pad_bbox(grid.bbox, 50))
    m = mask(extract.paths, grid)
    assert extract.info["features"] > 20
    assert 0.01 < (m == IDS["building"]).mean() < 0.8


# -- --osm SPEC ------------------------------------------------------------------------------------------------


def test_make_osm_source_specs(tmp_path):
    client = HttpClient(FAST)
    osm = tmp_path / "town.osm"
    osm.write_text((DATA / "content.osm").read_text())
    assert isinstance(make_osm_source("api", client, tmp_path, TABLE), OsmApiSource)
    over = make_osm_source("overpass:https://overpass.example.org/api/interpreter", client, tmp_path, TABLE)
    assert isinstance(over, OverpassSource) and over.url == "https://overpass.example.org/api/interpreter"
    assert isinstance(make_osm_source(str(osm), client, tmp_path, TABLE), LocalFileSource)
    with pytest.raises(ConfigError) as exc:
        make_osm_source(str(tmp_path / "missing.osm.pbf"), client, tmp_path, TABLE)
    assert "file not found; give an .osm/.osm.pbf path, 'api' or 'overpass'" in one_line(exc)
    with pytest.raises(ConfigError) as exc:
        make_osm_source("bing", client, tmp_path, TABLE)
    assert "unknown OSM source" in one_line(exc)


def test_a_josm_file_leaves_out_what_the_user_deleted_and_reads_new_objects(tmp_path, caplog):
    """JOSM keeps deleted objects in the saved file (action="delete") and gives new ones negative ids."""
    grid = sample_grid(24.9405, 60.17025, 18)
    def square(way_id: int, first: int, lon: float, action: str) -> str:
        corners = [(lon, 60.1700), (lon + 0.0004, 60.1700), (lon + 0.0004, 60.1703), (lon, 60.1703)]
        nodes = "".join(f"<node id='{first - i}' action='{action}' visible='true' lat='{la}' lon='{lo}'/>"
                        for i, (lo, la) in enumerate(corners))
        refs = "".join(f"<nd ref='{first - i}'/>" for i in (0, 1, 2, 3, 0))
        return f"{nodes}<way id='{way_id}' action='{action}' visible='true'>{refs}<tag k='building' v='yes'/></way>"
    path = tmp_path / "edit.osm"
    path.write_text("<?xml version='1.0' encoding='UTF-8'?>\n<osm version='0.6' upload='never' generator='JOSM'>"
                    + square(-201, -101, 24.9395, "modify") + square(-202, -111, 24.9410, "delete") + "</osm>")
    with caplog.at_level("WARNING"):
        extract = LocalFileSource(path, tmp_path / "work").fetch(pad_bbox(grid.bbox, 60))
    labels = mask(extract.paths, grid)
    cols = np.flatnonzero((labels == IDS["building"]).any(axis=0))
    west = grid.transform.c + cols.min() * grid.transform.a
    assert cols.size and abs(west - mercantile.xy(24.9395, 60.17)[0]) < 1.0  # the live square, where it is
    east = mercantile.xy(24.9410, 60.17)[0]
    assert grid.transform.c + cols.max() * grid.transform.a < east  # nothing of the deleted one
    assert any("marked deleted" in r.getMessage() and "left out" in r.getMessage() for r in caplog.records)
