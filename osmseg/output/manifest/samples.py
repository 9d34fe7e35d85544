"""The manifest's entries, typed: an accepted sample (:class:`SampleRecord`), a rejected attempt
(:class:`RejectionRecord`) and the parts they share (a centre, a tile, a source's provenance).

Each is a frozen value read from its JSON object by ``from_json`` (checked, one-line errors) and
written back by ``to_json``: the same object, key for key and value for value (keys the record
does not know are kept in ``extra``), so a manifest read and written again has the same bytes.
Schema: ``docs/dataset-format.md``. Imports: osmseg.errors.

>>> tile = TileRecord.from_json({"z": 3, "x": 3, "y": 5, "quadkey": "213"}, "t")
>>> tile.quadkey, tile.to_json() == {"z": 3, "x": 3, "y": 5, "quadkey": "213"}
('213', True)
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from osmseg.errors import DatasetError
from osmseg.output.manifest.values import (
    Json,
    JsonObject,
    extra_keys,
    int_map,
    json_object,
    number_list,
    optional_bool,
    optional_int,
    optional_number,
    string_list,
    text,
)

__all__ = ["SAMPLE_KEYS", "TERMS_KEYS", "Point", "Provenance", "RejectionRecord", "SampleRecord", "TileRecord"]

#: Keys every entry of ``samples`` has.
SAMPLE_KEYS = (
    "name", "center", "bbox_wgs84", "bounds_3857", "zoom", "ground_resolution_m", "tiles",
    "imagery", "osm", "class_histogram", "files",
)
#: The keys of an imagery provider's record that state its terms, in the order ATTRIBUTION.md lists them.
TERMS_KEYS = ("copyright", "terms", "terms_url", "terms_of_use", "license", "licence", "license_url", "brand_logo_uri")


@dataclass(frozen=True, slots=True)
class Point:
    """A centre in degrees: ``{"lon", "lat"}``."""

    lon: float
    lat: float

    @classmethod
    def from_json(cls, value: object, where: str) -> Point | None:
        if value is None:
            return None
        data = json_object(value, where)
        if set(data) != {"lon", "lat"}:
            raise DatasetError(f"{where} must be {{lon, lat}} or null, not {value!r}; rebuild the dataset")
        lon, lat = (optional_number(data[k], f"{where}.{k}") for k in ("lon", "lat"))
        if lon is None or lat is None:
            raise DatasetError(f"{where} must hold two numbers, not {value!r}; rebuild the dataset")
        return cls(lon, lat)

    def to_json(self) -> JsonObject:
        return {"lon": self.lon, "lat": self.lat}


@dataclass(frozen=True, slots=True)
class TileRecord:
    """One Web Mercator tile of a sample: ``{"z", "x", "y", "quadkey"}``."""

    z: int
    x: int
    y: int
    quadkey: str

    @classmethod
    def from_json(cls, value: object, where: str) -> TileRecord:
        if type(value) is dict:  # the common case first: a manifest lists 25 tiles a sample
            z, x, y, quadkey = value.get("z"), value.get("x"), value.get("y"), value.get("quadkey")
            if type(z) is int and type(x) is int and type(y) is int and type(quadkey) is str:
                return cls(z, x, y, quadkey)
        data = json_object(value, where)
        z, x, y = (optional_int(data.get(k), f"{where}.{k}") for k in ("z", "x", "y"))
        if z is None or x is None or y is None:
            raise DatasetError(f"{where} must have z, x, y and quadkey, not {value!r}; rebuild the dataset")
        return cls(z, x, y, text(data.get("quadkey"), f"{where}.quadkey"))

    def to_json(self) -> JsonObject:
        return {"z": self.z, "x": self.x, "y": self.y, "quadkey": self.quadkey}


@dataclass(frozen=True)
class Provenance:
    """Where a source's data came from, as the source describes itself (``describe()`` of an imagery
    provider or an OSM source, or a sample's ``Imagery.info``/``OsmExtract.info``): its own keys,
    kept whole in ``fields``; the ones osmseg's texts use are properties (None when absent or empty)."""

    fields: Mapping[str, Json] = field(default_factory=dict)

    @classmethod
    def from_json(cls, value: object, where: str) -> Provenance:
        return cls(json_object(value, where))

    def to_json(self) -> JsonObject:
        return dict(self.fields)

    def _text(self, key: str) -> str | None:
        value = self.fields.get(key)
        return str(value) if value else None

    @property
    def name(self) -> str | None:
        return self._text("name")

    @property
    def provider(self) -> str | None:
        return self._text("provider")

    @property
    def attribution(self) -> str | None:
        return self._text("attribution")

    @property
    def copyright(self) -> str | None:
        return self._text("copyright")

    @property
    def terms(self) -> str | None:
        return self._text("terms")

    @property
    def terms_url(self) -> str | None:
        """The provider's terms page (not ``url``/``template``: those are tile URLs)."""
        return self._text("terms_url")

    @property
    def brand_logo_uri(self) -> str | None:
        return self._text("brand_logo_uri")

    def stated_terms(self) -> list[tuple[str, str]]:
        """(key, value) of every :data:`TERMS_KEYS` the source states, in that order."""
        return [(key, value) for key in TERMS_KEYS if (value := self._text(key))]

    @property
    def uniform_tiles(self) -> tuple[str, ...] | None:
        """A sample's tiles of one colour (``z/x/y``), when its imagery record lists them."""
        tiles = self.fields.get("uniform_tiles")
        return None if tiles is None else string_list(tiles, "imagery uniform_tiles")

    @property
    def source(self) -> str | None:
        """An OSM source's kind: ``api``, ``overpass``, ``file``, ``geojson``, ..."""
        return self._text("source")

    @property
    def path(self) -> str | None:
        """The file of a file source (an OSM extract, a GeoJSON file)."""
        return self._text("path")

    @property
    def timestamp(self) -> str | None:
        """The OSM data's date (ISO 8601) when the source reports one."""
        return self._text("timestamp")

    @property
    def newest_element(self) -> str | None:
        """The edit date of the newest OSM element in a sample's box (ISO 8601), when known."""
        return self._text("newest_element")

    @property
    def timestamp_from(self) -> str | None:
        """Where ``timestamp`` comes from (``newest element``, a file's modification time, ...)."""
        return self._text("timestamp_from")


def _files(value: object, where: str) -> dict[str, str]:
    data = json_object(value, where)
    if not all(isinstance(v, str) for v in data.values()):
        raise DatasetError(f"{where} must map relative paths to sha256 strings; rebuild the dataset")
    for rel in data:
        if rel.startswith("/") or ".." in rel.split("/"):  # as PurePosixPath(rel) would say, a tenth of the time
            raise DatasetError(f"{where} lists a path outside the dataset: {rel!r}; restore the manifest.json")
    return {k: v for k, v in data.items() if isinstance(v, str)}


_SAMPLE_KNOWN = frozenset((*SAMPLE_KEYS, "osm_problems", "osm_unplaced", "overlap_group"))


@dataclass(frozen=True)
class SampleRecord:
    """An accepted sample (``samples[i]``): where it lies, its tiles and sources, its pixels per
    class and its files with their SHA-256. A dataset not made by a build may leave the places
    null (``center``, ``bbox_wgs84``, ``bounds_3857``, ``zoom``, ``ground_resolution_m``)."""

    name: str
    center: Point | None
    bbox_wgs84: tuple[float, ...] | None  # [W, S, E, N] degrees of the whole tile block ((): not recorded)
    bounds_3857: tuple[float, ...] | None  # [left, bottom, right, top] Web Mercator metres ((): not recorded)
    zoom: int | None
    ground_resolution_m: float | None
    tiles: tuple[TileRecord, ...]
    imagery: Provenance
    osm: Provenance
    class_histogram: Mapping[str, int]  # pixels per class name
    files: Mapping[str, str]  # relative path -> sha256 hex
    osm_problems: tuple[str, ...] | None = None  # broken OSM objects repaired or skipped (None: not recorded)
    osm_unplaced: int | None = None  # OSM objects of a class that could not be drawn (None: none)
    overlap_group: int | None = None  # samples of one group share pixels (None: not recorded)
    extra: Mapping[str, Json] = field(default_factory=dict)

    @classmethod
    def from_json(cls, value: object, where: str = "sample") -> SampleRecord:
        """A sample from its JSON object; ``where`` names it in errors (``manifest.json samples[3]``)."""
        data = json_object(value, where)
        missing = [k for k in SAMPLE_KEYS if k not in data]
        name = data.get("name")
        if missing:
            raise DatasetError(f"{where} ({name if isinstance(name, str) else '?'}) is missing {missing}; "
                               "rebuild the dataset")
        name = text(name, f"{where}.name")
        at = f"{where} ({name})"
        tiles = data["tiles"]
        if not isinstance(tiles, list):
            raise DatasetError(f"{at} tiles must be a list; rebuild the dataset")
        problems = data.get("osm_problems")
        return cls(
            name=name, center=Point.from_json(data["center"], f"{at} center"),
            bbox_wgs84=_box(data["bbox_wgs84"], f"{at} bbox_wgs84"),
            bounds_3857=_box(data["bounds_3857"], f"{at} bounds_3857"),
            zoom=optional_int(data["zoom"], f"{at} zoom"),
            ground_resolution_m=optional_number(data["ground_resolution_m"], f"{at} ground_resolution_m"),
            tiles=tuple(TileRecord.from_json(t, f"{at} tiles[{i}]") for i, t in enumerate(tiles)),
            imagery=Provenance.from_json(data["imagery"], f"{at} imagery"),
            osm=Provenance.from_json(data["osm"], f"{at} osm"),
            class_histogram=int_map(data["class_histogram"], f"{at} class_histogram"),
            files=_files(data["files"], f"{at} files"),
            osm_problems=None if problems is None else string_list(problems, f"{at} osm_problems"),
            osm_unplaced=optional_int(data.get("osm_unplaced"), f"{at} osm_unplaced"),
            overlap_group=optional_int(data.get("overlap_group"), f"{at} overlap_group"),
            extra=extra_keys(data, _SAMPLE_KNOWN))

    def to_json(self) -> JsonObject:
        """The JSON object :meth:`from_json` reads (the one it read, for a record read)."""
        out: JsonObject = {
            "name": self.name, "center": None if self.center is None else self.center.to_json(),
            "bbox_wgs84": None if self.bbox_wgs84 is None else list(self.bbox_wgs84),
            "bounds_3857": None if self.bounds_3857 is None else list(self.bounds_3857),
            "zoom": self.zoom, "ground_resolution_m": self.ground_resolution_m,
            "tiles": [t.to_json() for t in self.tiles], "imagery": self.imagery.to_json(), "osm": self.osm.to_json(),
            "class_histogram": dict(self.class_histogram), "files": dict(self.files),
        }
        if self.osm_problems is not None:
            out["osm_problems"] = list(self.osm_problems)
        if self.osm_unplaced is not None:
            out["osm_unplaced"] = self.osm_unplaced
        if self.overlap_group is not None:
            out["overlap_group"] = self.overlap_group
        return {**out, **self.extra}

    def bounds(self) -> tuple[float, float, float, float] | None:
        """``bounds_3857`` as (left, bottom, right, top), None when the manifest does not record it."""
        if not self.bounds_3857:
            return None
        left, bottom, right, top = self.bounds_3857
        return left, bottom, right, top

    def file_in(self, folder: str) -> str | None:
        """The sample's first file (sorted) under ``folder`` (``images``, ``labels``, ...), None when it lists none."""
        return next((rel for rel in sorted(self.files) if rel.startswith(f"{folder}/")), None)


def _box(value: object, where: str) -> tuple[float, ...] | None:
    """Four numbers, or null or an empty list (not recorded: a dataset made by hand)."""
    if value is None:
        return None
    return () if value == [] else number_list(value, 4, where)


_REJECTION_KEYS = ("center", "reason", "detail")
_REJECTION_KNOWN = frozenset((*_REJECTION_KEYS, "attempt", "slot", "osm_problems", "osm_unplaced", "uniform_tiles",
                              "osm_empty"))


@dataclass(frozen=True)
class RejectionRecord:
    """A rejected attempt (``rejected[i]``): its centre, why (``reason``, one of
    :data:`osmseg.output.manifest.REASONS`), a ``detail`` for humans, and what else it met."""

    center: Point | None
    reason: str
    detail: str
    attempt: int | None = None  # the attempt's number in its slot
    slot: int | None = None  # the slot it was tried for (the manifest's entries; a build's records have none)
    osm_problems: tuple[str, ...] | None = None
    osm_unplaced: int | None = None
    uniform_tiles: tuple[str, ...] | None = None  # z/x/y of its tiles of one colour
    osm_empty: bool | None = None  # True: no OSM object of any class over it
    extra: Mapping[str, Json] = field(default_factory=dict)

    @classmethod
    def from_json(cls, value: object, where: str = "rejected attempt") -> RejectionRecord:
        data = value if isinstance(value, dict) else None
        if data is None or not set(_REJECTION_KEYS) <= data.keys():
            raise DatasetError(f"{where} must have center, reason and detail; rebuild the dataset")
        data = json_object(data, where)
        problems, uniform = data.get("osm_problems"), data.get("uniform_tiles")
        return cls(
            center=Point.from_json(data["center"], f"{where} center"), reason=text(data["reason"], f"{where} reason"),
            detail=text(data["detail"], f"{where} detail"), attempt=optional_int(data.get("attempt"), f"{where} attempt"),
            slot=optional_int(data.get("slot"), f"{where} slot"),
            osm_problems=None if problems is None else string_list(problems, f"{where} osm_problems"),
            osm_unplaced=optional_int(data.get("osm_unplaced"), f"{where} osm_unplaced"),
            uniform_tiles=None if uniform is None else string_list(uniform, f"{where} uniform_tiles"),
            osm_empty=optional_bool(data.get("osm_empty"), f"{where} osm_empty"),
            extra=extra_keys(data, _REJECTION_KNOWN))

    def to_json(self) -> JsonObject:
        """The JSON object :meth:`from_json` reads (the one it read, for a record read)."""
        out: JsonObject = {"center": None if self.center is None else self.center.to_json(), "reason": self.reason,
                           "detail": self.detail}
        optional: dict[str, Json] = {
            "attempt": self.attempt, "slot": self.slot,
            "osm_problems": None if self.osm_problems is None else list(self.osm_problems),
            "osm_unplaced": self.osm_unplaced,
            "uniform_tiles": None if self.uniform_tiles is None else list(self.uniform_tiles),
            "osm_empty": self.osm_empty,
        }
        return {**out, **{k: v for k, v in optional.items() if v is not None}, **self.extra}
