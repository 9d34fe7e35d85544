"""The OSM reader's shortcuts on real extracts (../shared/data): they change speed, never features.

* Every tagged object of the Helsinki extract gets the class the table's rules give its full
  set of tags, whatever order the objects come in (the reader memoises decisions as a tree of
  tag look-ups, learnt from the objects it meets, and reads only the tags on the tree's path).
* West Oakland read as the API's XML (no multipolygon in it: osmium's area handler is skipped)
  and as PBF (read with it) gives the same features, problems and order.
* Clipping to a sample box gives GEOS's intersection bit for bit, also for the polygons inside
  the box, which skip GEOS's overlay.

Skipped when ../shared/data is absent.
"""

from __future__ import annotations

import math
import random
from pathlib import Path

import numpy as np
import osmium
import pytest
import shapely
from conftest import shared_path
from rasterio.features import rasterize

from osmseg.classes import ClassTable, load_class_table
from osmseg.grid import sample_grid
from osmseg.osm.features import FeatureSet, read_features
from osmseg.osm.geometry import to_mercator
from osmseg.osm.objects import COAST, WayRule, clip_to, rules_of

pytestmark = pytest.mark.shared_data


def expected_way(table: ClassTable, tags: dict[str, str]) -> object:
    """The reader's documented way rule, straight from the table (no memo, all tags)."""
    if table.coastline_class is not None and tags.get("natural") == "coastline":
        return COAST
    if table.is_hidden(tags):
        return None
    line, area = table.classify(tags, "line"), table.classify(tags, "area")
    if area is not None and (tags.get("area") == "yes" or line is None) and tags.get("area") != "no":
        return WayRule(True, area, math.nan)
    if line is None:
        return None
    width = line.width_for(tags, "line")
    return WayRule(False, line, math.nan if width is None else width)


def same(a: object, b: object) -> bool:
    """Equal decisions (a width of nan, no width, equals itself)."""
    if isinstance(a, tuple) and isinstance(b, tuple) and len(a) == len(b):
        return all(same(x, y) for x, y in zip(a, b))
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))


def test_every_helsinki_object_gets_its_rule_class_in_any_order() -> None:
    nodes: list[dict[str, str]] = []
    ways: list[dict[str, str]] = []
    relations: list[dict[str, str]] = []
    for obj in osmium.FileProcessor(str(shared_path("helsinki-osm", "helsinki.osm.pbf"))):
        if len(obj.tags):
            {"n": nodes, "w": ways, "r": relations}[obj.type_str()].append(dict(obj.tags))
    assert len(ways) > 2000 and len(nodes) > 500 and len(relations) > 50
    for shuffle in (False, True):
        table = load_class_table()  # a new table object: new (empty) decision trees
        rules = rules_of(table)
        order = list(range(len(ways)))
        if shuffle:
            random.Random(7).shuffle(order)
        for i in order:
            assert same(rules.way(ways[i]), expected_way(table, ways[i])), ways[i]
        for tags in nodes:
            cls = table.classify(tags, "point")
            want = None if cls is None or table.is_hidden(tags) else (cls, cls.width_for(tags, "point"))
            assert same(rules.node(tags), want), tags
        for tags in relations:
            want_area = None if table.is_hidden(tags) else table.classify(tags, "area")
            assert rules.area(tags) == want_area, tags
            assert rules.relation(tags) == (want_area if tags.get("type") == "multipolygon" else None), tags


def features_of(fs: FeatureSet) -> tuple[object, ...]:
    return (tuple((f.class_id, f.order, f.osm_id, f.kind, shapely.to_wkb(f.geometry)) for f in fs),
            fs.problems, fs.unplaced, tuple(fs.bounds))


def test_oakland_as_xml_and_as_pbf_gives_the_same_features(tmp_path: Path) -> None:
    xml = shared_path("oakland-osm", "west-oakland.osm")
    pbf = tmp_path / "west-oakland.osm.pbf"
    with osmium.SimpleWriter(str(pbf)) as writer:
        for obj in osmium.FileProcessor(str(xml)):
            writer.add(obj)
    table = load_class_table()
    for lon, lat in ((-122.3004, 37.8076), (-122.2990, 37.8065)):
        grid = sample_grid(lon, lat, 18)
        from_xml, from_pbf = read_features([xml], grid, table), read_features([pbf], grid, table)
        assert len(from_xml) > 50
        assert features_of(from_xml) == features_of(from_pbf)


def test_clipping_to_the_box_is_geos_intersection_to_the_pixel() -> None:
    # polygons inside the box skip GEOS's overlay: they must cover what GEOS's answer covers, and burn
    # the very same pixels
    polygons: list[shapely.Polygon] = []
    lines: list[shapely.LineString] = []
    for way in osmium.FileProcessor(str(shared_path("helsinki-osm", "helsinki.osm.pbf"))).with_locations():
        if not isinstance(way, osmium.osm.Way) or len(way.nodes) < 2 or not len(way.tags):
            continue
        try:
            coords = [(n.lon, n.lat) for n in way.nodes]
        except osmium.InvalidLocationError:  # nodes outside the extract
            continue
        if way.is_closed() and len(coords) > 3:
            polygons.append(shapely.Polygon(coords if len(polygons) % 2 else coords[::-1]))  # both orientations
        lines.append(shapely.LineString(coords))
    shapes = np.concatenate([np.array(polygons, dtype=object), shapely.buffer(np.array(lines, dtype=object), 4e-5)])
    shapes = shapes[shapely.is_valid(shapes)]  # what the reader clips is valid (areas are repaired first)
    known = np.arange(len(shapes)) % 2 == 0  # clip_to checks the validity of the others itself
    assert len(shapes) > 3000
    for lon, lat in ((24.9445, 60.1712), (24.9492, 60.1775)):
        b = sample_grid(lon, lat, 18).bbox
        clipped = clip_to(shapes, (b.west, b.south, b.east, b.north), known)
        expected = shapely.intersection(shapes, shapely.box(b.west, b.south, b.east, b.north))
        assert shapely.equals(clipped, expected).all()
        grid = sample_grid(lon, lat, 18)
        burn = [(g, 1 + i % 200) for i, g in enumerate(to_mercator(clipped)) if not g.is_empty]
        want = [(g, 1 + i % 200) for i, g in enumerate(to_mercator(expected)) if not g.is_empty]
        shape = (grid.height, grid.width)
        assert np.array_equal(rasterize(burn, out_shape=shape, transform=grid.transform),
                              rasterize(want, out_shape=shape, transform=grid.transform))
