"""OSM data from an Overpass API server (``--osm overpass`` or ``overpass:URL``).

Overpass answers queries, so this source asks only for what the class table can draw: one
filter per class rule (element kind from the rule's geometry: points are nodes, lines are
ways, areas are ways and ``type=multipolygon`` relations), plus ``natural=coastline`` ways
when the table draws sea; filters another one already covers are dropped.  The query then
recurses down (``(._;>;);``) so every way comes with all its nodes and every relation with
its member ways and their nodes, and prints the result as OSM XML (``out body``), which
osmium reads like any other ``.osm`` file::

    [out:xml][timeout:180][bbox:south,west,north,east];
    (
      way["building"];
      relation["building"]["type"="multipolygon"];
      ...
    );
    (._;>;);
    out body;

What differs from the API ``map`` call: Overpass's ``(bbox)`` also selects ways whose
*segments* cross the box without a node inside it, so it may return a few more features;
the builder asks for a padded box, so a sample's masks are the same (tested).

Timestamp: ``<meta osm_base="..."/>`` in the answer, the minutely-diff state of the
server's database: the OSM state the data reflects.

Errors: 429 and 504 are retried by the :class:`~osmseg.net.http.HttpClient`.  Overpass also
answers HTTP 200 with a ``<remark> runtime error: ...</remark>`` (query timed out, out of
memory) and partial or no data: that raises :class:`~osmseg.errors.OSMLimitError` (time or
memory: use a smaller box, a longer timeout or a local file) or ``OSMDataError``, never
silently incomplete labels.  Malformed XML raises ``OSMDataError``.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from osmseg.classes import ClassTable, load_class_table
from osmseg.errors import CorruptResponse, OSMDataError, OSMLimitError
from osmseg.grid import LngLatBBox
from osmseg.net.http import HttpClient
from osmseg.osm.base import OsmExtract
from osmseg.osm.store import OSM_ATTRIBUTION, OsmScan, cache_name, check_bbox, read_done, store_osm_xml, write_done
from osmseg.redact import redact

logger = logging.getLogger(__name__)

DEFAULT_OVERPASS_URL = "https://overpass-api.de/api/interpreter"
#: Server-side time limit asked for, in seconds (Overpass's default is 180).
DEFAULT_TIMEOUT = 180
_ELEMENTS = {"point": ("node",), "line": ("way",), "area": ("way", "relation")}
_REMARK = re.compile(rb"<remark>\s*(.*?)\s*</remark>", re.DOTALL)
_OSM_BASE = re.compile(rb"<meta\s+osm_base=\"([^\"]+)\"")
_ERE_SPECIAL = re.compile(r"([\\.^$|?*+()\[\]{}])")

#: A tag condition: key and its allowed values; None means "any value".
Condition = tuple[str, "tuple[str, ...] | None"]


@dataclass(frozen=True, order=True)
class TagFilter:
    """One Overpass query statement: an element kind and tag conditions that must all hold.

    >>> TagFilter("way", (("highway", ("primary", "secondary")),)).ql()
    'way["highway"~"^(primary|secondary)$"];'
    >>> TagFilter("relation", (("building", None), ("type", ("multipolygon",)))).ql()
    'relation["building"]["type"="multipolygon"];'
    """

    element: str
    conditions: tuple[Condition, ...]

    def ql(self) -> str:
        """The Overpass QL statement (the global ``[bbox:...]`` applies to it)."""
        parts = []
        for key, values in self.conditions:
            if values is None:
                parts.append(f"[{_quote(key)}]")
            elif len(values) == 1:
                parts.append(f"[{_quote(key)}={_quote(values[0])}]")
            else:
                alternatives = "|".join(_ERE_SPECIAL.sub(r"\\\1", v) for v in values)
                parts.append(f"[{_quote(key)}~{_quote(f'^({alternatives})$')}]")
        return f"{self.element}{''.join(parts)};"

    def matches(self, element: str, tags: Mapping[str, str]) -> bool:
        """True if an element of kind ``element`` with ``tags`` passes this filter.

        >>> f = TagFilter("way", (("highway", None),))
        >>> f.matches("way", {"highway": "track"}), f.matches("node", {"highway": "track"})
        (True, False)
        """
        if element != self.element:
            return False
        return all(key in tags and (values is None or tags[key] in values) for key, values in self.conditions)

    def covers(self, other: TagFilter) -> bool:
        """True if everything ``other`` selects is selected by this filter too.

        >>> broad = TagFilter("way", (("highway", None),))
        >>> broad.covers(TagFilter("way", (("highway", ("track",)), ("surface", ("dirt",)))))
        True
        >>> TagFilter("way", (("highway", ("track",)),)).covers(broad)
        False
        """
        if self.element != other.element:
            return False
        theirs = dict(other.conditions)
        for key, values in self.conditions:
            if key not in theirs:
                return False
            their_values = theirs[key]
            if values is not None and (their_values is None or not set(their_values) <= set(values)):
                return False
        return True


def _quote(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def tag_filters(table: ClassTable) -> tuple[TagFilter, ...]:
    """The filters that select every OSM element ``table`` can draw, and little else.

    A mapped table (classes6) uses the rules of its base table.  Negated keys (``!key``) are
    left out (the query fetches a superset; the parser applies the full rule).

    >>> fs = tag_filters(load_class_table("classes13.toml"))
    >>> any(f.matches("way", {"natural": "coastline"}) for f in fs)
    True
    >>> any(f.element == "node" and dict(f.conditions).get("natural") == ("tree",) for f in fs)
    True
    """
    rules_of = table.base if table.base is not None else table
    candidates: set[TagFilter] = set()
    for cls in rules_of.classes:
        for rule in cls.rules:
            conditions: list[Condition] = []
            for key, wanted in sorted(rule.tags.items()):
                if key.startswith("!"):
                    continue
                if wanted == "*":
                    conditions.append((key, None))
                elif isinstance(wanted, list):
                    conditions.append((key, tuple(sorted(set(map(str, wanted))))))
                else:
                    conditions.append((key, (str(wanted),)))
            if not conditions:
                continue
            for element in _ELEMENTS[rule.geometry]:
                extra: list[Condition] = [("type", ("multipolygon",))] if element == "relation" else []
                candidates.add(TagFilter(element, tuple(sorted(conditions + extra))))
    if rules_of.coastline_class is not None:
        candidates.add(TagFilter("way", (("natural", ("coastline",)),)))
    merged = _merge_single_key(candidates)
    kept = [f for f in merged if not any(g != f and g.covers(f) for g in merged)]
    return tuple(sorted(kept))


def _merge_single_key(filters: set[TagFilter]) -> set[TagFilter]:
    """Join filters on one key (``way[landuse=a]`` + ``way[landuse=b]`` -> ``way[landuse~a|b]``)."""
    single: dict[tuple[str, str, tuple[Condition, ...]], set[str] | None] = {}
    rest = set()
    for f in filters:
        plain = [c for c in f.conditions if c[0] != "type" or f.element != "relation"]
        fixed = tuple(c for c in f.conditions if c not in plain)
        if len(plain) != 1:
            rest.add(f)
            continue
        key, values = plain[0]
        slot = (f.element, key, fixed)
        if slot in single and single[slot] is None:
            continue
        single[slot] = None if values is None else (single.get(slot) or set()) | set(values)
    for (element, key, fixed), joined in single.items():
        condition: Condition = (key, None if joined is None else tuple(sorted(joined)))
        rest.add(TagFilter(element, tuple(sorted((condition, *fixed)))))
    return rest


def overpass_query(table: ClassTable, bbox: LngLatBBox, timeout: int = DEFAULT_TIMEOUT) -> str:
    """The Overpass QL query for ``bbox`` (see the module doc).

    >>> q = overpass_query(load_class_table(), LngLatBBox(24.94, 60.16, 24.95, 60.17))
    >>> q.splitlines()[0]
    '[out:xml][timeout:180][bbox:60.1600000,24.9400000,60.1700000,24.9500000];'
    >>> q.splitlines()[-2:]
    ['(._;>;);', 'out body;']
    """
    w, s, e, n = bbox
    head = f"[out:xml][timeout:{int(timeout)}][bbox:{s:.7f},{w:.7f},{n:.7f},{e:.7f}];"
    body = "\n".join(f"  {f.ql()}" for f in tag_filters(table))
    return f"{head}\n(\n{body}\n);\n(._;>;);\nout body;"


def remark_error(body: bytes) -> str | None:
    """The text of an Overpass ``<remark>`` reporting a runtime error, if any.

    >>> remark_error(b'<osm><remark> runtime error: Query timed out in "query" at line 3 after 26 seconds. </remark></osm>')
    'runtime error: Query timed out in "query" at line 3 after 26 seconds.'
    >>> remark_error(b"<osm><node id='1' lat='0' lon='0'/></osm>") is None
    True
    """
    for match in _REMARK.finditer(body):
        text = match.group(1).decode("utf-8", "replace")
        if "error" in text.lower():
            return " ".join(text.split())
    return None


def osm_base(body: bytes) -> str | None:
    """The ``osm_base`` timestamp of an Overpass answer (the data's state), if present.

    >>> osm_base(b'<osm><meta osm_base="2024-05-01T12:34:56Z"/></osm>')
    '2024-05-01T12:34:56Z'
    """
    match = _OSM_BASE.search(body[:4096])
    return match.group(1).decode() if match else None


class OverpassSource:
    """OSM data for a box from an Overpass API server (see the module doc).

    Args:
        client: the shared HTTP client (cache, retries on 429/504, 2 requests per host).
        workdir: folder for the downloaded files (created).
        table: the class table whose rules decide which tags are fetched (default classes13).
        url: the interpreter endpoint.
        timeout: server-side time limit in seconds (``[timeout:...]``).
    """

    name = "overpass"
    attribution = OSM_ATTRIBUTION

    def __init__(self, client: HttpClient, workdir: Path, table: ClassTable | None = None,
                 url: str = DEFAULT_OVERPASS_URL, timeout: int = DEFAULT_TIMEOUT) -> None:
        self.client = client
        self.workdir = Path(workdir)
        self.table = table if table is not None else load_class_table()
        self.url = url
        self.timeout = timeout

    def query(self, bbox: LngLatBBox) -> str:
        """The query this source sends for ``bbox``."""
        return overpass_query(self.table, bbox, self.timeout)

    def fetch(self, bbox: LngLatBBox) -> OsmExtract:
        """Download (or reuse) the OSM data for ``bbox``; raises OSMDataError or NetworkError."""
        bbox = check_bbox(bbox)
        query = self.query(bbox)
        stem = cache_name("overpass", bbox, self.url, query)
        marker = self.workdir / f"{stem}.json"
        done = read_done(marker)
        if done is not None:
            return done
        where = f"Overpass ({redact(self.url)}) for box {','.join(f'{v:.7f}' for v in bbox)}"
        path = self.workdir / f"{stem}.osm"

        def store(response: Any) -> OsmScan:
            body = response.content
            error = remark_error(body)
            if error is not None:
                if re.search(r"timed out|out of memory|run out of memory", error, re.IGNORECASE):
                    raise OSMLimitError(f"{where} gave up: {error}; use smaller boxes, a longer Overpass timeout, "
                                        "or a local .osm.pbf (--osm PATH)")
                raise CorruptResponse(f"{where} failed: {error}; run the same command again later or use --osm api")
            try:
                return store_osm_xml(body, path, f"the answer of {where}",
                                     "run the same command again later, or use --osm api or a local .osm.pbf")
            except OSMDataError as exc:
                raise CorruptResponse(str(exc)) from None

        # bad XML or a runtime-error remark is fetched again like a 5xx (and never kept in the cache);
        # a time-out or out-of-memory remark is the box's size, which retrying does not change
        response, scan = self.client.fetch(self.url, store, method="POST", data={"data": query})
        assert scan is not None
        body = response.content
        info: dict[str, Any] = {
            "source": "overpass",
            "url": redact(self.url),
            "bbox": list(bbox),
            "timestamp_from": "osm_base of the Overpass answer",
            "counts": scan.counts,
        }
        return write_done(marker, OsmExtract(paths=(path,), timestamp=osm_base(body), info=info))

    def describe(self) -> dict[str, Any]:
        """JSON-able description for the manifest."""
        return {"source": "overpass", "url": redact(self.url), "timeout": self.timeout, "attribution": self.attribution,
                "filters": [f.ql() for f in tag_filters(self.table)]}
