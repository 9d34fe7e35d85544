"""LocalFileSource.cut: many boxes in one read, each file and done-marker exactly what fetch writes.

Small OSM files are written here by hand (a long segment, a multipolygon, repeated ids); the
real Helsinki extract comes from ../shared/data (skipped when absent).
"""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import osmium
import pytest
from conftest import shared_path

import osmseg.osm.cut as cut_module
import osmseg.osm.localfile as localfile
from osmseg.grid import LngLatBBox, pad_bbox, sample_grid
from osmseg.osm.cut import segments_hit_box
from osmseg.osm.localfile import LocalFileSource, segment_hits_box

#: A sample-sized box near (0, 0); the default reach (1 km) is about 0.009 degrees here.
BOX = LngLatBBox(0.0, 0.0, 0.004, 0.002)


def osm_xml(path: Path, nodes: dict[int, tuple[float, float]], ways: dict[int, list[int]],
            relations: dict[int, list[tuple[str, int]]] | None = None, version: dict[int, int] | None = None,
            tags: dict[int, str] | None = None) -> Path:
    """An OSM XML file: ``nodes`` id -> (lon, lat), ``ways`` id -> node ids (tagged ``highway=road``
    or ``tags[id]``, e.g. ``natural=coastline``), multipolygons id -> members."""
    relations, version, tags = relations or {}, version or {}, tags or {}
    lines = ['<?xml version="1.0"?>', '<osm version="0.6" generator="test">']
    lines += [f'<node id="{i}" version="{version.get(i, 1)}" timestamp="2024-01-0{version.get(i, 1)}T00:00:00Z" '
              f'lat="{lat}" lon="{lon}"/>' for i, (lon, lat) in nodes.items()]
    for i, refs in ways.items():
        lines.append(f'<way id="{i}" version="1" timestamp="2024-01-01T00:00:00Z">'
                     + "".join(f'<nd ref="{r}"/>' for r in refs)
                     + '<tag k="{}" v="{}"/></way>'.format(*tags.get(i, "highway=road").split("=")))
    for i, members in relations.items():
        lines.append(f'<relation id="{i}" version="1" timestamp="2024-01-01T00:00:00Z">'
                     + "".join(f'<member type="{"way" if t == "w" else "node"}" ref="{r}" role="outer"/>'
                               for t, r in members)
                     + '<tag k="type" v="multipolygon"/><tag k="natural" v="water"/></relation>')
    path.write_text("\n".join(lines + ["</osm>"]) + "\n")
    return path


def assert_same_as_fetch(path: Path, boxes: list[LngLatBBox], tmp_path: Path, prepare: tuple[LngLatBBox, ...] = (),
                         enclosing: bool = False, **kwargs) -> list:
    """``cut(boxes)`` in one work folder, ``fetch`` box by box in another: same bytes, file and marker."""
    cutter = LocalFileSource(path, tmp_path / "cut", enclosing=enclosing)
    fetcher = LocalFileSource(path, tmp_path / "fetch", enclosing=enclosing)
    if prepare:
        cutter.prepare(list(prepare))
        fetcher.prepare(list(prepare))
    got = cutter.cut(boxes, **kwargs)
    for box, extract in zip(boxes, got):
        want = fetcher.fetch(box)
        assert extract == LocalFileSource(path, tmp_path / "cut", enclosing=enclosing).fetch(box)  # what fetch reads
        assert extract.paths[0].read_bytes() == want.paths[0].read_bytes()
        marker = extract.paths[0].parent / extract.paths[0].name.replace(".osm.pbf", ".json")
        assert marker.read_bytes() == (want.paths[0].parent / marker.name).read_bytes()
    return got


def ids(extract) -> dict[str, set[int]]:
    found: dict[str, set[int]] = {"n": set(), "w": set(), "r": set()}
    for obj in osmium.FileProcessor(str(extract.paths[0])):
        found[obj.type_str()].add(obj.id)
    return found


def test_vector_liang_barsky_is_the_scalar_one():
    rng = np.random.default_rng(5)
    box = LngLatBBox(0.0, 0.0, 1.0, 1.0)
    grid = np.array([-1.0, 0.0, 0.5, 1.0, 2.0])  # edges, corners, axis-parallel and zero-length segments
    x0, y0, x1, y1 = (a.ravel() for a in np.meshgrid(grid, grid, grid, grid))
    rand = rng.uniform(-0.5, 1.5, (4, 2000))
    x0, y0, x1, y1 = (np.concatenate([a, r]) for a, r in zip((x0, y0, x1, y1), rand))
    got = segments_hit_box(x0, y0, x1, y1, box)
    want = [segment_hits_box((a, b), (c, d), box) for a, b, c, d in zip(x0, y0, x1, y1)]
    assert got.tolist() == want
    assert 0 < got.sum() < len(got)


def test_a_long_segment_crossing_a_box_without_a_node_in_it(tmp_path):
    osm = osm_xml(tmp_path / "long.osm",
                  {1: (-0.003, 0.001), 2: (0.007, 0.001), 3: (-0.02, 0.0015), 4: (0.007, 0.0015), 5: (0.002, 0.001)},
                  {10: [1, 2], 11: [3, 4]})
    inside = LngLatBBox(0.001, 0.0005, 0.003, 0.0018)
    far = LngLatBBox(0.05, 0.05, 0.054, 0.052)
    got = assert_same_as_fetch(osm, [BOX, inside, far], tmp_path)
    # way 10 crosses with both ends within reach; way 11 crosses too, but one end is 2 km out
    assert ids(got[0]) == {"n": {1, 2, 5}, "w": {10}, "r": set()}
    assert ids(got[1]) == {"n": {1, 2, 5}, "w": {10}, "r": set()}
    assert got[2].info["counts"] == {"n": 0, "w": 0, "r": 0}


def test_a_multipolygon_pulled_in_by_one_member_way(tmp_path):
    osm = osm_xml(tmp_path / "mp.osm",
                  {1: (0.001, 0.001), 2: (0.0015, 0.0012), 3: (0.03, 0.03), 4: (0.031, 0.03), 5: (0.03, 0.031),
                   6: (0.05, 0.05), 7: (0.0305, 0.0302)},
                  {20: [1, 2], 21: [3, 4, 5, 3], 22: [6, 3]},
                  {30: [("w", 20), ("w", 21), ("w", 99), ("n", 7)], 31: [("w", 22)]})
    got = assert_same_as_fetch(osm, [BOX, LngLatBBox(0.0295, 0.0295, 0.0312, 0.0312)], tmp_path)
    # way 20 is in the box: relation 30 comes with its far member 21, 21's nodes and member node 7
    # (way 99 is not in the file); relation 31 shares no member with the box's ways
    assert ids(got[0]) == {"n": {1, 2, 3, 4, 5, 7}, "w": {20, 21}, "r": {30}}
    # ways 21 and 22 have nodes in this box: each brings its relation with all of its members
    assert ids(got[1]) == {"n": {3, 4, 5, 6, 7, 1, 2}, "w": {20, 21, 22}, "r": {30, 31}}


def enclosed_box_file(path: Path) -> Path:
    """BOX inside a 11 km closed way, a multipolygon of three open ways and a U-shaped closed way,
    with coastlines 3 and 9 km north and a small closed way 3 km away: no node within 3 km of BOX."""
    corners = {1: (-0.05, -0.05), 2: (0.05, -0.05), 3: (0.05, 0.05), 4: (-0.05, 0.05),       # way 10
               5: (-0.04, -0.04), 6: (0.04, -0.04), 7: (0.04, 0.04), 8: (-0.04, 0.04),       # relation 40
               20: (-0.03, -0.03), 21: (0.03, -0.03), 22: (0.03, 0.03), 23: (0.028, 0.03),   # way 14, a U
               24: (0.028, -0.028), 25: (-0.028, -0.028), 26: (-0.028, 0.03), 27: (-0.03, 0.03),
               30: (-0.1, 0.03), 31: (0.1, 0.03), 32: (-0.1, 0.08), 33: (0.1, 0.08),         # coastlines
               40: (0.03, -0.02), 41: (0.031, -0.02), 42: (0.031, -0.019)}                   # way 17
    ways = {10: [1, 2, 3, 4, 1], 11: [5, 6], 12: [6, 7], 13: [7, 8, 5], 14: [20, 21, 22, 23, 24, 25, 26, 27, 20],
            15: [31, 30], 16: [33, 32], 17: [40, 41, 42, 40]}
    return osm_xml(path, corners, ways, {40: [("w", 11), ("w", 12), ("w", 13)]},
                   tags={10: "landuse=forest", 14: "landuse=forest", 15: "natural=coastline", 16: "natural=coastline",
                         17: "building=yes"})


def test_enclosing_keeps_the_areas_a_box_lies_inside_and_the_coast_near_it(tmp_path):
    osm = enclosed_box_file(tmp_path / "enclosed.osm")
    plain = assert_same_as_fetch(osm, [BOX], tmp_path / "plain")
    assert plain[0].info["counts"] == {"n": 0, "w": 0, "r": 0}  # a build's cut: nothing near the box
    got = assert_same_as_fetch(osm, [BOX, LngLatBBox(0.06, 0.0, 0.064, 0.002)], tmp_path / "enclosing",
                               enclosing=True)
    # the forest, the U (its box holds BOX: kept though it does not cover it), the relation with its
    # three ways, the coast 3 km north; not the coast 9 km north, nor the small way
    assert ids(got[0]) == {"n": {1, 2, 3, 4, 5, 6, 7, 8, *range(20, 28), 30, 31}, "w": {10, 11, 12, 13, 14, 15},
                           "r": {40}}
    # a box outside every area but with both coastlines within 5 km: the coast only
    assert ids(got[1]) == {"n": {30, 31}, "w": {15}, "r": set()}
    # cut from the region prepared for both boxes: the same (the region holds all the rule keeps)
    area = LngLatBBox(0.0, 0.0, 0.064, 0.002)
    again = assert_same_as_fetch(osm, [BOX], tmp_path / "prepared", prepare=(area,), enclosing=True)
    assert ids(again[0]) == ids(got[0])


def test_a_file_with_repeated_ids_is_cut_box_by_box(tmp_path, caplog):
    osm = osm_xml(tmp_path / "history.osm", {1: (0.001, 0.001), 2: (0.002, 0.001)}, {10: [1, 2]}, version={1: 1})
    text = osm.read_text().replace("</osm>", '<node id="1" version="2" timestamp="2024-01-02T00:00:00Z" '
                                              'lat="0.0011" lon="0.001"/></osm>')
    osm.write_text(text)
    caplog.set_level("INFO", logger="osmseg.osm.cut")
    got = assert_same_as_fetch(osm, [BOX, LngLatBBox(0.0015, 0.0005, 0.003, 0.0015)], tmp_path)
    assert got[0].info["counts"]["n"] == 3  # both versions of node 1
    assert "node ids repeat in the file; cutting 2 boxes one by one" in caplog.text


def test_rerun_skips_boxes_already_cut(tmp_path, monkeypatch):
    osm = osm_xml(tmp_path / "a.osm", {1: (0.001, 0.001), 2: (0.002, 0.001), 3: (0.021, 0.001)}, {10: [1, 2]})
    boxes = [BOX, LngLatBBox(0.02, 0.0, 0.024, 0.002), LngLatBBox(0.04, 0.0, 0.044, 0.002)]
    source = LocalFileSource(osm, tmp_path / "work")
    first = source.cut(boxes[:2])
    written = {e.paths[0]: e.paths[0].stat().st_mtime_ns for e in first}
    calls: list[list] = []
    real = localfile.write_extracts

    def spy(src, jobs, *args, **kwargs):
        calls.append([box for box, _ in jobs])
        return real(src, jobs, *args, **kwargs)

    monkeypatch.setattr(localfile, "write_extracts", spy)
    again = LocalFileSource(osm, tmp_path / "work").cut(boxes + boxes[:1])
    assert calls == [[boxes[2]]]
    assert again[:2] == first and again[3] == first[0]
    assert {p: p.stat().st_mtime_ns for p in written} == written
    assert LocalFileSource(osm, tmp_path / "work").cut(boxes) == again[:3]
    assert len(calls) == 1


def test_an_interrupted_cut_leaves_no_half_file(tmp_path, monkeypatch):
    nodes = {i: (0.0002 * i, 0.001) for i in range(1, 60)}
    osm = osm_xml(tmp_path / "a.osm", nodes, {10: list(nodes)})
    boxes = [LngLatBBox(0.002 * k, 0.0, 0.002 * k + 0.004, 0.002) for k in range(5)]
    real = osmium.SimpleWriter
    adds = {"n": 0}

    class Failing:
        """osmium's writer, failing in the write pass of the second batch."""

        def __init__(self, *args, **kwargs):
            self.writer = real(*args, **kwargs)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return self.writer.__exit__(*exc)

        def __getattr__(self, name):  # add, add_node, add_way, add_relation
            def add(obj):
                adds["n"] += 1
                if adds["n"] > 200:
                    raise OSError("disk gone")
                getattr(self.writer, name)(obj)
            return add

    monkeypatch.setattr(cut_module.osmium, "SimpleWriter", Failing)
    work = tmp_path / "work"
    with pytest.raises(OSError, match="disk gone"):
        LocalFileSource(osm, work).cut(boxes, batch=2)
    monkeypatch.undo()
    names = sorted(p.name for p in work.iterdir())
    assert not [n for n in names if n.startswith(".")]  # no temporary file left
    pbfs = [n for n in names if n.endswith(".osm.pbf")]
    markers = [n for n in names if n.endswith(".json") and not n.startswith("timestamp_")]  # (the file's date)
    assert len(pbfs) == 2  # the first batch (2 boxes) is done, the failing second one left nothing
    assert [n.replace(".osm.pbf", ".json") for n in pbfs] == markers
    assert_same_as_fetch(osm, boxes, tmp_path)  # fresh folders: the complete cut
    rerun = LocalFileSource(osm, work).cut(boxes, batch=2)
    fresh = LocalFileSource(osm, tmp_path / "fetch")
    assert all(e.paths[0].read_bytes() == fresh.fetch(b).paths[0].read_bytes() for b, e in zip(boxes, rerun))


@pytest.mark.shared_data
@pytest.mark.parametrize("enclosing", [False, True])
def test_cut_of_real_helsinki_boxes_is_fetch_byte_for_byte(tmp_path, enclosing):
    helsinki = shared_path("helsinki-osm", "helsinki.osm.pbf")
    rng = random.Random(3)
    centres = [(24.944 + rng.uniform(-0.004, 0.004), 60.1715 + rng.uniform(-0.002, 0.002)) for _ in range(5)]
    centres += [(24.9352, 60.170), (24.953, 60.179), (24.90, 60.17)]  # two on the file's edge, one with no data
    boxes = [pad_bbox(sample_grid(lon, lat, 18).bbox, 60) for lon, lat in centres]
    boxes.append(pad_bbox(sample_grid(24.944, 60.1715, 19).bbox, 60))  # a smaller one, inside another
    area = pad_bbox(LngLatBBox(24.939, 60.169, 24.949, 60.174), 300)
    got = assert_same_as_fetch(helsinki, boxes, tmp_path, prepare=(area,), batch=4, enclosing=enclosing)
    counts = [sum(e.info["counts"].values()) for e in got]
    assert min(counts[:5]) > 1000
    assert any(r["r"] for r in (e.info["counts"] for e in got))
    if not enclosing:
        assert counts[-2] == 0
        return
    # the same boxes cut as a build cuts them: a subset; the box with no data gets the coast only
    plain = LocalFileSource(helsinki, tmp_path / "plain").cut(boxes, batch=4)
    for mine, theirs in zip(got, plain):
        assert all(ids(theirs)[k] <= ids(mine)[k] for k in "nwr")
    assert counts[-2] > 0 and not ids(plain[-2])["w"]
    coast = {w.id for w in osmium.FileProcessor(str(helsinki), osmium.osm.WAY) if w.tags.get("natural") == "coastline"}
    assert ids(got[-2])["w"] <= coast
