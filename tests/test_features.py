"""Reading OSM into features: broken data, unreadable files, split downloads, coastline to sea."""

from __future__ import annotations

import doctest
import gzip
import logging
from pathlib import Path

import numpy as np
import osmium
import pytest
import shapely

import osmseg.classes
import osmseg.osm.coastline
import osmseg.osm.features
from osmseg.classes import load_class_table
from osmseg.errors import OSMDataError
from osmseg.osm.coastline import sea_polygon
from osmseg.osm.features import FeatureSet, read_features
from osmseg.rasterize import rasterize
from test_rasterize import T13, at, centre, load_tinycity

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
    for module in (osmseg.osm.features, osmseg.osm.coastline, osmseg.classes):
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
