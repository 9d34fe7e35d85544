"""A STAC catalog of the dataset, so that STAC tools read it without osmseg.

:func:`write_stac` writes a self-contained STAC 1.1 catalog, all hrefs relative (the dataset
folder can be moved or zipped): ``OUT/stac/collection.json`` and ``OUT/stac/items/NAME.json``.

An **Item** per sample (id = name) holds the WGS84 footprint, ``gsd``, ``osmseg:zoom``, the
grid its rasters share (``proj:code`` EPSG:3857, ``proj:bbox``, ``proj:shape``,
``proj:transform``), the label extension (``label:type`` raster, ``label:tasks``
segmentation, ``label:classes`` = class ids, ``label:overviews`` = pixels per class name)
and one asset per file of the sample (``image``, ``labels``, ``geo``, ``segmented``) with
its ``file:checksum`` (multihash: ``1220`` + the manifest's SHA-256). The **Collection**:
licence ``other`` (labels ODbL-1.0, images the provider's terms; ``license`` links to
ATTRIBUTION.md and the ODbL), providers (OSM contributors, the imagery provider, osmseg),
the union of footprints and dates, ``item_assets``, ``summaries``.

**Class table.** For raster labels the label extension lists pixel values only, no names or
colours; so the id -> name -> colour table goes where the classification extension puts
it: ``classification:classes`` (``value`` = id, ``title`` = class name, ``name`` = the same
made machine-safe, as that extension requires, ``color_hint``) on the ``labels`` and ``geo``
assets, in ``item_assets`` and in the summaries.

**Datetime** = the date of the labels, the one date the manifest knows: the sample's OSM
data timestamp. Without one, ``datetime`` is null and ``start_datetime``..``end_datetime``
spans what the manifest knows: from the newest element edited in the box (else the earliest
OSM date of the manifest) to its latest OSM date. Never the time of writing: the same
manifest gives the same bytes (JSON as the manifest's: sorted keys, indent 2, atomic).
"""

from __future__ import annotations

import hashlib
import json
import re
import warnings
from collections import Counter
from datetime import datetime, timezone
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

from osmseg.classes import ClassTable
from osmseg.errors import DatasetError
from osmseg.grid import TILE_SIZE
from osmseg.output.atomic import atomic_write_text
from osmseg.output.attribution import ATTRIBUTION_NAME, ODBL_URL, OSM_COPYRIGHT_URL
from osmseg.output.datasheet import DATASHEET_NAME
from osmseg.output.manifest import MANIFEST_NAME, validate_manifest
from osmseg.output.pictures import OVERVIEW_NAME

STAC_DIR = "stac"
COLLECTION_NAME = "collection.json"
ITEMS_DIR = "items"
CRS = "EPSG:3857"
LABEL_LICENSE = "ODbL-1.0"  # SPDX id of the OSM data's licence
MARKDOWN = "text/markdown"
TASKS, METHODS = ("segmentation",), ("automated",)  # label:tasks, label:methods (rasterised, not hand-drawn)
UNLABELED_TEXT = "no OSM feature covers the pixel (not background: unmapped things may be there)"
#: sample folder -> (asset key, roles, title)
ASSET_KINDS = {
    "images": ("image", ["data"], "Aerial image, RGB"),
    "labels": ("labels", ["labels"], "Class ids, 8-bit greyscale (0 = unlabeled)"),
    "geo": ("geo", ["labels"], "Class ids as a GeoTIFF in EPSG:3857 with a colour table"),
    "segmented": ("segmented", ["visual"], "Labels in class colours, RGB"),
}
#: dataset-level files, as Collection assets: key -> (file, media type, role)
COLLECTION_ASSETS = {
    "manifest": (MANIFEST_NAME, pystac.MediaType.JSON, "metadata"),
    "datasheet": (DATASHEET_NAME, MARKDOWN, "metadata"),
    "attribution": (ATTRIBUTION_NAME, MARKDOWN, "metadata"),
    "overview": (OVERVIEW_NAME, pystac.MediaType.PNG, "overview"),
}
#: folders whose pixel values are class ids (they carry classification:classes)
CLASS_ID_FOLDERS = ("labels", "geo")
_MEDIA_TYPES = {".png": pystac.MediaType.PNG, ".jpg": pystac.MediaType.JPEG, ".jpeg": pystac.MediaType.JPEG,
                ".tif": pystac.MediaType.GEOTIFF, ".tiff": pystac.MediaType.GEOTIFF}
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")
_HEX64 = re.compile(r"[0-9a-f]{64}")


def media_type(rel: str) -> str | None:
    """Media type of a sample file from its suffix and folder (None when unknown: no ``type``).

    >>> media_type("images/a.tif"), media_type("geo/a.tif"), media_type("images/a.jpg")
    ('image/tiff; application=geotiff; profile=cloud-optimized', 'image/tiff; application=geotiff', 'image/jpeg')
    """
    path = PurePosixPath(rel)
    known = _MEDIA_TYPES.get(path.suffix.lower())
    if known == pystac.MediaType.GEOTIFF and path.parts[0] == "images":  # written as COGs (--image-format cog)
        known = pystac.MediaType.COG
    return str(known) if known else None


def machine_name(name: str) -> str:
    """A class name as the classification extension's ``name`` (letters, digits, ``-``, ``_``).

    >>> machine_name("dirt road")
    'dirt_road'
    """
    return re.sub(r"[^0-9A-Za-z_-]+", "_", name).strip("_") or "class"


def classification(table: ClassTable) -> list[Classification]:
    """The class table as ``classification:classes``, ordered by id."""
    classes = sorted((table.unlabeled, *table.classes), key=lambda c: c.id)
    names = [machine_name(c.name) for c in classes]
    if len(set(names)) != len(names):
        raise DatasetError(f"manifest classes: names {[c.name for c in classes]} do not stay distinct as {names}")
    return [Classification.create(value=c.id, name=n, title=c.name, color_hint="%02X%02X%02X" % c.color,
                                  description=UNLABELED_TEXT if c.id == 0 else None) for c, n in zip(classes, names)]


def _numbers(value: Any, n: int, what: str) -> list[float]:
    if not (isinstance(value, list) and len(value) == n and all(isinstance(v, (int, float)) for v in value)):
        raise DatasetError(f"manifest: {what} must be {n} numbers, got {value!r}")
    return [float(v) for v in value]


def _date(value: Any, what: str) -> datetime | None:
    if value is None:
        return None
    try:
        stamp = str_to_datetime(str(value))
    except (ValueError, OverflowError):
        raise DatasetError(f"manifest: {what} {value!r} is not an ISO 8601 date") from None
    return stamp if stamp.tzinfo else stamp.replace(tzinfo=timezone.utc)


def _known_dates(manifest: dict[str, Any]) -> list[datetime]:
    """Every OSM date in the manifest, sorted (the fallback span of undated samples)."""
    found = [_date(manifest["osm"].get("timestamp"), "osm.timestamp")]
    for s in manifest["samples"]:
        found += [_date(s["osm"].get(k), f"sample {s['name']} osm.{k}") for k in ("timestamp", "newest_element")]
    return sorted(d for d in found if d is not None)


def _sample_dates(sample: dict[str, Any], known: list[datetime]) -> tuple[datetime | None, ...]:
    """(datetime, start, end) of a sample: its OSM timestamp, else a span (see the module docstring)."""
    stamp = _date(sample["osm"].get("timestamp"), "osm.timestamp")
    if stamp is not None:
        return stamp, None, None
    if not known:
        raise DatasetError(f"manifest: sample {sample['name']} has no OSM date, nor has any other: STAC needs one")
    start = _date(sample["osm"].get("newest_element"), "osm.newest_element") or known[0]
    return None, start, max(start, known[-1])


def _item(sample: dict[str, Any], table: ClassTable, classes: list[Classification], pixels: int,
          known: list[datetime]) -> pystac.Item:
    name = sample["name"]
    if not (isinstance(name, str) and _NAME.fullmatch(name)):
        raise DatasetError(f"manifest: sample name {name!r} is not a file stem ([A-Za-z0-9][A-Za-z0-9_.-]*)")
    w, s, e, n = _numbers(sample["bbox_wgs84"], 4, f"sample {name} bbox_wgs84")
    left, bottom, right, top = _numbers(sample["bounds_3857"], 4, f"sample {name} bounds_3857")
    when, start, end = _sample_dates(sample, known)
    footprint = {"type": "Polygon", "coordinates": [[[w, s], [e, s], [e, n], [w, n], [w, s]]]}
    item = pystac.Item(id=name, geometry=footprint, bbox=[w, s, e, n], datetime=when, start_datetime=start,
                       end_datetime=end, properties={"gsd": float(sample["ground_resolution_m"]),
                                                     "osmseg:zoom": int(sample["zoom"])})
    res = (right - left) / pixels  # as osmseg.grid.SampleGrid.transform: square pixels, north up
    ProjectionExtension.ext(item, add_if_missing=True).apply(
        code=CRS, bbox=[left, bottom, right, top], shape=[pixels, pixels], transform=[res, 0.0, left, 0.0, -res, top])
    histogram = sample["class_histogram"]
    by_name = table.by_name
    if not isinstance(histogram, dict) or not set(histogram) <= set(by_name):
        raise DatasetError(f"manifest: sample {name} class_histogram names classes the class table lacks")
    overview = LabelOverview({})
    overview.counts = [LabelCount.create(c, int(histogram[c])) for c in sorted(histogram, key=lambda c: by_name[c].id)]
    when_text = f"as of {when:%Y-%m-%d %H:%M} UTC" if when else f"edited {start:%Y-%m-%d} or later"
    LabelExtension.ext(item, add_if_missing=True).apply(
        label_description=f"Class ids ({table.name}) rasterised by osmseg from OpenStreetMap data {when_text} "
                          f"(© OpenStreetMap contributors, ODbL 1.0); 0 = unlabeled, not background.",
        label_type=LabelType.RASTER, label_properties=None,
        label_classes=[LabelClasses.create(sorted(table.by_id), None)],
        label_tasks=list(TASKS), label_methods=list(METHODS), label_overviews=[overview])
    _add_assets(item, sample["files"], classes)
    return item


def _add_assets(item: pystac.Item, files: dict[str, str], classes: list[Classification]) -> None:
    """One asset per file; key by folder (``image``, ``labels``, ...; ``image_tif`` when a folder has two)."""
    folders = Counter(PurePosixPath(rel).parts[0] for rel in files)
    for rel, digest in sorted(files.items()):
        path = PurePosixPath(rel)
        if not _HEX64.fullmatch(digest):
            raise DatasetError(f"manifest: sample {item.id} {rel}: {digest!r} is not a sha256 hex digest")
        folder = path.parts[0] if len(path.parts) > 1 else ""
        key, roles, title = ASSET_KINDS.get(folder, (path.stem if not folder else folder, [], None))
        if folders[path.parts[0]] > 1:
            key = f"{key}_{path.suffix.lstrip('.').lower()}"
        asset = pystac.Asset(href=f"../../{rel}", title=title, media_type=media_type(rel), roles=list(roles))
        item.add_asset(key, asset)
        FileExtension.ext(asset, add_if_missing=True).checksum = "1220" + digest
        if folder in ASSET_KINDS and folder != "images":
            asset.extra_fields["license"] = LABEL_LICENSE
        if folder in CLASS_ID_FOLDERS:
            ClassificationExtension.ext(asset, add_if_missing=True).classes = classes
    if "labels" not in item.assets:
        raise DatasetError(f"manifest: sample {item.id} lists no labels/ file")


def _providers(manifest: dict[str, Any]) -> list[pystac.Provider]:
    imagery, osm, version = manifest["imagery"], manifest["osm"], manifest["tool"].get("version", "")
    url = imagery.get("terms_url")  # not "url"/"template": those are tile URLs
    notes = dict.fromkeys(str(imagery[k]) for k in ("attribution", "copyright", "terms") if imagery.get(k))
    return [
        pystac.Provider("OpenStreetMap contributors", osm.get("attribution") or "labels: OpenStreetMap data, ODbL 1.0",
                        roles=[pystac.ProviderRole.LICENSOR, pystac.ProviderRole.PRODUCER], url=OSM_COPYRIGHT_URL),
        pystac.Provider(str(imagery.get("name") or imagery.get("provider") or "imagery provider"),
                        "; ".join(notes) or f"see {ATTRIBUTION_NAME}",
                        roles=[pystac.ProviderRole.LICENSOR, pystac.ProviderRole.PRODUCER],
                        url=url if isinstance(url, str) and url.startswith(("https://", "http://")) else None),
        pystac.Provider("osmseg", f"osmseg {version} rasterised the OSM data on the imagery's tile grid; "
                        f"command: {manifest['command']}", roles=[pystac.ProviderRole.PROCESSOR]),
    ]


def _collection(manifest: dict[str, Any], table: ClassTable, classes: list[Classification],
                items: list[pystac.Item], pixels: int) -> pystac.Collection:
    area = manifest["area"]
    place = str(area.get("name") or "area")
    identity = json.dumps(manifest.get("config") or manifest["command"], sort_keys=True, ensure_ascii=False)
    slug = re.sub(r"[^0-9a-z]+", "-", place.lower()).strip("-") or "area"
    boxes = [i.bbox for i in items if i.bbox] or [_numbers(area.get("bbox") or [-180, -90, 180, 90], 4, "area.bbox")]
    starts = [i.datetime or i.common_metadata.start_datetime for i in items]
    ends = [i.datetime or i.common_metadata.end_datetime for i in items]
    interval: list[datetime | None] = [None, None]
    if items:
        interval = [min(d for d in starts if d), max(d for d in ends if d)]
    extent = pystac.Extent(
        pystac.SpatialExtent([[min(b[0] for b in boxes), min(b[1] for b in boxes),
                               max(b[2] for b in boxes), max(b[3] for b in boxes)]]),
        pystac.TemporalExtent([interval]))
    collection = pystac.Collection(
        id=f"osmseg-{slug}-{hashlib.sha256(identity.encode()).hexdigest()[:8]}",
        title=f"osmseg: {place}, zoom {manifest['zoom']}, {len(items)} samples",
        description=(f"{len(items)} aerial images of {place} ({pixels}x{pixels} px, zoom {manifest['zoom']}) with "
                     f"per-pixel class ids rasterised by osmseg from OpenStreetMap (class table {table.name}). "
                     f"Labels © OpenStreetMap contributors, ODbL 1.0; images under the imagery provider's terms "
                     f"(see {ATTRIBUTION_NAME}). How it was built: {MANIFEST_NAME}, {DATASHEET_NAME}."),
        extent=extent, license="other", providers=_providers(manifest), catalog_type=pystac.CatalogType.SELF_CONTAINED,
        keywords=["OpenStreetMap", "semantic segmentation", "aerial imagery", "training data"])
    collection.add_links([pystac.Link("license", f"../{ATTRIBUTION_NAME}", MARKDOWN, "Labels ODbL 1.0; images"),
                          pystac.Link("license", ODBL_URL, "text/html", "Open Database License 1.0 (labels)")])
    for key, (rel, kind, role) in COLLECTION_ASSETS.items():
        collection.add_asset(key, pystac.Asset(f"../{rel}", media_type=str(kind), roles=[role]))
    definitions: dict[str, pystac.ItemAssetDefinition | dict[str, Any]] = {}
    for item in items:
        for key, asset in item.assets.items():
            fields = {k: v for k, v in asset.extra_fields.items() if k.startswith("classification:")}
            definitions.setdefault(key, pystac.ItemAssetDefinition.create(
                asset.title, None, asset.media_type, asset.roles, extra_fields=fields or None))
    collection.item_assets = definitions
    summaries = LabelExtension.summaries(collection, add_if_missing=True)
    summaries.label_type, summaries.label_tasks = [LabelType.RASTER], list(TASKS)
    summaries.label_methods = list(METHODS)
    summaries.label_classes = [LabelClasses.create(sorted(table.by_id), None)]
    ClassificationExtension.summaries(collection, add_if_missing=True).classes = classes
    ProjectionExtension.summaries(collection, add_if_missing=True).code = [CRS]
    if items:
        gsd = [float(i.properties["gsd"]) for i in items]
        collection.summaries.add("gsd", pystac.RangeSummary(min(gsd), max(gsd)))
        collection.summaries.add("osmseg:zoom", sorted({int(i.properties["osmseg:zoom"]) for i in items}))
    for item in items:
        collection.add_item(item)
    return collection


def _json_text(stac: dict[str, Any]) -> str:
    """Deterministic JSON (as the manifest's), extension URIs sorted."""
    if "stac_extensions" in stac:
        stac["stac_extensions"] = sorted(stac["stac_extensions"])
    try:
        return json.dumps(stac, sort_keys=True, indent=2, ensure_ascii=False, allow_nan=False) + "\n"
    except (TypeError, ValueError) as exc:
        raise DatasetError(f"manifest: a value cannot be written as STAC JSON ({exc})") from None


def write_stac(out_dir: Path, manifest: dict[str, Any]) -> Path:
    """Write ``OUT/stac/collection.json`` and ``OUT/stac/items/NAME.json``; return the Collection's path.

    A pure function of ``manifest`` (reads no file); raises a one-line
    :class:`~osmseg.errors.DatasetError` when the manifest lacks what STAC needs. Items are
    written before the Collection that lists them; items of samples no longer listed are removed.
    """
    validate_manifest(manifest)
    table = ClassTable.from_dict(manifest["classes"], where="manifest classes")
    classes = classification(table)
    try:
        pixels = int(manifest["grid_size"]) * TILE_SIZE
        known = _known_dates(manifest)
        items = [_item(s, table, classes, pixels, known) for s in manifest["samples"]]
        collection = _collection(manifest, table, classes, items, pixels)
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise DatasetError(f"manifest cannot be described as STAC: {type(exc).__name__} {exc}") from None
    root = Path(out_dir).resolve() / STAC_DIR
    collection.set_self_href(str(root / COLLECTION_NAME))
    written = set()
    for item in items:
        path = root / ITEMS_DIR / f"{item.id}.json"
        item.set_self_href(str(path))
        atomic_write_text(path, _json_text(item.to_dict(include_self_link=False, transform_hrefs=True)))
        written.add(path.name)
    collection_json = _json_text(collection.to_dict(include_self_link=False, transform_hrefs=True))
    atomic_write_text(root / COLLECTION_NAME, collection_json)
    for stale in sorted((root / ITEMS_DIR).glob("*.json")):  # items of samples the manifest no longer has
        if stale.name not in written:
            stale.unlink()
    return root / COLLECTION_NAME
