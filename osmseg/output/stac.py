"""A STAC catalog of the dataset, readable by pystac, STAC Browser and Raster Vision without osmseg.

:func:`write_stac` writes a self-contained STAC 1.1 catalog, all hrefs relative (the dataset
folder can be moved or zipped): ``OUT/stac/catalog.json`` (root Catalog; its child is the
Collection), ``OUT/stac/collection.json`` and, per sample, two Items in ``OUT/stac/items/``,
as the label extension (and Radiant MLHub, Raster Vision's ``read_stac``) has them:

* the **label item** ``NAME``: the label extension (``label:type`` raster, ``label:tasks``
  segmentation, ``label:classes`` = class ids, ``label:overviews`` = pixels per class name),
  assets in this order: ``labels`` (``geo/NAME.tif``, the class-id COG: *first*, as readers
  take the first asset for the label raster), ``labels_style`` (``geo/NAME.qml``, its QGIS
  style, role ``metadata``), ``labels_png``, ``segmented``, ``image`` (last, so that one item
  still shows every file); one ``source`` link to the image item;
* the **image item** ``NAME_image``: the imagery, asset ``image`` only (role ``data``).

Both hold the WGS84 footprint, ``gsd``, ``osmseg:zoom`` and the grid the rasters share
(``proj:code`` EPSG:3857, ``proj:bbox``, ``proj:shape``, ``proj:transform``); every asset
has its ``file:checksum`` (multihash: ``1220`` + the manifest's SHA-256). The **Collection**:
licence ``other`` (labels ODbL-1.0, images the provider's terms; ``license`` links to
ATTRIBUTION.md and the ODbL), providers (OSM contributors, the imagery provider, osmseg),
the union of footprints and dates, ``item_assets``, ``summaries``.

**Class table.** For raster labels the label extension lists pixel values only, no names or
colours; so the id -> name -> colour table goes where the classification extension puts
it: ``classification:classes`` (``value`` = id, ``title`` = class name, ``name`` = the same
made machine-safe, as that extension requires, ``color_hint``) on the ``labels`` and
``labels_png`` assets, in ``item_assets`` and in the summaries.

**Datetime** = the date of the labels, the one date the manifest knows: the sample's OSM
data timestamp. Without one, ``datetime`` is null and ``start_datetime``..``end_datetime``
spans what the manifest knows: from the newest element edited in the box (else the earliest
OSM date of the manifest) to its latest OSM date. Never the time of writing: the same
manifest gives the same bytes (JSON as the manifest's: sorted keys, except that assets keep
their order; indent 2; atomic).

**Large builds.** ``manifest.samples`` may be any sequence of records, also a lazy one that
reads each entry from disk as it is iterated: :func:`write_stac` iterates it three times (the
manifest's shape; what STAC needs and the dates undated samples span; the items, made, written
and dropped a sample at a time, the Collection's extent gathered on the way) and keeps only the
sample names, so its memory does not grow with the entries. The item files are made durable
by one ``syncfs`` of their file system, not an fsync each (see :func:`write_stac`).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import warnings
from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from datetime import datetime, timezone
from fnmatch import fnmatch
from pathlib import Path, PurePosixPath
from typing import Any

import pystac
from pystac.extensions.classification import Classification, ClassificationExtension
from pystac.extensions.file import FileExtension
from pystac.extensions.projection import ProjectionExtension
from pystac.utils import str_to_datetime

with warnings.catch_warnings():  # pystac flags the label extension "unmaintained"; tools still read it
    warnings.simplefilter("ignore", DeprecationWarning)
    from pystac.extensions.label import LabelClasses, LabelCount, LabelExtension, LabelOverview, LabelType

from osmseg.classes import ClassTable, machine_name
from osmseg.errors import DatasetError
from osmseg.grid import TILE_SIZE
from osmseg.output.atomic import atomic_path, atomic_write_text, sync_file_system
from osmseg.output.attribution import ATTRIBUTION_NAME, ODBL_URL, OSM_COPYRIGHT_URL, LabelSource
from osmseg.output.datasheet import DATASHEET_NAME
from osmseg.output.manifest import MANIFEST_NAME, AreaRecord, DatasetManifest, SampleRecord, check_sample_names
from osmseg.output.overview import OVERVIEW_NAME

STAC_DIR = "stac"
CATALOG_NAME = "catalog.json"
COLLECTION_NAME = "collection.json"
ITEMS_DIR = "items"
IMAGE_ITEM_SUFFIX = "_image"  # id of a sample's image item: NAME_image
CRS = "EPSG:3857"
MARKDOWN = "text/markdown"
TASKS, METHODS = ("segmentation",), ("automated",)  # label:tasks, label:methods (rasterised, not hand-drawn)
UNLABELED_TEXT = "no OSM feature covers the pixel (not background: unmapped things may be there)"
#: sample folder -> (asset key, roles, title), in the order of the label item's assets (label raster first)
ASSET_KINDS = {
    "geo": ("labels", ["labels"], "Class ids, Cloud-Optimized GeoTIFF in EPSG:3857 with a colour table"),
    "labels": ("labels_png", ["labels"], "Class ids, 8-bit greyscale PNG (0 = unlabeled)"),
    "segmented": ("segmented", ["visual"], "Labels in class colours, RGB"),
    "images": ("image", ["data"], "Aerial image, RGB"),
}
#: sidecar files of a sample raster, by suffix: (asset key suffix, roles, title); listed after their raster
SIDECARS = {".qml": ("style", ["metadata"], "QGIS layer style: the class colours and names in QGIS's legend")}
#: dataset-level files, as Collection assets: key -> (file, media type, role)
COLLECTION_ASSETS = {
    "manifest": (MANIFEST_NAME, pystac.MediaType.JSON, "metadata"),
    "datasheet": (DATASHEET_NAME, MARKDOWN, "metadata"),
    "attribution": (ATTRIBUTION_NAME, MARKDOWN, "metadata"),
    "overview": (OVERVIEW_NAME, pystac.MediaType.PNG, "overview"),
}
#: folders whose pixel values are class ids (they carry classification:classes)
CLASS_ID_FOLDERS = ("labels", "geo")
COG_FOLDERS = ("images", "geo")  # their .tif files are Cloud-Optimized GeoTIFFs
_MEDIA_TYPES = {".png": pystac.MediaType.PNG, ".jpg": pystac.MediaType.JPEG, ".jpeg": pystac.MediaType.JPEG,
                ".tif": pystac.MediaType.GEOTIFF, ".tiff": pystac.MediaType.GEOTIFF, ".qml": pystac.MediaType.XML}
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")
_HEX64 = re.compile(r"[0-9a-f]{64}")
_FOLDS = (min, min, max, max, min, max, min, max)  # how _Facts.folded gathers each value
_ITEM_LINKS = "\u0000item links\u0000"  # where _write_collection puts them: no real link is a string


def media_type(rel: str) -> str | None:
    """Media type of a sample file from its suffix and folder (None when unknown: no ``type``).

    >>> media_type("geo/a.tif"), media_type("images/a.jpg"), media_type("other/a.tif")
    ('image/tiff; application=geotiff; profile=cloud-optimized', 'image/jpeg', 'image/tiff; application=geotiff')
    """
    path = PurePosixPath(rel)
    known = _MEDIA_TYPES.get(path.suffix.lower())
    if known == pystac.MediaType.GEOTIFF and path.parts[0] in COG_FOLDERS:  # osmseg.output.geotiff writes COGs
        known = pystac.MediaType.COG
    return str(known) if known else None


def classification(table: ClassTable) -> list[Classification]:
    """The class table as ``classification:classes``, ordered by id."""
    classes = sorted((table.unlabeled, *table.classes), key=lambda c: c.id)
    names = [machine_name(c.name) for c in classes]
    if len(set(names)) != len(names):
        raise DatasetError(f"manifest classes: names {[c.name for c in classes]} do not stay distinct as {names}")
    return [Classification.create(value=c.id, name=n, title=c.name, color_hint="{:02X}{:02X}{:02X}".format(*c.color),
                                  description=UNLABELED_TEXT if c.id == table.unlabeled.id else None) for c, n in zip(classes, names)]


def _numbers(value: tuple[float, ...] | None, n: int, what: str) -> list[float]:
    if value is None or len(value) != n:
        raise DatasetError(f"manifest: {what} must be {n} numbers, got {value!r}")
    return [float(v) for v in value]


def _date(value: str | None, what: str) -> datetime | None:
    if value is None:
        return None
    try:
        stamp = str_to_datetime(str(value))
    except (ValueError, OverflowError):
        raise DatasetError(f"manifest: {what} {value!r} is not an ISO 8601 date") from None
    return stamp if stamp.tzinfo else stamp.replace(tzinfo=timezone.utc)


def _sample_dates(sample: SampleRecord, known: tuple[datetime, ...]) -> tuple[datetime | None, ...]:
    """(datetime, start, end) of a sample: its OSM timestamp, else a span (see the module docstring);
    ``known``: the earliest and latest OSM date of the manifest (empty: none)."""
    stamp = _date(sample.osm.timestamp, "osm.timestamp")
    if stamp is not None:
        return stamp, None, None
    if not known:
        raise DatasetError(f"manifest: sample {sample.name} has no OSM date, nor has any other: STAC needs one")
    start = _date(sample.osm.newest_element, "osm.newest_element") or known[0]
    return None, start, max(start, known[-1])


def _geometry(sample: SampleRecord) -> tuple[str, list[float], list[float], float, int]:
    """(name, ``bbox_wgs84``, ``bounds_3857``, gsd, zoom) of a sample, checked."""
    name = sample.name
    if not _NAME.fullmatch(name):
        raise DatasetError(f"manifest: sample name {name!r} is not a file stem ([A-Za-z0-9][A-Za-z0-9_.-]*)")
    if sample.ground_resolution_m is None or sample.zoom is None:
        raise DatasetError(f"manifest: sample {name} records no zoom or ground_resolution_m: STAC needs both")
    return (name, _numbers(sample.bbox_wgs84, 4, f"sample {name} bbox_wgs84"),
            _numbers(sample.bounds_3857, 4, f"sample {name} bounds_3857"),
            float(sample.ground_resolution_m), sample.zoom)


def _counts(sample: SampleRecord, table: ClassTable) -> list[tuple[str, int]]:
    """(class name, pixels) of a sample's ``class_histogram``, in class id order."""
    histogram, by_name = sample.class_histogram, table.by_name
    if not set(histogram) <= set(by_name):
        raise DatasetError(f"manifest: sample {sample.name} class_histogram names classes the class table lacks")
    return [(c, int(histogram[c])) for c in sorted(histogram, key=lambda c: by_name[c].id)]


def _asset_plan(name: str, files: Mapping[str, str]) -> list[tuple[str, str, str, str]]:
    """(asset key, file, sha256, folder) per file of a sample, in the label item's asset order:
    :data:`ASSET_KINDS` order, other files before ``images/``, a :data:`SIDECARS` file after its
    folder's raster. Keys by folder (``image_tif`` when a folder has two files; ``labels_style``
    for the style beside ``geo/``'s raster)."""
    paths = {rel: PurePosixPath(rel) for rel in files}
    folders = Counter(path.parts[0] for path in paths.values() if not _is_sidecar(path))
    for folder in ("geo", "images"):  # the label raster (first asset) and the image item's asset
        if folders[folder] != 1:
            raise DatasetError(f"manifest: sample {name} lists {folders[folder]} {folder}/ files, not one")
    rank = {folder: i for i, folder in enumerate(ASSET_KINDS)}
    plan: dict[str, tuple[str, str, str, str]] = {}
    for rel, digest in sorted(files.items(), key=lambda f: (rank.get(paths[f[0]].parts[0], 2.5),
                                                            _is_sidecar(paths[f[0]]), f[0])):
        path = paths[rel]
        if not _HEX64.fullmatch(digest):
            raise DatasetError(f"manifest: sample {name} {rel}: {digest!r} is not a sha256 hex digest")
        folder = path.parts[0] if len(path.parts) > 1 else ""
        key = ASSET_KINDS[folder][0] if folder in ASSET_KINDS else folder or path.stem
        if _is_sidecar(path):
            key = f"{key}_{SIDECARS[path.suffix.lower()][0]}"
        elif folders[path.parts[0]] > 1:
            key = f"{key}_{path.suffix.lstrip('.').lower()}"
        if key in plan:
            raise DatasetError(f"manifest: sample {name}: two files make asset {key!r}, one is {rel}")
        plan[key] = (key, rel, digest, folder)
    return list(plan.values())


def _is_sidecar(path: PurePosixPath) -> bool:
    """True for a :data:`SIDECARS` file of a sample folder (``geo/NAME.qml``), not one of its rasters."""
    return len(path.parts) > 1 and path.suffix.lower() in SIDECARS


def _items(sample: SampleRecord, table: ClassTable, classes: list[Classification], pixels: int,
           known: tuple[datetime, ...], source: LabelSource) -> tuple[pystac.Item, pystac.Item]:
    """The (label item, image item) of a sample; the label item links the image item (rel ``source``)."""
    name, (w, s, e, n), (left, bottom, right, top), gsd, zoom = _geometry(sample)
    when, start, end = _sample_dates(sample, known)
    res = (right - left) / pixels  # as osmseg.grid.SampleGrid.transform: square pixels, north up
    pair = []
    for item_id in (name, name + IMAGE_ITEM_SUFFIX):
        footprint = {"type": "Polygon", "coordinates": [[[w, s], [e, s], [e, n], [w, n], [w, s]]]}
        item = pystac.Item(id=item_id, geometry=footprint, bbox=[w, s, e, n], datetime=when, start_datetime=start,
                           end_datetime=end, properties={"gsd": gsd, "osmseg:zoom": zoom})
        ProjectionExtension.ext(item, add_if_missing=True).apply(
            code=CRS, bbox=[left, bottom, right, top], shape=[pixels, pixels],
            transform=[res, 0.0, left, 0.0, -res, top])
        pair.append(item)
    label_item, image_item = pair
    overview = LabelOverview({})
    overview.counts = [LabelCount.create(c, count) for c, count in _counts(sample, table)]
    origin = sample.osm.timestamp_from or ""
    when_text = (f"edited up to {when:%Y-%m-%d %H:%M} UTC (its newest element)" if when and origin == "newest element"
                 else f"of a file dated {when:%Y-%m-%d} (no edit times in it)" if when and "modification" in origin
                 else f"as of {when:%Y-%m-%d %H:%M} UTC" if when else f"edited {start:%Y-%m-%d} or later")
    origin_text = (f"OpenStreetMap data {when_text} (© OpenStreetMap contributors, ODbL 1.0)" if source.is_osm else
              f"{source.name.replace('`', '')} (licence: the file's source's)")
    LabelExtension.ext(label_item, add_if_missing=True).apply(
        label_description=f"Class ids ({table.name}) rasterised by osmseg from {origin_text}; 0 = unlabeled, "
                          "not background.",
        label_type=LabelType.RASTER, label_properties=None,
        label_classes=[LabelClasses.create(sorted(table.by_id), None)],
        label_tasks=list(TASKS), label_methods=list(METHODS), label_overviews=[overview])
    for key, rel, digest, folder in _asset_plan(name, sample.files):  # the images/ one in the image item too
        sidecar = _is_sidecar(PurePosixPath(rel))
        kind: tuple[str, list[str], str | None] = ("", [], None)
        _, roles, title = SIDECARS[PurePosixPath(rel).suffix.lower()] if sidecar else ASSET_KINDS.get(folder, kind)
        asset = pystac.Asset(href=f"../../{rel}", title=title, media_type=media_type(rel), roles=list(roles))
        for item in (label_item, image_item) if folder == "images" and not sidecar else (label_item,):
            copy = asset.clone()
            item.add_asset(key, copy)
            FileExtension.ext(copy, add_if_missing=True).checksum = "1220" + digest
            if sidecar:
                continue  # osmseg's own file, made from the class table: no data licence, no classes
            if folder in ASSET_KINDS and folder != "images":
                copy.extra_fields["license"] = source.spdx or "other"  # a GeoJSON source: its own terms
            if folder in CLASS_ID_FOLDERS:
                ClassificationExtension.ext(copy, add_if_missing=True).classes = classes
    label_item.add_link(pystac.Link("source", f"./{name}{IMAGE_ITEM_SUFFIX}.json", pystac.MediaType.JSON,
                                    "Imagery of the labels"))
    return label_item, image_item


def _survey(manifest: DatasetManifest, table: ClassTable) -> tuple[list[str], tuple[datetime, ...]]:
    """Check every sample as :func:`_items` does (a faulty manifest writes no item); return their
    names and the earliest and latest OSM date of the manifest (empty: none), as ``sorted(dates)``
    has them first and last (of one instant in several time zones: the first, the last)."""
    names: list[str] = []
    earliest = latest = _date(manifest.osm.timestamp, "osm.timestamp")
    for sample in manifest.samples:
        for k, value in (("timestamp", sample.osm.timestamp), ("newest_element", sample.osm.newest_element)):
            if (d := _date(value, f"sample {sample.name} osm.{k}")) is not None:
                earliest = d if earliest is None or d < earliest else earliest
                latest = d if latest is None or d >= latest else latest
        names.append(name := _geometry(sample)[0])
        _counts(sample, table)
        _asset_plan(name, sample.files)
    unique = set(names)  # check_sample_names checks
    if clash := sorted(n for n in unique if n.endswith(IMAGE_ITEM_SUFFIX) and n[:-len(IMAGE_ITEM_SUFFIX)] in unique):
        raise DatasetError(f"manifest: sample name {clash[0]!r} is the image item id of sample "
                           f"{clash[0].removesuffix(IMAGE_ITEM_SUFFIX)!r}: rename one")
    return names, () if earliest is None or latest is None else (earliest, latest)


@dataclass
class _Facts:
    """What the Collection says of its label items, gathered an item at a time (items are not
    kept): as ``min``/``max`` over a list of them, of equal values the first."""

    folded: list[Any] = field(default_factory=list)  # west, south, east, north, start, end, gsd min, max
    zooms: set[int] = field(default_factory=set)
    definitions: dict[str, pystac.ItemAssetDefinition | dict[str, Any]] = field(default_factory=dict)

    def add(self, item: pystac.Item) -> None:
        when, gsd = item.datetime, float(item.properties["gsd"])  # no item lacks both date and span
        new = [*(item.bbox or []), when or item.common_metadata.start_datetime,
               when or item.common_metadata.end_datetime, gsd, gsd]
        self.folded = [fold(a, b) for fold, a, b in zip(_FOLDS, self.folded, new)] if self.folded else new
        self.zooms.add(int(item.properties["osmseg:zoom"]))
        for key, asset in item.assets.items():
            if key not in self.definitions:
                fields = {k: v for k, v in asset.extra_fields.items() if k.startswith("classification:")}
                self.definitions[key] = pystac.ItemAssetDefinition.create(
                    asset.title, None, asset.media_type, asset.roles, extra_fields=fields or None)

    def describe(self, collection: pystac.Collection, area: AreaRecord) -> None:
        """Set the Collection's extent, ``item_assets`` and item summaries."""
        box = self.folded[:4] or _numbers(area.bbox or (-180, -90, 180, 90), 4, "area.bbox")
        interval = self.folded[4:6] or [None, None]
        collection.extent = pystac.Extent(pystac.SpatialExtent([box]), pystac.TemporalExtent([interval]))
        collection.item_assets = self.definitions
        if self.folded:
            collection.summaries.add("gsd", pystac.RangeSummary(*self.folded[6:]))
            collection.summaries.add("osmseg:zoom", sorted(self.zooms))


def _providers(manifest: DatasetManifest) -> list[pystac.Provider]:
    imagery, osm, version = manifest.imagery, manifest.osm, manifest.tool.version or ""
    url = imagery.terms_url  # not "url"/"template": those are tile URLs
    notes = dict.fromkeys(note for note in (imagery.attribution, imagery.copyright, imagery.terms) if note)
    source = LabelSource.of(osm)
    labels = (pystac.Provider("OpenStreetMap contributors", osm.attribution or "labels: OpenStreetMap data, "
                              "ODbL 1.0", roles=[pystac.ProviderRole.LICENSOR, pystac.ProviderRole.PRODUCER],
                              url=OSM_COPYRIGHT_URL) if source.is_osm else
              pystac.Provider(f"label source: {osm.path or 'GeoJSON file'}", source.notice,
                              roles=[pystac.ProviderRole.LICENSOR, pystac.ProviderRole.PRODUCER]))
    return [
        labels,
        pystac.Provider(imagery.name or imagery.provider or "imagery provider",
                        "; ".join(notes) or f"see {ATTRIBUTION_NAME}",
                        roles=[pystac.ProviderRole.LICENSOR, pystac.ProviderRole.PRODUCER],
                        url=url if url and url.startswith(("https://", "http://")) else None),
        pystac.Provider("osmseg", f"osmseg {version} rasterised the OSM data on the imagery's tile grid; "
                        f"command: {manifest.command}", roles=[pystac.ProviderRole.PROCESSOR]),
    ]


def _collection(manifest: DatasetManifest, table: ClassTable, classes: list[Classification], count: int,
                pixels: int) -> pystac.Collection:
    """The Collection of ``count`` samples, without what comes from the items (:class:`_Facts`)."""
    place = manifest.area.name or "area"
    labels = LabelSource.of(manifest.osm)
    identity = json.dumps(manifest.build_identity() or manifest.command, sort_keys=True, ensure_ascii=False)
    slug = re.sub(r"[^0-9a-z]+", "-", place.lower()).strip("-") or "area"
    extent = pystac.Extent(pystac.SpatialExtent([-180.0, -90.0, 180.0, 90.0]), pystac.TemporalExtent([None, None]))
    collection = pystac.Collection(
        id=f"osmseg-{slug}-{hashlib.sha256(identity.encode()).hexdigest()[:8]}",
        title=f"osmseg: {place}, zoom {manifest.zoom}, {count} samples",
        description=(f"{count} aerial images of {place} ({pixels}x{pixels} px, zoom {manifest.zoom}) with "
                     f"per-pixel class ids rasterised by osmseg from {labels.name.replace('`', '')} (class table "
                     f"{table.name}). Labels: {labels.notice}; images under the imagery provider's terms "
                     f"(see {ATTRIBUTION_NAME}). How it was built: {MANIFEST_NAME}, {DATASHEET_NAME}."),
        extent=extent, license="other", providers=_providers(manifest), catalog_type=pystac.CatalogType.SELF_CONTAINED,
        keywords=["OpenStreetMap", "semantic segmentation", "aerial imagery", "training data"])
    collection.add_links([pystac.Link("license", f"../{ATTRIBUTION_NAME}", MARKDOWN,
                                      "Labels ODbL 1.0; images" if labels.is_osm else "Labels and images")])
    if labels.is_osm:
        collection.add_link(pystac.Link("license", ODBL_URL, "text/html", "Open Database License 1.0 (labels)"))
    for key, (rel, kind, role) in COLLECTION_ASSETS.items():
        collection.add_asset(key, pystac.Asset(f"../{rel}", media_type=str(kind), roles=[role]))
    summaries = LabelExtension.summaries(collection, add_if_missing=True)
    summaries.label_type, summaries.label_tasks = [LabelType.RASTER], list(TASKS)
    summaries.label_methods = list(METHODS)
    summaries.label_classes = [LabelClasses.create(sorted(table.by_id), None)]
    ClassificationExtension.summaries(collection, add_if_missing=True).classes = classes
    ProjectionExtension.summaries(collection, add_if_missing=True).code = [CRS]
    return collection


def _canonical(value: Any, keep_order: bool = False) -> Any:
    """``value`` with every mapping's keys sorted, except the top one when ``keep_order``."""
    if isinstance(value, dict):
        return {k: _canonical(value[k]) for k in (value if keep_order else sorted(value))}
    return [_canonical(v) for v in value] if isinstance(value, list) else value


def _json_text(stac: dict[str, Any]) -> str:
    """Deterministic JSON (as the manifest's), extension URIs sorted; assets keep their order."""
    if "stac_extensions" in stac:
        stac["stac_extensions"] = sorted(stac["stac_extensions"])
    try:
        doc = {k: _canonical(stac[k], keep_order=k in ("assets", "item_assets")) for k in sorted(stac)}
        return json.dumps(doc, indent=2, ensure_ascii=False, allow_nan=False) + "\n"
    except (TypeError, ValueError) as exc:
        raise DatasetError(f"manifest: a value cannot be written as STAC JSON ({exc})") from None


def _write_collection(path: Path, doc: dict[str, Any], item_hrefs: Iterable[str]) -> None:
    """Write ``doc`` (the Collection's JSON, without item links) with a link per item href
    appended to its ``links``, as :func:`_json_text` would, atomically: the text goes to the file
    a link at a time, so that it is never whole in memory (two links per sample)."""
    doc["links"].append(_ITEM_LINKS)
    head, tail = _json_text(doc).split(",\n    " + json.dumps(_ITEM_LINKS))  # a list two deep, after root, parent
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8", newline="\n") as f:
            f.write(head)
            for href in item_hrefs:
                link = pystac.Link("item", href, pystac.MediaType.GEOJSON).to_dict(transform_href=False)
                f.write(",\n    " + json.dumps(_canonical(link), indent=2, ensure_ascii=False).replace("\n", "\n    "))
            f.write(tail)
            f.flush()
            os.fsync(f.fileno())


def _remove_stale_items(folder: Path, names: set[str]) -> None:
    """Remove the ``*.json`` (as Path.glob matches it) in ``folder`` but ``NAME.json`` and
    ``NAME_image.json`` of the samples ``names``, not holding the folder's whole listing."""
    def stale(file: str) -> bool:
        stem = file.removesuffix(".json")
        return fnmatch(file, "*.json") and not (file.endswith(".json") and (
            stem in names or stem.removesuffix(IMAGE_ITEM_SUFFIX) in names))
    if folder.is_dir():
        with os.scandir(folder) as entries:
            for name in sorted(e.name for e in entries if stale(e.name)):
                (folder / name).unlink(missing_ok=True)  # (two shards may finalise at once)


def write_stac(out_dir: Path, manifest: DatasetManifest) -> Path:
    """Write ``OUT/stac/catalog.json``, ``collection.json`` and ``items/*.json``; return the Catalog's path.

    A pure function of ``manifest`` (reads no file); raises a one-line
    :class:`~osmseg.errors.DatasetError` when the manifest lacks what STAC needs (every sample is
    checked before the first file is written, but for values JSON cannot hold, such as NaN, found
    as their item is written). Items are written before the Collection that lists them, the
    Collection before the Catalog; items of samples no longer listed are removed.

    ``manifest.samples`` (any sequence) is iterated three times: by
    :func:`~osmseg.output.manifest.check_sample_names`, by :func:`_survey` (the checks, the dates
    undated samples span), then to make, write and drop each sample's two items, gathering the
    Collection's extent and summaries (:class:`_Facts`). Only the sample names stay in memory.

    The item files are written without an fsync each (which cost more than making the item)
    and made durable together by one ``syncfs`` of their file system
    (:func:`~osmseg.output.atomic.sync_file_system`) before the Collection and the Catalog are
    written (these keep their fsync), so the Collection written here lists durable items only.
    A power loss before that sync can leave item files empty or old; this Collection, the
    Catalog and the manifest (which the build writes after the catalog) are then not written
    yet, and a rerun of the same build command rewrites the whole catalog (this is a pure
    function of the manifest). Where that cannot be asked (Windows), each item is fsynced.
    """
    check_sample_names(manifest.samples)
    table = manifest.classes
    classes = classification(table)
    try:
        pixels = int(manifest.grid_size or 0) * TILE_SIZE
        source = LabelSource.of(manifest.osm)
        names, known = _survey(manifest, table)
        collection = _collection(manifest, table, classes, len(names), pixels)  # the items hold its id and title
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise DatasetError(f"manifest cannot be described as STAC: {type(exc).__name__} {exc}") from None
    root = Path(out_dir).resolve() / STAC_DIR
    up = [pystac.Link(rel, f"../{target}", pystac.MediaType.JSON, collection.title)  # every item's links
          for rel, target in (("root", CATALOG_NAME), ("parent", COLLECTION_NAME), ("collection", COLLECTION_NAME))]
    facts = _Facts()
    for sample in manifest.samples:
        pair = _items(sample, table, classes, pixels, known, source)  # checked by _survey
        facts.add(pair[0])
        for item in pair:
            item.collection_id = collection.id
            doc = item.to_dict(include_self_link=False, transform_hrefs=False)
            doc["links"] += [link.to_dict(transform_href=False) for link in up]
            atomic_write_text(root / ITEMS_DIR / f"{item.id}.json", _json_text(doc), durable=False)
    # the items, durable before a file that lists them (see above)
    if names and not sync_file_system(root / ITEMS_DIR):
        for name in names:
            for item_id in (name, name + IMAGE_ITEM_SUFFIX):
                with open(root / ITEMS_DIR / f"{item_id}.json", "rb") as f:
                    os.fsync(f.fileno())
    facts.describe(collection, manifest.area)
    catalog = pystac.Catalog(f"{collection.id}-catalog", title=collection.title,
                             description=f"osmseg dataset: Collection {collection.id}; per sample a label item NAME "
                                         f"whose source link is its image item NAME{IMAGE_ITEM_SUFFIX}.",
                             catalog_type=pystac.CatalogType.SELF_CONTAINED)
    catalog.set_self_href(str(root / CATALOG_NAME))
    catalog.add_child(collection)
    collection.set_self_href(str(root / COLLECTION_NAME))
    _write_collection(root / COLLECTION_NAME, collection.to_dict(include_self_link=False, transform_hrefs=True),
                      (f"./{ITEMS_DIR}/{i}.json" for name in names for i in (name, name + IMAGE_ITEM_SUFFIX)))
    atomic_write_text(root / CATALOG_NAME, _json_text(catalog.to_dict(include_self_link=False, transform_hrefs=True)))
    _remove_stale_items(root / ITEMS_DIR, set(names))
    return root / CATALOG_NAME
