"""OSM data from the OpenStreetMap editing API 0.6 (``--osm api``).

``GET {base}/map?bbox=left,bottom,right,top`` returns every node in the box, every way using
one of them with all its nodes, and every relation that references any of those, but only as
a record: a multipolygon whose other member ways lie outside the box arrives without them.
For each ``type=multipolygon`` relation with some but not all member ways in the answer this
source also fetches ``{base}/relation/{id}/full`` (the relation, its member ways and their
nodes) as another file.  Together that is the content :mod:`osmseg.osm.base` promises.

Limits of the API (https://wiki.openstreetmap.org/wiki/API_v0.6) and what happens:

* area over 0.25 square degrees: HTTP 400 ("The maximum bbox size is 0.25..."). Boxes are
  split into quadrants *before* asking until each is under the limit.
* over 50,000 nodes: HTTP 400 ("You requested too many nodes (limit is 50000)..."). The box
  is split into quadrants and each asked again, recursively up to ``max_split_depth`` times
  (then :class:`~osmseg.errors.OSMLimitError`: use a local ``.osm.pbf``).
* HTTP 509 "bandwidth limit exceeded": a one-line ``NetworkError`` (wait, then rerun).
* at most 2 concurrent requests per client: enforced by the shared
  :class:`~osmseg.net.http.HttpClient` (``host_limits["api.openstreetmap.org"] = 2``).

Timestamp: the API serves live data, and its XML has no replication timestamp.  The
extract's timestamp is the HTTP ``Date`` of the answer (the earliest one when the box took
several calls): the database state the data reflects, to the second.  The newest element
timestamp in the answer is only a lower bound (the last edit in the box, possibly years
old), so it is recorded in ``info["newest_element"]`` but not used as the timestamp.

Answers are written as they are (``.osm`` XML) under ``workdir/api_<box>_<hash>/`` and an
``api_<box>_<hash>.json`` marker is written last; a rerun with the marker present makes no
request.  Malformed XML never reaches the parser: it raises a one-line ``OSMDataError``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from email.utils import parsedate_to_datetime
from pathlib import Path
from typing import Any

import requests

from osmseg.errors import HTTPStatusError, NetworkError, OSMDataError, OSMLimitError
from osmseg.grid import LngLatBBox
from osmseg.net.http import HttpClient
from osmseg.osm.base import OsmExtract
from osmseg.osm.store import (
    OSM_ATTRIBUTION,
    OsmScan,
    bbox_label,
    cache_name,
    check_bbox,
    iso_utc,
    read_done,
    store_osm_xml,
    write_done,
)
from osmseg.redact import redact

logger = logging.getLogger(__name__)

DEFAULT_API_URL = "https://api.openstreetmap.org/api/0.6"
#: Largest box the API serves, in square degrees.
MAX_AREA = 0.25
#: Texts of the API's HTTP 400 answers that mean "this box is too big: ask for less".
LIMIT_MESSAGES = ("too many nodes", "maximum bbox size")
_ADVICE = ("run the same command again later, "
           "or use --osm overpass or a local .osm.pbf")


def bbox_param(bbox: LngLatBBox) -> str:
    """The API's ``bbox`` parameter: left,bottom,right,top with OSM's 7 decimals.

    >>> bbox_param(LngLatBBox(13.4, 52.5, 13.41, 52.51))
    '13.4000000,52.5000000,13.4100000,52.5100000'
    """
    return ",".join(f"{v:.7f}" for v in bbox)


def quadrants(bbox: LngLatBBox) -> tuple[LngLatBBox, ...]:
    """The four quarters of ``bbox``: south-west, south-east, north-west, north-east.

    >>> [tuple(q) for q in quadrants(LngLatBBox(0, 0, 2, 2))]
    [(0, 0, 1.0, 1.0), (1.0, 0, 2, 1.0), (0, 1.0, 1.0, 2), (1.0, 1.0, 2, 2)]
    """
    w, s, e, n = bbox
    mx, my = (w + e) / 2, (s + n) / 2
    return (LngLatBBox(w, s, mx, my), LngLatBBox(mx, s, e, my), LngLatBBox(w, my, mx, n), LngLatBBox(mx, my, e, n))


def split_to_area(bbox: LngLatBBox, max_area: float = MAX_AREA) -> list[LngLatBBox]:
    """``bbox`` cut into quadrants, recursively, until each piece is at most ``max_area`` deg².

    >>> len(split_to_area(LngLatBBox(0, 0, 0.5, 0.5))), len(split_to_area(LngLatBBox(0, 0, 0.6, 0.6)))
    (1, 4)
    >>> len(split_to_area(LngLatBBox(0, 0, 1.2, 1.2)))
    16
    """
    if (bbox.east - bbox.west) * (bbox.north - bbox.south) <= max_area:
        return [bbox]
    return [piece for q in quadrants(bbox) for piece in split_to_area(q, max_area)]


def is_limit_answer(text: str) -> bool:
    """True if an HTTP 400 body says the box is over the area or node limit.

    >>> is_limit_answer("You requested too many nodes (limit is 50000). Either request a smaller area, or use planet.osm")
    True
    >>> is_limit_answer("The latitudes must be between -90 and 90")
    False
    """
    lowered = text.lower()
    return any(m in lowered for m in LIMIT_MESSAGES)


def _date(response: requests.Response) -> str | None:
    """The response's HTTP ``Date`` as ISO 8601 UTC, None if absent or unreadable."""
    value = response.headers.get("Date")
    if not value:
        return None
    try:
        return iso_utc(parsedate_to_datetime(value))
    except (TypeError, ValueError):
        return None


class OsmApiSource:
    """OSM data for a box from the OSM API 0.6 ``map`` call (see the module doc).

    Args:
        client: the shared HTTP client (cache, retries, per-host limit of 2 for the API).
        workdir: folder for the downloaded files (created).
        base_url: the API root, e.g. the dev server ``https://master.apis.dev.openstreetmap.org/api/0.6``.
        max_split_depth: how many times a box refused for the node limit is quartered.
    """

    name = "api"
    attribution = OSM_ATTRIBUTION

    def __init__(self, client: HttpClient, workdir: Path, base_url: str = DEFAULT_API_URL,
                 max_split_depth: int = 4) -> None:
        self.client = client
        self.workdir = Path(workdir)
        self.base_url = base_url.rstrip("/")
        self.max_split_depth = max_split_depth

    def fetch(self, bbox: LngLatBBox) -> OsmExtract:
        """Download (or reuse) the OSM data for ``bbox``; raises OSMDataError or NetworkError."""
        bbox = check_bbox(bbox)
        stem = cache_name("api", bbox, self.base_url)
        marker = self.workdir / f"{stem}.json"
        done = read_done(marker)
        if done is not None:
            return done
        folder = self.workdir / stem
        folder.mkdir(parents=True, exist_ok=True)
        parts: list[tuple[Path, OsmScan, str | None]] = []
        for piece in split_to_area(bbox):
            self._fetch_map(piece, 0, folder, parts)
        ways = set().union(*(scan.way_ids for _, scan, _ in parts))
        multipolygons: dict[int, tuple[int, ...]] = {}
        for _, scan, _ in parts:
            multipolygons.update(scan.multipolygons)
        incomplete = sorted(rid for rid, members in multipolygons.items()
                            if any(w in ways for w in members) and not all(w in ways for w in members))
        completed = []
        for rid in incomplete:
            part = self._fetch_relation(rid, folder)
            if part is not None:
                parts.append(part)
                completed.append(rid)
        dates = [d for _, _, d in parts if d is not None]
        newest = [s.newest for _, s, _ in parts if s.newest is not None]
        info: dict[str, Any] = {
            "source": "api",
            "url": redact(self.base_url),
            "bbox": list(bbox),
            "map_calls": sum(1 for p, _, _ in parts if p.name.startswith("map_")),
            "relations_completed": completed,
            "timestamp_from": "HTTP Date of the API answer (earliest when split)",
            "newest_element": max(newest) if newest else None,
        }
        extract = OsmExtract(paths=tuple(p for p, _, _ in parts), timestamp=min(dates) if dates else None, info=info)
        return write_done(marker, extract)

    def describe(self) -> dict[str, Any]:
        """JSON-able description for the manifest."""
        return {"source": "api", "url": redact(self.base_url), "attribution": self.attribution}

    # -- internals ------------------------------------------------------------------------------

    def _get(self, url: str, params: dict[str, str] | None = None,
             store: Callable[[requests.Response], OsmScan] | None = None) -> tuple[requests.Response, OsmScan | None]:
        """GET an API call; ``store`` keeps a 200's OSM XML, and XML it cannot read is fetched again."""
        try:
            return self.client.fetch(url, store or (lambda r: None), params=params, ok_statuses=(400, 404, 410),
                                     corrupt=(OSMDataError,))
        except HTTPStatusError as exc:
            if exc.status == 509:
                raise NetworkError(f"the OSM API says this client downloaded too much (HTTP 509, bandwidth "
                                   f"limit exceeded) at {url}: wait an hour and run the same command again, "
                                   "or use a local .osm.pbf") from None
            raise

    def _fetch_map(self, box: LngLatBBox, depth: int, folder: Path,
                   parts: list[tuple[Path, OsmScan, str | None]]) -> None:
        """Fetch one box into ``parts``, quartering it while the API says it is too big."""
        path = folder / f"map_{bbox_label(box)}.osm"
        url = f"{self.base_url}/map"
        origin = f"the OSM API answer to map?bbox={bbox_param(box)}"
        response, scan = self._get(url, {"bbox": bbox_param(box)},
                                   lambda r: store_osm_xml(r.content, path, origin, _ADVICE))
        if response.status_code != 200:
            text = response.text.strip()
            if response.status_code == 400 and is_limit_answer(text):
                if depth >= self.max_split_depth:
                    raise OSMLimitError(f"the OSM API still refuses box {bbox_param(box)} after splitting it "
                                        f"{depth} times ({_one_line(text)}): use a local .osm.pbf (--osm PATH) "
                                        "or --osm overpass for such dense areas")
                logger.info("OSM API: box %s over its limit (%s); asking for its quarters", bbox_param(box), _one_line(text))
                for quarter in quadrants(box):
                    self._fetch_map(quarter, depth + 1, folder, parts)
                return
            raise OSMDataError(f"the OSM API refused map?bbox={bbox_param(box)} with HTTP {response.status_code} "
                               f"({_one_line(text)}): check the box, or use --osm overpass or a local .osm.pbf")
        assert scan is not None  # a 200: stored by _get
        parts.append((path, scan, _date(response)))

    def _fetch_relation(self, rid: int, folder: Path) -> tuple[Path, OsmScan, str | None] | None:
        """The full relation ``rid`` (members and their nodes), None if it is gone (404/410)."""
        path = folder / f"relation_{rid}.osm"
        origin = f"the OSM API answer to relation/{rid}/full"
        response, scan = self._get(f"{self.base_url}/relation/{rid}/full",
                                   store=lambda r: store_osm_xml(r.content, path, origin, _ADVICE))
        if response.status_code in (404, 410):
            logger.warning("OSM API: multipolygon relation %d is gone (HTTP %d); drawing it from what the map "
                           "call returned", rid, response.status_code)
            return None
        if response.status_code != 200:
            raise OSMDataError(f"the OSM API refused relation/{rid}/full with HTTP {response.status_code} "
                               f"({_one_line(response.text)}): {_ADVICE}")
        assert scan is not None
        return path, scan, _date(response)


def _one_line(text: str, limit: int = 160) -> str:
    """First line of a server message, shortened, for one-line errors."""
    line = (text.strip().splitlines() or [""])[0].strip()
    return line if len(line) <= limit else line[: limit - 1] + "…"
