#!/usr/bin/env python3
"""Generate the OSM source fixtures: one small OSM content and what three services answer for it.

Run from the repository root (``.venv/bin/python tests/data/osm/data.py``); it rewrites:

* ``content.osm``: a made-up town of ~1 km around Berlin-Mitte coordinates (no real data),
  in OSM XML 0.6 with full metadata: roads (primary, residential, a gravel residential that
  is a "dirt road", a track, a footway, a hidden tunnel), buildings (one crossing each
  sample edge, one courtyard multipolygon with a hole), park with trees, grass, parking,
  industrial, construction, beach, a coastline with the sea to its north, and a lake
  multipolygon with an island whose outer ring is split in two ways, one of them entirely
  outside the fetched box (so the API's map call returns the relation without it).
* ``scenario.json``: the sample grid (centre, zoom), the padding and the box that is fetched.
* ``api_map.yaml``: vcrpy cassette of ``OsmApiSource.fetch(box)``: ``GET /api/0.6/map`` and
  the ``GET /api/0.6/relation/<lake>/full`` it triggers.
* ``api_split.yaml``: the same fetch against a server whose node limit the box exceeds: the
  HTTP 400 "You requested too many nodes" answer, then the quadrant calls (one quadrant is
  refused again and split once more), then the relation call.
* ``overpass.yaml``: vcrpy cassette of ``OverpassSource.fetch(box)``: the POST of the
  query for the classes13 table and the answer.

The answers are computed with osmium from ``content.osm`` by emulating each service:

* OSM API 0.6 ``map`` (cgimap): nodes in the box; ways using any of them; all nodes of those
  ways; relations referencing any of those nodes or ways; relations referencing those
  relations; refuses boxes over 0.25 deg² and boxes with more than ``node_limit`` nodes
  (the real limit is 50,000: this tiny fixture uses ``SPLIT_NODE_LIMIT`` so that it is
  exceeded, and answers with the API's real message text).
* OSM API ``relation/<id>/full``: the relation, its members, and the nodes of member ways.
* Overpass ``[bbox:...]`` query: the statements of the query text are *parsed here* (element,
  ``["k"]``, ``["k"="v"]``, ``["k"~"regex"]``) so the answer follows what the query says, not
  what osmseg meant; ``(bbox)`` selects nodes inside, ways with a segment crossing the box
  (checked with shapely), relations with such a member; ``(._;>;)`` adds members and their
  nodes; ``out body`` prints tags and references without metadata, after a ``<meta
  osm_base>`` line, as Overpass 0.7.62 does.

Wire format: status lines, headers (``Content-Type: text/xml; charset=utf-8`` for the API,
``application/osm3s+xml`` for Overpass, ``text/plain`` errors with the API's ``Error`` header,
fixed ``Date``) and bodies as the services send them.  Bodies are stored identity-encoded
(the services gzip only when asked; vcrpy stores decoded bodies anyway) so cassettes stay
readable.  Requests are what osmseg sends (``quadrants`` and ``bbox_param`` from
``osmseg.osm.api``, ``overpass_query`` from ``osmseg.osm.overpass``); matching uses the
method, host, path, query and body (as ``osmseg.net.cassette.match_key`` does).
"""

from __future__ import annotations

import json
import math
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlencode
from xml.sax.saxutils import quoteattr

import osmium
import shapely
from vcr.request import Request
from vcr.serialize import serialize
from vcr.serializers import yamlserializer

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[2]))

from osmseg.classes import load_class_table  # noqa: E402
from osmseg.grid import LngLatBBox, pad_bbox, sample_grid  # noqa: E402
from osmseg.osm.api import DEFAULT_API_URL, bbox_param, quadrants  # noqa: E402
from osmseg.osm.overpass import DEFAULT_OVERPASS_URL, overpass_query  # noqa: E402

CENTRE = (13.4000, 52.5200)  # lon, lat: the sample grid's centre point
ZOOM = 18
PAD_METRES = 50.0  # the fetched box is the sample box grown by this; > longest segment (40 m)
SPLIT_NODE_LIMIT = 52
API_DATE = "Fri, 14 Mar 2025 09:27:31 GMT"
OVERPASS_DATE = "Fri, 14 Mar 2025 09:28:05 GMT"
OSM_BASE = "2025-03-14T09:27:02Z"
USER_AGENT = "osmseg/0.1.0 (+https://github.com/osmseg/osmseg)"
CGIMAP = "openstreetmap-cgimap 2.0.1 (3319 spike-07.openstreetmap.org)"
OVERPASS_GENERATOR = "Overpass API 0.7.62.5 1bd436f1"


# -- the content ----------------------------------------------------------------------------------


@dataclass
class Content:
    """OSM objects in insertion order, built in metres around the grid centre."""

    lon0: float
    lat0: float
    nodes: dict[int, tuple[float, float, dict[str, str]]] = field(default_factory=dict)
    ways: dict[int, tuple[list[int], dict[str, str]]] = field(default_factory=dict)
    relations: dict[int, tuple[list[tuple[str, int, str]], dict[str, str]]] = field(default_factory=dict)
    next_node: int = 4_100_000_001
    next_way: int = 420_000_001
    next_rel: int = 17_000_001

    def lonlat(self, x: float, y: float) -> tuple[float, float]:
        lat = self.lat0 + y / 111_320.0
        lon = self.lon0 + x / (111_320.0 * math.cos(math.radians(self.lat0)))
        return round(lon, 7), round(lat, 7)

    def node(self, x: float, y: float, tags: dict[str, str] | None = None) -> int:
        nid = self.next_node
        self.next_node += 1
        self.nodes[nid] = (*self.lonlat(x, y), dict(tags or {}))
        return nid

    def way(self, points: list[tuple[float, float]], tags: dict[str, str] | None = None,
            closed: bool = False, step: float = 40.0) -> int:
        """A way through ``points`` with a node at least every ``step`` metres."""
        pts = list(points) + ([points[0]] if closed else [])
        dense = [pts[0]]
        for (x0, y0), (x1, y1) in zip(pts, pts[1:]):
            k = max(1, math.ceil(math.hypot(x1 - x0, y1 - y0) / step))
            dense += [(x0 + (x1 - x0) * i / k, y0 + (y1 - y0) * i / k) for i in range(1, k + 1)]
        refs = [self.node(x, y) for x, y in (dense[:-1] if closed else dense)]
        if closed:
            refs.append(refs[0])
        wid = self.next_way
        self.next_way += 1
        self.ways[wid] = (refs, dict(tags or {}))
        return wid

    def way_refs(self, refs: list[int], tags: dict[str, str] | None = None) -> int:
        wid = self.next_way
        self.next_way += 1
        self.ways[wid] = (refs, dict(tags or {}))
        return wid

    def relation(self, members: list[tuple[str, int, str]], tags: dict[str, str]) -> int:
        rid = self.next_rel
        self.next_rel += 1
        self.relations[rid] = (members, dict(tags))
        return rid


def rect(x0: float, y0: float, x1: float, y1: float) -> list[tuple[float, float]]:
    return [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]


def build_content() -> tuple[Content, int]:
    """The town. Returns it and the id of the split lake relation."""
    grid = sample_grid(*CENTRE, ZOOM)
    b = grid.bbox
    c = Content(lon0=(b.west + b.east) / 2, lat0=(b.south + b.north) / 2)
    # sample box: about +-232 m around (0, 0); fetched box: about +-282 m
    c.way([(600, 200), (200, 205), (0, 195), (-300, 200), (-600, 200)], {"natural": "coastline"})  # sea to the north
    c.way(rect(-100, 170, 100, 196), {"natural": "beach"}, closed=True)
    c.way([(-600, -40), (600, -40)], {"highway": "primary", "name": "Hauptstraße", "lanes": "2"})
    c.way([(-120, -600), (-120, 165)], {"highway": "residential", "name": "Westweg"})
    c.way([(160, -40), (160, 165)], {"highway": "residential", "surface": "gravel"})
    c.way([(0, -600), (0, -40)], {"highway": "track", "tracktype": "grade3"})
    c.way([(-300, -300), (-130, -130), (-20, -45)], {"highway": "footway"})
    c.way([(-250, 120), (250, 120)], {"highway": "secondary", "tunnel": "yes", "layer": "-1"})
    c.way([(-60, 150), (-20, 150), (-20, 130), (-60, 130)], {"highway": "service"}, closed=True)
    for x0, y0, w, h in [(-90, 20, 20, 15), (-60, 20, 18, 15), (30, 0, 25, 20), (215, 20, 35, 20),
                         (-250, -80, 35, 20), (190, -100, 15, 15), (-60, -90, 30, 20), (260, -20, 30, 12),
                         (400, 40, 20, 20)]:
        c.way(rect(x0, y0, x0 + w, y0 + h), {"building": "yes"}, closed=True)
    outer = c.way(rect(-200, 40, -140, 100), closed=True)
    inner = c.way(rect(-185, 55, -155, 85), closed=True)
    c.relation([("w", outer, "outer"), ("w", inner, "inner")], {"type": "multipolygon", "building": "apartments"})
    c.way(rect(40, 40, 140, 140), {"leisure": "park", "name": "Stadtpark"}, closed=True)
    for x, y in [(55, 60), (80, 75), (110, 60), (125, 120), (60, 125), (95, 100), (-105, -10), (-135, 60)]:
        c.node(x, y, {"natural": "tree"})
    c.way(rect(-100, -200, -40, -120), {"landuse": "grass"}, closed=True)
    c.way(rect(60, -120, 110, -70), {"amenity": "parking"}, closed=True)
    c.way(rect(-600, -600, -180, -100), {"landuse": "industrial"}, closed=True)
    c.way(rect(20, -250, 70, -190), {"landuse": "construction"}, closed=True)
    # the lake: outer ring split at x=340; the east part has no node in the fetched box
    west = c.way([(340, -150), (120, -150), (120, -260), (340, -260)])
    nw, sw = c.ways[west][0][0], c.ways[west][0][-1]
    mid_e = [c.node(420, -260), c.node(420, -205), c.node(420, -150)]
    east = c.way_refs([sw, c.node(380, -260), *mid_e, c.node(380, -150), nw])
    island = c.way(rect(180, -215, 220, -185), {"place": "islet"}, closed=True)
    lake = c.relation([("w", west, "outer"), ("w", east, "outer"), ("w", island, "inner")],
                      {"type": "multipolygon", "natural": "water", "name": "Kleiner See"})
    return c, lake


def meta(kind: str, oid: int) -> str:
    """Deterministic, plausible metadata attributes for an object."""
    version = 1 + oid % 3
    day = 1 + oid % 27
    year = 2016 + oid % 9
    user = ("mapper_a", "Strassenkarte", "gruen_nrw", "osm_fan")[oid % 4]
    return (f'visible="true" version="{version}" changeset="{150_000_000 + oid % 9_000_000}" '
            f'timestamp="{year}-{1 + oid % 12:02d}-{day:02d}T{oid % 24:02d}:{oid % 60:02d}:{(oid * 7) % 60:02d}Z" '
            f'user="{user}" uid="{1000 + oid % 4}"')


def tags_xml(tags: dict[str, str], indent: str) -> list[str]:
    return [f"{indent}<tag k={quoteattr(k)} v={quoteattr(v)}/>" for k, v in tags.items()]


def write_content(c: Content, path: Path) -> None:
    """``content.osm`` in the API's XML layout (the "planet" every emulated service serves)."""
    lines = ['<?xml version="1.0" encoding="UTF-8"?>',
             '<osm version="0.6" generator="osmseg tests/data/osm/data.py">']
    lines += object_lines(c, set(c.nodes), set(c.ways), set(c.relations), with_meta=True, indent=" ")
    lines.append("</osm>")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


# -- reading it back with osmium --------------------------------------------------------------------


@dataclass
class Planet:
    """``content.osm`` as osmium reads it."""

    nodes: dict[int, tuple[float, float, dict[str, str]]]
    ways: dict[int, tuple[list[int], dict[str, str]]]
    relations: dict[int, tuple[list[tuple[str, int, str]], dict[str, str]]]
    meta: dict[tuple[str, int], str]


def load(path: Path, c: Content) -> Planet:
    p = Planet({}, {}, {}, {})
    for o in osmium.FileProcessor(str(path)):
        tags = {t.k: t.v for t in o.tags}
        if o.is_node():
            p.nodes[o.id] = (o.location.lon, o.location.lat, tags)
        elif o.is_way():
            p.ways[o.id] = ([n.ref for n in o.nodes], tags)
        elif o.is_relation():
            p.relations[o.id] = ([(m.type, m.ref, m.role) for m in o.members], tags)
    return p


def object_lines(c: Content | Planet, nodes: set[int], ways: set[int], relations: set[int],
                 with_meta: bool, indent: str) -> list[str]:
    """XML lines for the chosen objects, sorted by type then id (as both services print)."""
    out = []
    i2 = indent * 2
    for nid in sorted(nodes):
        lon, lat, tags = c.nodes[nid]
        attrs = f'id="{nid}" ' + (meta("n", nid) + " " if with_meta else "") + f'lat="{lat:.7f}" lon="{lon:.7f}"'
        if tags:
            out += [f"{indent}<node {attrs}>", *tags_xml(tags, i2), f"{indent}</node>"]
        else:
            out.append(f"{indent}<node {attrs}/>")
    for wid in sorted(ways):
        refs, tags = c.ways[wid]
        attrs = f'id="{wid}"' + (" " + meta("w", wid) if with_meta else "")
        out += [f"{indent}<way {attrs}>", *(f'{i2}<nd ref="{r}"/>' for r in refs), *tags_xml(tags, i2), f"{indent}</way>"]
    for rid in sorted(relations):
        members, tags = c.relations[rid]
        attrs = f'id="{rid}"' + (" " + meta("r", rid) if with_meta else "")
        names = {"n": "node", "w": "way", "r": "relation"}
        out += [f"{indent}<relation {attrs}>",
                *(f'{i2}<member type="{names[t]}" ref="{ref}" role={quoteattr(role)}/>' for t, ref, role in members),
                *tags_xml(tags, i2), f"{indent}</relation>"]
    return out


# -- the OSM API ---------------------------------------------------------------------------------------


def inside(lon: float, lat: float, box: LngLatBBox) -> bool:
    return box.west <= lon <= box.east and box.south <= lat <= box.north


def api_map(p: Planet, box: LngLatBBox, node_limit: int) -> tuple[int, dict[str, str], str]:
    """What cgimap answers to ``GET /api/0.6/map?bbox=``: status, headers, body."""
    if (box.east - box.west) * (box.north - box.south) > 0.25:
        return api_error("The maximum bbox size is 0.250000, and your request was too large. "
                         "Either request a smaller area, or use planet.osm")
    nodes = {nid for nid, (lon, lat, _) in p.nodes.items() if inside(lon, lat, box)}
    if len(nodes) > node_limit:
        return api_error("You requested too many nodes (limit is 50000). Either request a smaller area, or use planet.osm")
    ways = {wid for wid, (refs, _) in p.ways.items() if nodes.intersection(refs)}
    all_nodes = nodes | {r for wid in ways for r in p.ways[wid][0]}
    rels = {rid for rid, (members, _) in p.relations.items()
            if any((t == "n" and ref in nodes) or (t == "w" and ref in ways) for t, ref, _ in members)}
    rels |= {rid for rid, (members, _) in p.relations.items() if any(t == "r" and ref in rels for t, ref, _ in members)}
    head = ['<?xml version="1.0" encoding="UTF-8"?>',
            f'<osm version="0.6" generator="{CGIMAP}" copyright="OpenStreetMap and contributors" '
            'attribution="http://www.openstreetmap.org/copyright" license="http://opendatacommons.org/licenses/odbl/1-0/">',
            f' <bounds minlat="{box.south:.7f}" minlon="{box.west:.7f}" maxlat="{box.north:.7f}" maxlon="{box.east:.7f}"/>']
    body = "\n".join(head + object_lines(p, all_nodes, ways, rels, with_meta=True, indent=" ") + ["</osm>"]) + "\n"
    return 200, {**api_headers(), "Content-Disposition": 'attachment; filename="map.osm"'}, body


def api_relation_full(p: Planet, rid: int) -> tuple[int, dict[str, str], str]:
    """What the API answers to ``GET /api/0.6/relation/<id>/full``."""
    members, _ = p.relations[rid]
    ways = {ref for t, ref, _ in members if t == "w"}
    nodes = {ref for t, ref, _ in members if t == "n"} | {r for w in ways for r in p.ways[w][0]}
    rels = {rid} | {ref for t, ref, _ in members if t == "r"}
    head = ['<?xml version="1.0" encoding="UTF-8"?>',
            f'<osm version="0.6" generator="{CGIMAP}" copyright="OpenStreetMap and contributors" '
            'attribution="http://www.openstreetmap.org/copyright" license="http://opendatacommons.org/licenses/odbl/1-0/">']
    body = "\n".join(head + object_lines(p, nodes, ways, rels, with_meta=True, indent=" ") + ["</osm>"]) + "\n"
    return 200, api_headers(), body


def api_headers() -> dict[str, str]:
    return {
        "Date": API_DATE,
        "Server": "Apache/2.4.58 (Ubuntu)",
        "Strict-Transport-Security": "max-age=31536000; includeSubDomains; preload",
        "Cache-Control": "private, max-age=0, must-revalidate",
        "Vary": "Accept-Encoding",
        "Content-Type": "text/xml; charset=utf-8",
    }


def api_error(message: str) -> tuple[int, dict[str, str], str]:
    headers = {**api_headers(), "Content-Type": "text/plain; charset=utf-8", "Error": message,
               "Cache-Control": "no-cache"}
    return 400, headers, message


def api_session(p: Planet, box: LngLatBBox, node_limit: int) -> list[tuple[str, str, str | None, tuple[int, dict[str, str], str]]]:
    """The calls ``OsmApiSource.fetch(box)`` makes and their answers, in order.

    Mirrors the client: quarter a refused box (south-west, south-east, north-west,
    north-east, depth first), then fetch every multipolygon with some but not all member
    ways in the answers.
    """
    calls = []
    answered: list[str] = []

    def visit(b: LngLatBBox) -> None:
        answer = api_map(p, b, node_limit)
        calls.append(("GET", f"{DEFAULT_API_URL}/map?bbox={bbox_param(b)}", None, answer))
        if answer[0] == 400:
            for q in quadrants(b):
                visit(q)
        else:
            answered.append(answer[2])

    visit(box)
    present_ways = {int(m) for body in answered for m in re.findall(r'<way id="(\d+)"', body)}
    rels = sorted({int(m) for body in answered for m in re.findall(r'<relation id="(\d+)"', body)})
    for rid in rels:
        members, tags = p.relations[rid]
        ways = [ref for t, ref, _ in members if t == "w"]
        if tags.get("type") == "multipolygon" and any(w in present_ways for w in ways) and not all(w in present_ways for w in ways):
            calls.append(("GET", f"{DEFAULT_API_URL}/relation/{rid}/full", None, api_relation_full(p, rid)))
    return calls


# -- Overpass -------------------------------------------------------------------------------------------

_STATEMENT = re.compile(r"^\s*(node|way|relation)((?:\[[^\]]*\])*);\s*$")
_FILTER = re.compile(r'\["((?:[^"\\]|\\.)*)"(?:(=|~)"((?:[^"\\]|\\.)*)")?\]')


def parse_query(query: str) -> tuple[LngLatBBox, list[tuple[str, list[tuple[str, str | None, str | None]]]]]:
    """The global bbox and the union statements of an osmseg Overpass query."""
    m = re.match(r"\[out:xml\]\[timeout:\d+\]\[bbox:([-\d.]+),([-\d.]+),([-\d.]+),([-\d.]+)\];", query)
    assert m, query
    s, w, n, e = map(float, m.groups())
    lines = query.splitlines()
    assert lines[1] == "(" and lines[-3:] == [");", "(._;>;);", "out body;"], lines
    statements = []
    for line in lines[2:-3]:
        sm = _STATEMENT.match(line)
        assert sm, line
        filters = [(_unquote(k), op or None, _unquote(v) if op else None) for k, op, v in _FILTER.findall(sm.group(2))]
        statements.append((sm.group(1), filters))
    return LngLatBBox(w, s, e, n), statements


def _unquote(text: str) -> str:
    """An Overpass QL string body without its backslash escapes."""
    return re.sub(r"\\(.)", r"\1", text)


def tag_ok(tags: dict[str, str], filters: list[tuple[str, str | None, str | None]]) -> bool:
    for key, op, value in filters:
        if key not in tags:
            return False
        if op == "=" and tags[key] != value:
            return False
        if op == "~" and not re.search(value, tags[key]):
            return False
    return True


def overpass_answer(p: Planet, query: str) -> tuple[int, dict[str, str], str]:
    """What Overpass answers to ``query`` (see the module doc for the semantics emulated)."""
    box, statements = parse_query(query)
    area = shapely.box(*box)

    def way_line(wid: int) -> shapely.Geometry:
        coords = [p.nodes[r][:2] for r in p.ways[wid][0] if r in p.nodes]
        return shapely.LineString(coords) if len(coords) > 1 else shapely.Point(coords[0])

    nodes, ways, rels = set(), set(), set()
    for element, filters in statements:
        if element == "node":
            nodes |= {i for i, (lon, lat, t) in p.nodes.items() if tag_ok(t, filters) and inside(lon, lat, box)}
        elif element == "way":
            ways |= {i for i, (_, t) in p.ways.items() if tag_ok(t, filters) and way_line(i).intersects(area)}
        else:
            rels |= {i for i, (members, t) in p.relations.items() if tag_ok(t, filters) and any(
                (k == "n" and inside(*p.nodes[ref][:2], box)) or (k == "w" and way_line(ref).intersects(area))
                for k, ref, _ in members)}
    # (._;>;): members of relations, nodes of ways
    for rid in rels:
        for k, ref, _ in p.relations[rid][0]:
            (ways if k == "w" else nodes if k == "n" else set()).add(ref)
    nodes |= {r for w in ways for r in p.ways[w][0]}
    head = ['<?xml version="1.0" encoding="UTF-8"?>',
            f'<osm version="0.6" generator="{OVERPASS_GENERATOR}">',
            "<note>The data included in this document is from www.openstreetmap.org. "
            "The data is made available under ODbL.</note>",
            f'<meta osm_base="{OSM_BASE}"/>', ""]
    body = "\n".join(head + object_lines(p, nodes, ways, rels, with_meta=False, indent="  ") + ["", "</osm>"]) + "\n"
    headers = {"Date": OVERPASS_DATE, "Server": "Apache/2.4.62 (Debian)", "Vary": "Accept-Encoding",
               "Content-Type": "application/osm3s+xml", "Access-Control-Allow-Origin": "*"}
    return 200, headers, body


# -- cassettes --------------------------------------------------------------------------------------------

REASONS = {200: "OK", 400: "Bad Request"}


def write_cassette(path: Path, calls: list[tuple[str, str, str | None, tuple[int, dict[str, str], str]]]) -> None:
    requests_, responses = [], []
    for method, uri, body, (status, headers, text) in calls:
        req_headers = {"User-Agent": USER_AGENT, "Accept-Encoding": "gzip, deflate", "Accept": "*/*",
                       "Connection": "keep-alive"}
        if body is not None:
            req_headers["Content-Type"] = "application/x-www-form-urlencoded"
            req_headers["Content-Length"] = str(len(body.encode()))
        requests_.append(Request(method, uri, body, req_headers))
        data = text.encode("utf-8")
        responses.append({
            "status": {"code": status, "message": REASONS[status]},
            "headers": {**{k: [v] for k, v in headers.items()}, "Content-Length": [str(len(data))]},
            "body": {"string": data},
        })
    path.write_text(serialize({"requests": requests_, "responses": responses}, yamlserializer), encoding="utf-8")


def main() -> None:
    content, lake = build_content()
    write_content(content, HERE / "content.osm")
    planet = load(HERE / "content.osm", content)
    grid = sample_grid(*CENTRE, ZOOM)
    box = pad_bbox(grid.bbox, PAD_METRES)
    in_box = sum(1 for lon, lat, _ in planet.nodes.values() if inside(lon, lat, box))
    assert in_box > SPLIT_NODE_LIMIT, in_box
    single = api_session(planet, box, node_limit=50_000)
    split = api_session(planet, box, node_limit=SPLIT_NODE_LIMIT)
    assert any(uri.endswith(f"/relation/{lake}/full") for _, uri, _, _ in single), "lake must need relation/full"
    assert sum(1 for *_, a in split if a[0] == 400) >= 2, "the split must recurse at least once"
    write_cassette(HERE / "api_map.yaml", single)
    write_cassette(HERE / "api_split.yaml", split)
    query = overpass_query(load_class_table("classes13.toml"), box)
    write_cassette(HERE / "overpass.yaml",
                   [("POST", DEFAULT_OVERPASS_URL, urlencode({"data": query}), overpass_answer(planet, query))])
    scenario = {
        "centre": list(CENTRE), "zoom": ZOOM, "pad_metres": PAD_METRES, "fetch_bbox": list(box),
        "api_date": API_DATE, "osm_base": OSM_BASE, "lake_relation": lake,
        "split_node_limit": SPLIT_NODE_LIMIT, "nodes_in_fetch_bbox": in_box,
        "api_calls": [uri for _, uri, _, _ in single], "api_split_calls": [(uri, a[0]) for _, uri, _, a in split],
    }
    (HERE / "scenario.json").write_text(json.dumps(scenario, indent=1) + "\n", encoding="utf-8")
    print(f"wrote content.osm ({len(planet.nodes)} nodes, {len(planet.ways)} ways, {len(planet.relations)} relations), "
          f"{len(single)} + {len(split)} API calls, 1 Overpass call; {in_box} nodes in the fetched box")


if __name__ == "__main__":
    main()
