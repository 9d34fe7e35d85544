"""The whole manifest, typed and versioned: :class:`DatasetManifest` and its parts (the tool, the
area, the summary).

:meth:`DatasetManifest.from_json` reads the two versions osmseg has written and refuses any other
in one line. Version 2 (:data:`FORMAT_VERSION`, written now) writes each build setting once: the
top-level keys (:data:`TOP_LEVEL_SETTINGS`) and ``config`` for the rest. Version 1 repeated them
all in ``config``; it lacks nothing a reader needs, and :meth:`DatasetManifest.build_identity`
reads either. Keys that came later without a new version are optional, None when absent:
``image_format``, ``config``, a sample's ``overlap_group``, the summary's overlap counts.

:meth:`DatasetManifest.to_json` gives back the object read (a manifest of a build, byte for
byte: ``tests/core/test_manifest.py``); :func:`osmseg.output.manifest.write_manifest` writes it a
sample at a time, so that ``samples`` and ``rejected`` may be lazy sequences (a build's
finaliser reads each entry from disk as it goes). Imports: osmseg.classes, osmseg.errors.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

from osmseg.classes import ClassTable
from osmseg.errors import DatasetError
from osmseg.output.manifest.samples import Provenance, RejectionRecord, SampleRecord
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
    optional_text,
    text,
)

__all__ = ["FORMAT", "FORMAT_VERSION", "READ_VERSIONS", "REQUIRED_KEYS", "TOP_LEVEL_SETTINGS", "AreaRecord",
           "DatasetManifest", "DatasetSummary", "ToolInfo", "check_sample_names"]

FORMAT = "osmseg-dataset"
#: The version written: 2 writes each build setting once (see the module's docstring).
FORMAT_VERSION = 2
#: The versions this osmseg reads.
READ_VERSIONS = (1, 2)
#: Build settings written at the top level, so not again in ``config`` (version 2).
TOP_LEVEL_SETTINGS = ("area", "seed", "zoom", "grid_size", "image_format", "filters")
#: Keys every manifest has (see docs/dataset-format.md).
REQUIRED_KEYS = (
    "format", "format_version", "tool", "command", "seed", "area", "zoom", "grid_size", "classes",
    "filters", "imagery", "osm", "samples", "rejected", "summary",
)
_KNOWN = frozenset((*REQUIRED_KEYS, "image_format", "config", "name"))


@dataclass(frozen=True)
class ToolInfo:
    """What wrote the dataset: ``{"name": "osmseg", "version": ...}`` (absent keys: None)."""

    name: str | None = None
    version: str | None = None

    @classmethod
    def from_json(cls, value: object, where: str) -> ToolInfo:
        data = json_object(value, where)
        return cls(optional_text(data.get("name"), f"{where}.name"), optional_text(data.get("version"), f"{where}.version"))

    def to_json(self) -> JsonObject:
        return {k: v for k, v in (("name", self.name), ("version", self.version)) if v is not None}

    def text(self) -> str:
        """``osmseg 0.5.0`` for the texts that say what made the dataset."""
        return f"{self.name or 'osmseg'} {self.version or ''}".strip()


_AREA_KEYS = ("name", "kind", "lat", "lon", "radius_km", "bbox")


@dataclass(frozen=True)
class AreaRecord:
    """The sampling area: a named place (``kind`` urban/rural) with a centre and radius, or a box
    ``bbox`` [W, S, E, N]; what a build leaves out is null."""

    name: str | None = None
    kind: str | None = None
    lat: float | None = None
    lon: float | None = None
    radius_km: float | None = None
    bbox: tuple[float, ...] | None = None

    @classmethod
    def from_json(cls, value: object, where: str) -> AreaRecord:
        data = json_object(value, where)
        bbox = data.get("bbox")
        return cls(name=optional_text(data.get("name"), f"{where}.name"),
                   kind=optional_text(data.get("kind"), f"{where}.kind"),
                   lat=optional_number(data.get("lat"), f"{where}.lat"),
                   lon=optional_number(data.get("lon"), f"{where}.lon"),
                   radius_km=optional_number(data.get("radius_km"), f"{where}.radius_km"),
                   bbox=None if bbox is None else number_list(bbox, 4, f"{where}.bbox"))

    def to_json(self) -> JsonObject:
        """All six keys, null where unset, as a build writes them."""
        return {"name": self.name, "kind": self.kind, "lat": self.lat, "lon": self.lon, "radius_km": self.radius_km,
                "bbox": None if self.bbox is None else list(self.bbox)}


_SUMMARY_KNOWN = frozenset(("requested", "accepted", "rejected", "attempts", "max_attempts", "rejected_by_reason",
                           "complete", "duplicate_samples", "overlapping_samples", "overlap_groups", "osm_unplaced"))


@dataclass(frozen=True)
class DatasetSummary:
    """The manifest's ``summary`` (docs/dataset-format.md): what a build asked for and got, and how
    its samples fall relative to each other and to OSM. A count a manifest does not record is None
    (the overlap counts came after version 1; a dataset made by hand may record none)."""

    requested: int | None = None
    accepted: int | None = None
    rejected: int | None = None
    attempts: int | None = None
    max_attempts: int | None = None
    rejected_by_reason: Mapping[str, int] | None = None
    complete: bool | None = None  # accepted >= requested
    duplicate_samples: int | None = None  # samples on the very tiles of another
    overlapping_samples: int | None = None  # samples sharing pixels with another
    overlap_groups: int | None = None  # groups of samples that overlap; a lone sample is a group
    osm_unplaced: int | None = None  # OSM objects of a class that could not be drawn (no node located)
    extra: Mapping[str, Json] = field(default_factory=dict)

    @classmethod
    def from_json(cls, value: object, where: str) -> DatasetSummary:
        data = json_object(value, where)
        def count(key: str) -> int | None:
            return optional_int(data.get(key), f"{where}.{key}")

        by_reason = data.get("rejected_by_reason")
        return cls(requested=count("requested"), accepted=count("accepted"), rejected=count("rejected"),
                   attempts=count("attempts"), max_attempts=count("max_attempts"),
                   rejected_by_reason=None if by_reason is None else int_map(by_reason, f"{where}.rejected_by_reason"),
                   complete=optional_bool(data.get("complete"), f"{where}.complete"),
                   duplicate_samples=count("duplicate_samples"), overlapping_samples=count("overlapping_samples"),
                   overlap_groups=count("overlap_groups"), osm_unplaced=count("osm_unplaced"),
                   extra=extra_keys(data, _SUMMARY_KNOWN))

    def to_json(self) -> JsonObject:
        out: JsonObject = {
            "requested": self.requested, "accepted": self.accepted, "rejected": self.rejected,
            "attempts": self.attempts, "max_attempts": self.max_attempts, "complete": self.complete,
            "rejected_by_reason": None if self.rejected_by_reason is None else dict(self.rejected_by_reason),
            "duplicate_samples": self.duplicate_samples, "overlapping_samples": self.overlapping_samples,
            "overlap_groups": self.overlap_groups, "osm_unplaced": self.osm_unplaced,
        }
        return {**{k: v for k, v in out.items() if v is not None}, **self.extra}


@dataclass(frozen=True)
class DatasetManifest:
    """A dataset's ``manifest.json``: what was built (``samples``, ``rejected``, ``summary``), from
    what (``area``, ``imagery``, ``osm``, ``classes``, the settings) and by which command. Read it
    with :func:`osmseg.output.manifest.read_manifest`; the schema is ``docs/dataset-format.md``."""

    format_version: int
    tool: ToolInfo
    command: str
    seed: int
    area: AreaRecord
    zoom: int | None
    grid_size: int | None  # tiles per side
    classes: ClassTable  # names and colours (no OSM rules: :func:`dataset_class_table` finds those)
    filters: Mapping[str, Json]  # FilterConfig.to_dict(): the thresholds as used
    imagery: Provenance
    osm: Provenance
    samples: Sequence[SampleRecord]  # any sequence, also a lazy one (see the module's docstring)
    rejected: Sequence[RejectionRecord]
    summary: DatasetSummary
    image_format: str | None = None  # png, jpg or cog (None: not recorded, png)
    config: Mapping[str, Json] | None = None  # the rest of the build's identity (version 1: all of it)
    name: str | None = None  # a title (datasets made by hand)
    extra: Mapping[str, Json] = field(default_factory=dict)

    @classmethod
    def from_json(cls, value: object, where: str = "manifest") -> DatasetManifest:
        """A manifest from its parsed JSON: the format and version checked first (one line saying
        what to do with another), then every part; samples named once each."""
        data, samples_json, rejected_json = _checked_top(value, where)
        samples = tuple(SampleRecord.from_json(s, f"{where} samples[{i}]") for i, s in enumerate(samples_json))
        check_sample_names(samples, where)
        config = data.get("config")
        return cls(
            format_version=_int(data["format_version"], f"{where} format_version"), tool=ToolInfo.from_json(data["tool"], f"{where} tool"),
            command=text(data["command"], f"{where} command"), seed=_int(data["seed"], f"{where} seed"),
            area=AreaRecord.from_json(data["area"], f"{where} area"),
            zoom=optional_int(data["zoom"], f"{where} zoom"), grid_size=optional_int(data["grid_size"], f"{where} grid_size"),
            classes=ClassTable.from_dict(data["classes"], f"{where} classes"),
            filters=json_object(data["filters"], f"{where} filters"),
            imagery=Provenance.from_json(data["imagery"], f"{where} imagery"),
            osm=Provenance.from_json(data["osm"], f"{where} osm"), samples=samples,
            rejected=tuple(RejectionRecord.from_json(r, f"{where} rejected[{i}]") for i, r in enumerate(rejected_json)),
            summary=DatasetSummary.from_json(data["summary"], f"{where} summary"),
            image_format=optional_text(data.get("image_format"), f"{where} image_format"),
            config=None if config is None else json_object(config, f"{where} config"),
            name=optional_text(data.get("name"), f"{where} name"), extra=extra_keys(data, _KNOWN))

    def head_json(self) -> JsonObject:
        """The JSON object of everything but the ``samples`` and ``rejected`` lists."""
        out: JsonObject = {
            "format": FORMAT, "format_version": self.format_version, "tool": self.tool.to_json(),
            "command": self.command, "seed": self.seed, "area": self.area.to_json(), "zoom": self.zoom,
            "grid_size": self.grid_size, "classes": self.classes.to_dict(), "filters": dict(self.filters),
            "imagery": self.imagery.to_json(), "osm": self.osm.to_json(), "summary": self.summary.to_json(),
        }
        optional: JsonObject = {"image_format": self.image_format, "name": self.name,
                                "config": None if self.config is None else dict(self.config)}
        return {**out, **{k: v for k, v in optional.items() if v is not None}, **self.extra}

    def to_json(self) -> JsonObject:
        """The whole JSON object (every entry in memory: for a big lazy manifest, write it with
        :func:`osmseg.output.manifest.write_manifest` instead)."""
        return {**self.head_json(), "samples": [s.to_json() for s in self.samples],
                "rejected": [r.to_json() for r in self.rejected]}

    def build_identity(self) -> JsonObject:
        """Everything that decided the dataset's content (``BuildConfig.identity()``), from either
        version: version 1 kept it whole in ``config``, version 2 once across the top level and ``config``."""
        if self.format_version == 1:
            return dict(self.config or {})
        head = self.head_json()
        top = {key: head[key] for key in TOP_LEVEL_SETTINGS if key in head}
        top["area"] = {k: v for k, v in self.area.to_json().items() if v is not None}
        return {**top, **(self.config or {})}

    @property
    def classes_source(self) -> str | None:
        """The class table the build was given (a shipped name or a path), when the manifest records it."""
        source = (self.config or {}).get("classes")
        return source if isinstance(source, str) and source else None

    def ground_resolutions(self) -> list[float]:
        """Metres per pixel of every sample that records it, in manifest order."""
        return [s.ground_resolution_m for s in self.samples if s.ground_resolution_m is not None]


def _int(value: object, where: str) -> int:
    number = optional_int(value, where)
    if number is None:
        raise DatasetError(f"{where} must be an integer, not null; rebuild the dataset or restore its manifest.json")
    return number


def _checked_top(value: object, where: str) -> tuple[JsonObject, list[Json], list[Json]]:
    """The manifest's top-level object, its format and version checked, every required key there;
    and its ``samples`` and ``rejected`` lists."""
    if not isinstance(value, dict):
        raise DatasetError(f"{where}: top level must be a JSON object; give the manifest.json of an 'osmseg build' dataset")
    data = json_object(value, where)
    if data.get("format") != FORMAT:
        raise DatasetError(f"{where}: format is {data.get('format')!r}, expected {FORMAT!r}; give the manifest.json "
                           "of an 'osmseg build' dataset")
    version = data.get("format_version")
    if version not in READ_VERSIONS or isinstance(version, bool):
        tool = data.get("tool")
        made = (f" (written by osmseg {tool.get('version')})" if isinstance(tool, dict) and tool.get("version")
                else "")
        raise DatasetError(f"{where}: format_version {version!r}{made} is not one this osmseg reads "
                           f"({', '.join(map(str, READ_VERSIONS))}): rebuild the dataset with this osmseg "
                           "(the manifest's command), or read it with the osmseg that wrote it")
    missing = [k for k in REQUIRED_KEYS if k not in data]
    if missing:
        raise DatasetError(f"{where}: missing keys {missing}; rebuild the dataset or restore its manifest.json")
    samples, rejected = data["samples"], data["rejected"]
    if not isinstance(samples, list) or not isinstance(rejected, list):
        raise DatasetError(f"{where}: samples and rejected must be lists; rebuild the dataset or restore its manifest.json")
    return data, samples, rejected


def check_sample_names(samples: Iterable[SampleRecord], where: str = "manifest") -> None:
    """A one-line :class:`DatasetError` when two samples share a name (their files would be one).
    Iterates ``samples`` once, keeping only the names."""
    names: set[str] = set()
    for sample in samples:
        if sample.name in names:
            raise DatasetError(f"{where}: sample name {sample.name!r} appears twice; rebuild the dataset")
        names.add(sample.name)
