#!/usr/bin/env python3
"""Write ``tinycity.osm``: a small synthetic OSM XML 0.6 town for the rasterisation tests.

Run it again to regenerate the file (deterministic; no network).  Every feature is placed in
the *pixel* coordinates (col, row) of the test grid (:func:`grid`: a 5x5 block of z18 tiles
around lon 24.94, lat 60.17 in Helsinki, 1280x1280 px of ~0.298 m on the ground), converted to
lon/lat through the grid's Web Mercator transform.  The tests import this module and check
pixels at the same (col, row) positions, so the constants below are the layout:

========================  ======================================================================
feature                   where (col, row) / tags
========================  ======================================================================
courtyard building        multipolygon relation building=yes: outer 100..300, inner 160..240
building in park          way building=yes 400..480 x 100..180 on leisure=park 350..650 x 60..330
residential road          row 450, col -50..1330 (crosses the box), lanes=2 -> 7 m
primary road              col 1000, row -50..1330, width=12
footway                   col 700, row 350..560, crossing the residential road
track / gravel road       row 1200 / row 1100, col 50..600 (highway=track; residential+gravel)
grass / wood              50..300 x 550..750 / 350..650 x 550..750
lake with island          multipolygon natural=water 50..450 x 800..1050 (two outer ways),
                          island 200..300 x 880..970
river                     waterway=river width=8, col 1150, row 480..1190
bridge                    residential bridge=yes, row 1000, col 1080..1230 (over the river)
tunnel                    primary tunnel=yes, col 1080, row 500..850 (never drawn)
parking / construction    750..950 x 80..250 / 750..950 x 280..400
industrial / beach        1050..1250 x 80..350 / 1180..1270 x 850..950
trees                     natural=tree nodes at (800, 600) (default crown 5 m) and (850, 600)
                          (diameter_crown=8); tree_row from (780, 700) to (950, 700)
pedestrian square         highway=pedestrian area=yes 500..650 x 800..900
footway loop              closed highway=footway way, no area tag, 520..630 x 920..980
coastline                 (400, 1930) to (1930, 400), col + row = 2330: sea in the south-east
broken: unclosed          building way 500..560 x 1000..1060 whose last node is not its first
broken: self-intersecting landuse=grass bow tie (800,800) (900,900) (900,800) (800,900)
broken: missing node      building 600..680 x 1000..1060 whose ring references node 999999
broken: missing member    landuse=forest relation: outer way 720..950 x 960..1060 present,
                          inner way 888888 absent (osmium cannot assemble it)
broken: open relation     landuse=grass relation: a U-shaped way in 1180..1270 x 550..650 and
                          an absent way 888889: no ring closes, skipped
========================  ======================================================================
"""

from __future__ import annotations

import sys
from pathlib import Path
from xml.sax.saxutils import quoteattr

import mercantile

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from osmseg.grid import SampleGrid, sample_grid

HERE = Path(__file__).resolve().parent
OSM_FILE = HERE / "tinycity.osm"
LON, LAT, ZOOM = 24.94, 60.17, 18

COURTYARD_OUTER = (100, 100, 300, 300)  # col0, row0, col1, row1
COURTYARD_INNER = (160, 160, 240, 240)
PARK = (350, 60, 650, 330)
PARK_BUILDING = (400, 100, 480, 180)
ROAD_ROW, ROAD_LANES = 450, 2
PRIMARY_COL, PRIMARY_WIDTH = 1000, 12.0
FOOTWAY_COL, FOOTWAY_ROWS = 700, (350, 560)
TRACK_ROW, GRAVEL_ROW, DIRT_COLS = 1200, 1100, (50, 600)
GRASS = (50, 550, 300, 750)
WOOD = (350, 550, 650, 750)
LAKE = (50, 800, 450, 1050)
ISLAND = (200, 880, 300, 970)
RIVER_COL, RIVER_ROWS, RIVER_WIDTH = 1150, (480, 1190), 8.0
BRIDGE_ROW, BRIDGE_COLS = 1000, (1080, 1230)
TUNNEL_COL, TUNNEL_ROWS = 1080, (500, 850)
PARKING = (750, 80, 950, 250)
CONSTRUCTION = (750, 280, 950, 400)
INDUSTRIAL = (1050, 80, 1250, 350)
BEACH = (1180, 850, 1270, 950)
TREE, BIG_TREE, BIG_TREE_CROWN = (800, 600), (850, 600), 8.0
TREE_ROW = ((780, 700), (950, 700))
SQUARE = (500, 800, 650, 900)
LOOP = (520, 920, 630, 980)
COAST = ((400, 1930), (1930, 400))  # col + row = 2330; land on the left (north-west), sea on the right
UNCLOSED_BUILDING = (500, 1000, 560, 1060)
BOWTIE = ((800, 800), (900, 900), (900, 800), (800, 900))
MISSING_NODE_BUILDING = (600, 1000, 680, 1060)
FOREST = (720, 960, 950, 1060)
OPEN_RELATION = ((1180, 550), (1180, 650), (1270, 650), (1270, 550))
MISSING_NODE, MISSING_WAYS = 999999, (888888, 888889)


def grid() -> SampleGrid:
    """The sample grid the tests rasterise tinycity on."""
    return sample_grid(LON, LAT, ZOOM)


def lonlat(col: float, row: float) -> tuple[float, float]:
    """Pixel (col, row) of :func:`grid` (pixel corners at integers) to (lon, lat)."""
    x, y = grid().transform @ (col, row)
    ll = mercantile.lnglat(x, y)
    return ll.lng, ll.lat


def rect(box: tuple[int, int, int, int]) -> list[tuple[int, int]]:
    """Corners of a (col0, row0, col1, row1) box, clockwise on screen, first repeated."""
    c0, r0, c1, r1 = box
    return [(c0, r0), (c1, r0), (c1, r1), (c0, r1), (c0, r0)]


class OsmWriter:
    """Collects nodes, ways and relations (ids in creation order) and writes OSM XML 0.6."""

    def __init__(self) -> None:
        self.nodes: list[str] = []
        self.ways: list[str] = []
        self.relations: list[str] = []
        self.next_id = {"node": 1, "way": 1, "relation": 1}
        self.at: dict[tuple[float, float], int] = {}

    def _id(self, kind: str) -> int:
        self.next_id[kind] += 1
        return self.next_id[kind] - 1

    def node(self, pixel: tuple[float, float], tags: dict[str, str] | None = None) -> int:
        """A node at a pixel position (untagged nodes at the same pixel are shared)."""
        if not tags and pixel in self.at:
            return self.at[pixel]
        nid = self._id("node")
        lon, lat = lonlat(*pixel)
        body = _tags(tags)
        attrs = f'id="{nid}" version="1" lat="{lat:.7f}" lon="{lon:.7f}"'
        self.nodes.append(f"  <node {attrs}>\n{body}  </node>" if body else f"  <node {attrs}/>")
        if not tags:
            self.at[pixel] = nid
        return nid

    def way(self, points: list[tuple[float, float]] | list[int], tags: dict[str, str] | None = None) -> int:
        """A way through pixel positions (or existing node ids)."""
        refs = [p if isinstance(p, int) else self.node(p) for p in points]
        wid = self._id("way")
        nds = "".join(f'    <nd ref="{r}"/>\n' for r in refs)
        self.ways.append(f'  <way id="{wid}" version="1">\n{nds}{_tags(tags)}  </way>')
        return wid

    def relation(self, members: list[tuple[int, str]], tags: dict[str, str]) -> int:
        """A multipolygon relation of (way id, role) members."""
        rid = self._id("relation")
        body = "".join(f'    <member type="way" ref="{ref}" role="{role}"/>\n' for ref, role in members)
        self.relations.append(f'  <relation id="{rid}" version="1">\n{body}{_tags({"type": "multipolygon", **tags})}  </relation>')
        return rid

    def xml(self) -> str:
        w, s, e, n = grid().bbox
        pad = 0.0005
        head = ("<?xml version='1.0' encoding='UTF-8'?>\n"
                '<osm version="0.6" generator="osmseg tests/data/tinycity/data.py">\n'
                f'  <bounds minlat="{s - pad:.7f}" minlon="{w - pad:.7f}" maxlat="{n + pad:.7f}" maxlon="{e + pad:.7f}"/>\n')
        return head + "\n".join(self.nodes + self.ways + self.relations) + "\n</osm>\n"


def _tags(tags: dict[str, str] | None) -> str:
    return "".join(f"    <tag k={quoteattr(k)} v={quoteattr(v)}/>\n" for k, v in (tags or {}).items())


def build() -> str:
    """The tinycity OSM XML text."""
    o = OsmWriter()
    # buildings: a courtyard multipolygon, and a building standing in a park
    outer = o.way(rect(COURTYARD_OUTER))
    inner = o.way(rect(COURTYARD_INNER))
    o.relation([(outer, "outer"), (inner, "inner")], {"building": "yes"})
    o.way(rect(PARK), {"leisure": "park", "name": "Tiny Park"})
    o.way(rect(PARK_BUILDING), {"building": "yes"})
    # roads
    o.way([(-50, ROAD_ROW), (FOOTWAY_COL, ROAD_ROW), (PRIMARY_COL, ROAD_ROW), (1330, ROAD_ROW)],
          {"highway": "residential", "lanes": str(ROAD_LANES)})
    o.way([(PRIMARY_COL, -50), (PRIMARY_COL, ROAD_ROW), (PRIMARY_COL, 1330)],
          {"highway": "primary", "width": f"{PRIMARY_WIDTH:g} m"})
    o.way([(FOOTWAY_COL, FOOTWAY_ROWS[0]), (FOOTWAY_COL, ROAD_ROW), (FOOTWAY_COL, FOOTWAY_ROWS[1])], {"highway": "footway"})
    o.way([(DIRT_COLS[0], TRACK_ROW), (DIRT_COLS[1], TRACK_ROW)], {"highway": "track", "tracktype": "grade3"})
    o.way([(DIRT_COLS[0], GRAVEL_ROW), (DIRT_COLS[1], GRAVEL_ROW)], {"highway": "residential", "surface": "gravel"})
    o.way([(TUNNEL_COL, TUNNEL_ROWS[0]), (TUNNEL_COL, TUNNEL_ROWS[1])], {"highway": "primary", "tunnel": "yes", "layer": "-1"})
    o.way([(BRIDGE_COLS[0], BRIDGE_ROW), (BRIDGE_COLS[1], BRIDGE_ROW)], {"highway": "residential", "bridge": "yes", "layer": "1"})
    o.way(rect(SQUARE), {"highway": "pedestrian", "area": "yes"})
    o.way(rect(LOOP), {"highway": "footway"})
    # land cover
    o.way(rect(GRASS), {"landuse": "grass"})
    o.way(rect(WOOD), {"natural": "wood"})
    o.way(rect(PARKING), {"amenity": "parking"})
    o.way(rect(CONSTRUCTION), {"landuse": "construction"})
    o.way(rect(INDUSTRIAL), {"landuse": "industrial"})
    o.way(rect(BEACH), {"natural": "beach"})
    # water: a lake whose outer ring is two ways, with an island; a river; the sea
    c0, r0, c1, r1 = LAKE
    north = o.way([(c0, r1), (c0, r0), (c1, r0)])
    south = o.way([(c1, r0), (c1, r1), (c0, r1)])
    island = o.way(rect(ISLAND), {"place": "islet"})
    o.relation([(north, "outer"), (south, "outer"), (island, "inner")], {"natural": "water", "water": "lake"})
    o.way([(RIVER_COL, RIVER_ROWS[0]), (RIVER_COL, BRIDGE_ROW), (RIVER_COL, RIVER_ROWS[1])],
          {"waterway": "river", "width": f"{RIVER_WIDTH:g}"})
    o.way([COAST[0], ((COAST[0][0] + COAST[1][0]) / 2, (COAST[0][1] + COAST[1][1]) / 2), COAST[1]], {"natural": "coastline"})
    # trees
    o.node(TREE, {"natural": "tree"})
    o.node(BIG_TREE, {"natural": "tree", "diameter_crown": f"{BIG_TREE_CROWN:g}"})
    o.way(list(TREE_ROW), {"natural": "tree_row"})
    # broken data
    o.way(rect(UNCLOSED_BUILDING)[:-1], {"building": "yes"})
    o.way([*BOWTIE, BOWTIE[0]], {"landuse": "grass"})
    c0, r0, c1, r1 = MISSING_NODE_BUILDING
    ids = [o.node((c0, r0)), o.node((c1, r0)), MISSING_NODE, o.node((c1, r1)), o.node((c0, r1))]
    o.way([*ids, ids[0]], {"building": "yes"})
    forest = o.way(rect(FOREST))
    o.relation([(forest, "outer"), (MISSING_WAYS[0], "inner")], {"landuse": "forest"})
    u_shape = o.way(list(OPEN_RELATION))
    o.relation([(u_shape, "outer"), (MISSING_WAYS[1], "outer")], {"landuse": "grass"})
    return o.xml()


def main() -> None:
    text = build()
    tmp = OSM_FILE.with_suffix(".osm.tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(OSM_FILE)
    print(f"wrote {OSM_FILE} ({len(text)} bytes)")


if __name__ == "__main__":
    main()
