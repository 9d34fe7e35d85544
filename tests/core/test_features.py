"""Reading OSM into features: broken data, unreadable files, split downloads, coastline to sea."""

from __future__ import annotations

import doctest
import gzip
import logging
import tempfile
from pathlib import Path

import numpy as np
import osmium
import pytest
import shapely
from test_rasterize import T13, at, centre, load_tinycity

import osmseg.classes
import osmseg.osm.coastline
import osmseg.osm.features
import osmseg.osm.geometry
import osmseg.osm.renumber
from osmseg.classes import load_class_table
from osmseg.errors import OSMDataError
from osmseg.grid import sample_grid
from osmseg.osm.coastline import sea_polygon
from osmseg.osm.features import FeatureSet, read_features
from osmseg.rasterize import rasterize

D = load_tinycity()
WATER = T13.by_name["water"].id


def write_osm(tmp_path: Path, build, name: str = "t.osm") -> Path:
    """An OSM XML file drawn in tinycity pixel coordinates by ``build(writer)``."""
    writer = D.OsmWriter()
    build(writer)
    path = tmp_path / name
    path.write_text(writer.xml(), encoding="utf-8")
    return path


def labels_of(path: Path) -> np.ndarray:
    return rasterize(read_features([path], D.grid(), T13), D.grid(), T13)


# -- broken data ---------------------------------------------------------------------------

def test_broken_geometry_is_repaired_or_skipped_with_warnings(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="osmseg.osm.features"):
        fs = read_features([D.OSM_FILE], D.grid(), T13)
    text = "\n".join(r.getMessage() for r in caplog.records)
    # ids follow data.py's creation order: ways 26-28 and relations 3-4 are the broken ones
    assert "way 26 (building): is tagged as an area but not closed: closed it" in text
    assert "way 27 (grass): is an invalid polygon" in text and "repaired" in text
    assert "way 28 (building): 1 of its 6 nodes are missing from the file" in text
    assert "relation 3 (natural): osmium could not assemble it (1 of its 2 member ways are missing" in text
    assert "relation 4 (grass)" in text and "skipped" in text
    assert list(fs.problems) == [r.getMessage() for r in caplog.records]
    assert all("\n" not in p for p in fs.problems)
    labels = rasterize(fs, D.grid(), T13)
    assert at(labels, centre(D.UNCLOSED_BUILDING)) == "building"
    assert at(labels, centre(D.MISSING_NODE_BUILDING)) == "building"
    assert at(labels, (815, 850)) == at(labels, (885, 850)) == "grass"  # the bow tie's two triangles
    assert at(labels, (850, 815)) == at(labels, (850, 885)) == "unlabeled"  # not its crossing gaps
    assert at(labels, centre(D.FOREST)) == "natural"  # outer ring kept, missing inner ignored
    c0, r0, c1, r1 = 1180, 550, 1270, 650
    assert not (labels[r0:r1, c0:c1] == T13.by_name["grass"].id).any()


def test_way_with_all_nodes_missing_is_skipped(tmp_path: Path) -> None:
    def build(o) -> None:
        o.way([999001, 999002, 999003], {"highway": "residential"})
        o.way(D.rect((100, 100, 200, 200)), {"building": "yes"})
    fs = read_features([write_osm(tmp_path, build)], D.grid(), T13)
    assert [f.osm_id for f in fs] == ["w2"]
    assert fs.unplaced == 1 and fs.problems[-1].startswith("1 highway way has no node with a location in the file")


def test_truncated_xml_is_a_one_line_error(tmp_path: Path) -> None:
    text = D.OSM_FILE.read_text(encoding="utf-8")
    broken = tmp_path / "truncated.osm"
    broken.write_text(text[: len(text) // 2], encoding="utf-8")
    with pytest.raises(OSMDataError) as info:
        read_features([broken], D.grid(), T13)
    message = str(info.value)
    assert "truncated.osm" in message and "download it again" in message and "\n" not in message


def test_unreadable_inputs_are_osm_data_errors(tmp_path: Path) -> None:
    garbage = tmp_path / "garbage.osm.pbf"
    garbage.write_bytes(b"\x00\x01 not a pbf " * 50)
    with pytest.raises(OSMDataError, match="garbage.osm.pbf"):
        read_features([garbage], D.grid(), T13)
    with pytest.raises(OSMDataError, match="does not exist"):
        read_features([tmp_path / "absent.osm"], D.grid(), T13)
    with pytest.raises(OSMDataError, match="no OSM file"):
        read_features([], D.grid(), T13)
    with pytest.raises(OSMDataError, match="garbage.osm.pbf"):
        read_features([D.OSM_FILE, garbage], D.grid(), T13)


def test_split_download_is_merged_without_duplicates(tmp_path: Path) -> None:
    # two overlapping parts, as a split API download: every node in both, ways shared out,
    # relations only in the first part (their member ways partly in the other), one PBF
    a_path, b_path = tmp_path / "part-a.osm", tmp_path / "part-b.osm.pbf"
    with osmium.SimpleWriter(str(a_path)) as a, osmium.SimpleWriter(str(b_path)) as b:
        for obj in osmium.FileProcessor(str(D.OSM_FILE)):
            if obj.is_node():
                a.add(obj)
                b.add(obj)
            elif obj.is_way():
                (a if obj.id % 2 else b).add(obj)
                if obj.id % 5 == 0:
                    (b if obj.id % 2 else a).add(obj)  # some ways in both parts
            else:
                a.add(obj)
    whole = labels_of(D.OSM_FILE)
    merged = rasterize(read_features([a_path, b_path], D.grid(), T13), D.grid(), T13)
    assert (merged == whole).all()
    assert (rasterize(read_features([D.OSM_FILE, D.OSM_FILE], D.grid(), T13), D.grid(), T13) == whole).all()


def test_feature_api() -> None:
    fs = read_features([str(D.OSM_FILE)], D.grid(), T13)
    assert isinstance(fs, FeatureSet) and len(fs) == len(list(fs))
    by_id = {f.osm_id: f for f in fs}
    courtyard = by_id["r1"]
    assert (courtyard.kind, T13.by_id[courtyard.class_id].name) == ("area", "building")
    assert [len(p.interiors) for p in shapely.get_parts(courtyard.geometry)] == [1]
    assert {f.kind for f in fs} == {"area", "line", "point", "sea"}
    assert by_id["coastline"].class_id == WATER
    assert all(f.geometry.geom_type in ("Polygon", "MultiPolygon") and f.geometry.is_valid for f in fs)
    assert all(f.order == T13.by_id[f.class_id].order for f in fs)
    assert fs.bounds[0] < D.grid().xy_bounds[0]


def test_closed_way_rules(tmp_path: Path) -> None:
    def build(o) -> None:
        o.way(D.rect((100, 100, 300, 300)), {"highway": "residential"})  # a loop road, not an area
        o.way(D.rect((400, 100, 600, 300)), {"highway": "pedestrian", "area": "yes"})
        o.way(D.rect((700, 100, 900, 300)), {"leisure": "park", "area": "no"})  # no line rule: nothing
        o.way(D.rect((100, 400, 300, 600)), {"amenity": "parking", "parking": "underground"})
        o.way([(400, 500), (900, 500)], {"waterway": "stream", "tunnel": "culvert"})
        o.way([(400, 700), (900, 700)], {"highway": "path", "surface": "gravel"})  # a path stays a path
    labels = labels_of(write_osm(tmp_path, build))
    assert at(labels, (200, 200)) == "unlabeled" and at(labels, (100, 200)) == "highway"
    assert at(labels, (500, 200)) == "footway"
    assert at(labels, (800, 200)) == "unlabeled"
    assert at(labels, (200, 500)) == "unlabeled"
    assert not labels[480:520].any()
    assert at(labels, (650, 700)) == "footway"


# -- coastline ------------------------------------------------------------------------------

def coast_file(tmp_path: Path, points, name: str = "coast.osm") -> Path:
    return write_osm(tmp_path, lambda o: o.way(list(points), {"natural": "coastline"}), name)


def test_coast_across_the_box_both_directions(tmp_path: Path) -> None:
    # a coast crossing the box from west to east along row 600: water on its right = south
    west_to_east = labels_of(coast_file(tmp_path, [(-100, 600), (640, 620), (1400, 600)]))
    assert (west_to_east[700:] == WATER).all() and not (west_to_east[:590] == WATER).any()
    east_to_west = labels_of(coast_file(tmp_path, [(1400, 600), (640, 620), (-100, 600)], "reversed.osm"))
    assert (east_to_west[:590] == WATER).all() and not (east_to_west[700:] == WATER).any()


def test_island_inside_the_box(tmp_path: Path) -> None:
    # OSM islands run anticlockwise (land on the left, inside); rect() runs clockwise
    labels = labels_of(coast_file(tmp_path, D.rect((400, 400, 800, 800))[::-1]))
    assert at(labels, (600, 600)) == "unlabeled"
    assert at(labels, (100, 100)) == at(labels, (1200, 1200)) == "water"
    lake_like = labels_of(coast_file(tmp_path, D.rect((400, 400, 800, 800)), "inverted.osm"))
    assert at(lake_like, (600, 600)) == "water" and at(lake_like, (100, 100)) == "unlabeled"


def test_coast_outside_the_box_decides_the_whole_box(tmp_path: Path) -> None:
    # an island east of the box: the whole box is sea; seen from inside a big island, land
    labels = labels_of(coast_file(tmp_path, D.rect((1500, 500, 1700, 700))[::-1]))
    assert (labels == WATER).all()
    inland = labels_of(coast_file(tmp_path, D.rect((-500, -500, 1800, 1800))[::-1], "big-island.osm"))
    assert not inland.any()


def test_coast_with_loose_ends_is_not_guessed(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="osmseg.osm.features"):
        fs = read_features([coast_file(tmp_path, [(200, 600), (1000, 600)])], D.grid(), T13)  # stops in the box
    assert not rasterize(fs, D.grid(), T13).any()
    assert "loose ends" in caplog.text and any("loose ends" in p for p in fs.problems)


def test_sea_polygon_corner_cases() -> None:
    box = (0.0, 0.0, 100.0, 100.0)
    assert sea_polygon([], box) is None
    diagonal = shapely.LineString([(-10, 110), (110, -10)])  # heading south-east: sea south-west
    sea = sea_polygon([diagonal], box)
    assert sea.area == pytest.approx(100 * 100 / 2) and sea.contains(shapely.Point(10, 10))
    two = [shapely.LineString([(110, 30), (-10, 30)]), shapely.LineString([(-10, 70), (110, 70)])]
    strait = sea_polygon(two, box)  # two coasts facing each other (land south and north): a strait
    assert strait.area == pytest.approx(40 * 100) and strait.contains(shapely.Point(50, 50))


def test_doctests() -> None:
    for module in (osmseg.osm.features, osmseg.osm.renumber, osmseg.osm.coastline, osmseg.classes):
        assert doctest.testmod(module).failed == 0, module.__name__


def test_widths_from_tags() -> None:
    table = load_class_table()
    road, tree = table.by_name["highway"], table.by_name["tree"]
    assert road.width_for({"highway": "residential", "width": "7,5 m", "lanes": "4"}) == 7.5
    assert road.width_for({"highway": "residential", "width": "10'"}) == pytest.approx(3.048)
    assert road.width_for({"highway": "residential", "lanes": "3"}) == 10.5
    assert road.width_for({"highway": "motorway"}) == 14.0
    assert road.width_for({"highway": "residential", "width": "-3"}) == 6.0
    assert tree.width_for({"natural": "tree"}, "point") == 5.0
    assert tree.width_for({"natural": "tree", "diameter_crown": "12"}, "point") == 12.0


def test_files_named_without_osm_suffix_are_sniffed(tmp_path: Path) -> None:
    # an API download saved as "map", and a gzipped XML file, read like tinycity.osm
    plain = tmp_path / "map"
    plain.write_bytes(D.OSM_FILE.read_bytes())
    gzipped = tmp_path / "tinycity.osm.gz"
    with gzip.open(gzipped, "wb") as f:
        f.write(D.OSM_FILE.read_bytes())
    whole = labels_of(D.OSM_FILE)
    assert (labels_of(plain) == whole).all() and (labels_of(gzipped) == whole).all()
    merged = rasterize(read_features([plain, gzipped], D.grid(), T13), D.grid(), T13)
    assert (merged == whole).all()


def test_committed_tinycity_matches_its_generator() -> None:
    assert D.build() == D.OSM_FILE.read_text(encoding="utf-8"), "run tests/data/tinycity/data.py"


# -- negative ids (JOSM's objects not yet uploaded) -------------------------------------------

JOSM_GRID = sample_grid(24.9405, 60.17025, 18, 5)
BUILDING = T13.by_name["building"].id
GRASS = T13.by_name["grass"].id
TREE = T13.by_name["tree"].id
PARKING = T13.by_name["parking"].id
# lon/lat rectangles (west, south, east, north) inside JOSM_GRID's box
JOSM_BUILDING = (24.9400, 60.1700, 24.9410, 60.1705)  # the bug report's way -201
JOSM_UNCLOSED = (24.9415, 60.1690, 24.9420, 60.1694)  # way -204, its last nd missing
JOSM_MIXED = (24.9425, 60.1690, 24.9430, 60.1694)  # way -205 through downloaded node 7 and new ones
JOSM_OUTER, JOSM_INNER = (24.9380, 60.1690, 24.9395, 60.1698), (24.9385, 60.1692, 24.9390, 60.1696)  # relation -301
JOSM_PARKING = (24.9432, 60.1700, 24.9440, 60.1706)  # relation -302's only present member
JOSM_TREE = (24.9425, 60.1715)
JOSM_ROAD = (24.9380, 60.1712, 24.9440, 60.1712)  # downloaded way 50, west-east


def josm_xml(sign: int = -1, nodes: bool = True) -> str:
    """A JOSM file of drawn labels: new objects get id ``sign * k`` (JOSM: negative), as JOSM writes them.

    New: building way 201 (the bug report's), an unclosed building 204, building 205 through
    the downloaded node 7, grass multipolygon 301 with a courtyard (inner ring), parking
    multipolygon 302 with member way 299 missing, tree node 124.  Downloaded (positive ids,
    with versions): node 7 and residential road 50.  Each type in JOSM's order: -1, -2, ...,
    then 1, 2, ...  ``nodes=False`` leaves out every node, as an Overpass answer without ``>;``.
    """
    new = "action='modify' visible='true'"
    old = "visible='true' version='3'"
    objects: dict[str, list[tuple[int, str]]] = {"node": [], "way": [], "relation": []}
    next_node = iter(range(101, 200))

    def tags(pairs: dict[str, str] | None) -> str:
        return "".join(f"<tag k='{k}' v='{v}' />" for k, v in (pairs or {}).items())

    def node(lon: float, lat: float, pairs: dict[str, str] | None = None, nid: int | None = None) -> int:
        attrs = new if nid is None else old
        nid = sign * next(next_node) if nid is None else nid
        objects["node"].append((nid, f"  <node id='{nid}' {attrs} lat='{lat}' lon='{lon}'>{tags(pairs)}</node>"))
        return nid

    def ring(box: tuple[float, float, float, float], first: int | None = None) -> list[int]:
        w, s, e, n = box
        refs = [first if first is not None else node(w, s), node(e, s), node(e, n), node(w, n)]
        return [*refs, refs[0]]

    def way(wid: int, refs: list[int], pairs: dict[str, str] | None = None, attrs: str = new) -> None:
        nds = "".join(f"<nd ref='{r}' />" for r in refs)
        objects["way"].append((wid, f"  <way id='{wid}' {attrs}>{nds}{tags(pairs)}</way>"))

    def relation(rid: int, members: list[tuple[int, str]], pairs: dict[str, str]) -> None:
        refs = "".join(f"<member type='way' ref='{sign * ref}' role='{role}' />" for ref, role in members)
        body = refs + tags({"type": "multipolygon", **pairs})
        objects["relation"].append((sign * rid, f"  <relation id='{sign * rid}' {new}>{body}</relation>"))

    way(sign * 201, ring(JOSM_BUILDING), {"building": "yes"})
    way(sign * 202, ring(JOSM_OUTER))
    way(sign * 203, ring(JOSM_INNER))
    relation(301, [(202, "outer"), (203, "inner")], {"landuse": "grass"})
    way(sign * 204, ring(JOSM_UNCLOSED)[:-1], {"building": "yes"})
    downloaded = node(JOSM_MIXED[0], JOSM_MIXED[1], nid=7)
    way(sign * 205, ring(JOSM_MIXED, first=downloaded), {"building": "yes"})
    way(sign * 206, ring(JOSM_PARKING))
    relation(302, [(206, "outer"), (299, "outer")], {"amenity": "parking"})
    node(*JOSM_TREE, {"natural": "tree"})
    road = [node(*JOSM_ROAD[:2], nid=8), node(*JOSM_ROAD[2:], nid=9)]
    way(50, road, {"highway": "residential"}, attrs=old)
    lines = [text for kind in ("node", "way", "relation") if nodes or kind != "node"
             for _, text in sorted(objects[kind], key=lambda item: (item[0] > 0, abs(item[0])))]
    head = "<?xml version='1.0' encoding='UTF-8'?>\n<osm version='0.6' upload='never' generator='JOSM'>\n"
    return head + "\n".join(lines) + "\n</osm>\n"


def josm_file(tmp_path: Path, sign: int = -1, nodes: bool = True) -> Path:
    path = tmp_path / f"josm{'-' if sign < 0 else '+'}{'' if nodes else '-nodes'}.osm"
    path.write_text(josm_xml(sign, nodes), encoding="utf-8")
    return path


def box_mask(box: tuple[float, float, float, float]) -> np.ndarray:
    """Pixels of JOSM_GRID whose centre lies inside a lon/lat rectangle (the rasteriser's rule)."""
    (x0, y0), (x1, y1) = osmseg.osm.geometry.lonlat_to_mercator(np.array([box[:2], box[2:]]))
    res, left, top = JOSM_GRID.transform.a, JOSM_GRID.transform.c, JOSM_GRID.transform.f
    xs = left + (np.arange(JOSM_GRID.width) + 0.5) * res
    ys = top - (np.arange(JOSM_GRID.height) + 0.5) * res
    return ((ys > y0) & (ys < y1))[:, None] & ((xs > x0) & (xs < x1))[None, :]


def test_josm_file_with_negative_ids_is_drawn(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="osmseg.osm.features"):
        fs = read_features([josm_file(tmp_path)], JOSM_GRID, T13)
    labels = rasterize(fs, JOSM_GRID, T13)
    buildings = box_mask(JOSM_BUILDING) | box_mask(JOSM_UNCLOSED) | box_mask(JOSM_MIXED)
    assert box_mask(JOSM_BUILDING).sum() > 20000  # ~70 m x 55 m of 0.3 m pixels
    assert ((labels == BUILDING) == buildings).all()
    assert ((labels == GRASS) == (box_mask(JOSM_OUTER) & ~box_mask(JOSM_INNER))).all()
    assert ((labels == PARKING) == box_mask(JOSM_PARKING)).all()  # drawn from its closed ring
    assert at(labels, lonlat_pixel(JOSM_TREE)) == "tree" and 100 < (labels == TREE).sum() < 400  # a 5 m crown
    assert at(labels, lonlat_pixel((24.9410, 60.1712))) == "highway"
    assert sorted(f.osm_id for f in fs) == ["n-124", "r-301", "r-302", "w-201", "w-204", "w-205", "w50"]
    assert fs.problems == (  # named by the ids the user sees in JOSM
        "way -204 (building): is tagged as an area but not closed: closed it",
        "relation -302 (parking): osmium could not assemble it (1 of its 2 member ways are missing from the file): "
        "drew its closed rings",
    )
    assert [r.getMessage() for r in caplog.records] == list(fs.problems)  # each logged once
    assert fs.unplaced == 0

    # the same objects with positive ids: the same mask, the same problems but for the ids
    positive = read_features([josm_file(tmp_path, sign=+1)], JOSM_GRID, T13)
    assert (rasterize(positive, JOSM_GRID, T13) == labels).all()
    assert sorted(f.osm_id for f in positive) == ["n124", "r301", "r302", "w201", "w204", "w205", "w50"]
    assert list(positive.problems) == [p.replace(" -", " ", 1) for p in fs.problems]


def lonlat_pixel(point: tuple[float, float]) -> tuple[float, float]:
    xy = osmseg.osm.geometry.lonlat_to_mercator(np.array([point]))[0]
    return ~JOSM_GRID.transform * tuple(xy)


def test_bug_report_josm_file_in_a_split_download(tmp_path: Path) -> None:
    # the bug report's file verbatim (single quotes, no version), alone and merged with another file
    path = tmp_path / "josm.osm"
    path.write_text(
        "<?xml version='1.0' encoding='UTF-8'?>\n<osm version='0.6' upload='never' generator='JOSM'>\n"
        + "".join(f"  <node id='-{101 + i}' action='modify' visible='true' lat='{lat}' lon='{lon}' />\n" for i, (lon, lat)
                  in enumerate([(24.9400, 60.1700), (24.9410, 60.1700), (24.9410, 60.1705), (24.9400, 60.1705)]))
        + "  <way id='-201' action='modify' visible='true'>\n"
          "    <nd ref='-101' /><nd ref='-102' /><nd ref='-103' /><nd ref='-104' /><nd ref='-101' />\n"
          "    <tag k='building' v='yes' />\n  </way>\n</osm>\n", encoding="utf-8")
    table = load_class_table()
    fs = read_features([path], JOSM_GRID, table)
    assert [f.osm_id for f in fs] == ["w-201"] and fs.problems == () and fs.unplaced == 0
    labels = rasterize(fs, JOSM_GRID, table)
    assert ((labels == table.by_name["building"].id) == box_mask(JOSM_BUILDING)).all()
    merged = read_features([path, josm_file(tmp_path, sign=+1)], JOSM_GRID, T13)  # JOSM new + downloaded
    assert "w-201" in {f.osm_id for f in merged} and "w201" in {f.osm_id for f in merged}


def test_ways_without_their_nodes_are_one_warning(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    expected = ("3 building ways, 1 grass relation, 1 highway way and 1 parking relation have no node with a location "
                "in the file (an extract without its nodes, e.g. an Overpass answer without '>;'?): not drawn")
    for sign in (+1, -1):
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="osmseg.osm.features"):
            fs = read_features([josm_file(tmp_path, sign=sign, nodes=False)], JOSM_GRID, T13)
        assert len(fs) == 0 and fs.unplaced == 6
        assert fs.problems == (expected,)
        assert [(r.levelname, r.getMessage()) for r in caplog.records] == [("WARNING", expected)]


def test_files_without_negative_ids_are_not_renumbered(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    before = read_features([D.OSM_FILE], D.grid(), T13)
    assert before.unplaced == 0 and not any("no node with a location" in p for p in before.problems)
    # no temporary directory can be made: reading must not need one (it would for a copy)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "absent"))
    after = read_features([D.OSM_FILE], D.grid(), T13)
    assert after == before
    assert read_features([josm_file(tmp_path, sign=+1)], JOSM_GRID, T13).problems
    with pytest.raises(FileNotFoundError):  # ... which the negative-id file does need
        read_features([josm_file(tmp_path)], JOSM_GRID, T13)


def test_renumbered_copy_keeps_the_id_order(tmp_path: Path) -> None:
    out = tmp_path / "copy.osm.pbf"
    assert osmseg.osm.renumber.write_renumbered(str(josm_file(tmp_path)), out, "josm.osm") == 32
    base = osmseg.osm.renumber.RENUMBER_BASE
    by_id = {}  # "w205" -> (tags, version, location or None, node refs, members)
    for o in osmium.FileProcessor(str(out)):
        location = (o.location.lon, o.location.lat) if o.is_node() else None
        refs = [n.ref for n in o.nodes] if o.is_way() else []
        members = [(m.ref, m.role) for m in o.members] if o.is_relation() else []
        by_id[o.type_str() + str(o.id)] = (dict(o.tags), o.version, location, refs, members)
    for kind in "nwr":  # osmium's multipolygon assembler needs the ways in order
        ids = [int(key[1:]) for key in by_id if key[0] == kind]
        assert ids == sorted(ids)
    assert f"n{base + 7}" in by_id and f"w{base + 50}" in by_id
    assert by_id["w205"][3] == [base + 7, 117, 118, 119, base + 7]
    assert by_id["r302"][4] == [(206, "outer"), (299, "outer")]
    assert by_id["n124"][0] == {"natural": "tree"} and by_id["n124"][2] == JOSM_TREE
    assert by_id[f"w{base + 50}"][:2] == ({"highway": "residential"}, 3)
    clash = tmp_path / "clash.osm"
    clash.write_text(josm_xml().replace("id='-124'", f"id='-{base + 1}'"), encoding="utf-8")
    with pytest.raises(OSMDataError, match="cannot renumber"):
        read_features([clash], JOSM_GRID, T13)
