"""The STAC catalog ``osmseg build`` writes (``OUT/stac/``), read back with pystac alone.

Two real builds of tinycity go through the CLI (local OSM file, local GeoTIFF imagery
painted from it, as in ``test_build.py``). The catalog is then read only with pystac,
jsonschema, rasterio, PIL and numpy: validated against the STAC 1.1 core schemas pystac
bundles (offline: a schema that is not bundled makes the check fail, never fetches), its
extension fields read through pystac's extension APIs and compared with the files
themselves (COG grid, pixel counts by class id, SHA-256 of every asset), and walked the
way Raster Vision's ``parse_stac`` walks a catalog (:func:`parse_stac_like_raster_vision`).
"""

from __future__ import annotations

import copy
import hashlib
import json
import shutil
import warnings
from collections.abc import Callable, Sequence
from dataclasses import replace
from datetime import datetime
from pathlib import Path
from typing import Any, overload

import numpy as np
import pystac
import pytest
import rasterio
from click.testing import CliRunner
from jsonschema import Draft7Validator
from PIL import Image
from pystac.extensions.classification import ClassificationExtension
from pystac.extensions.file import FileExtension
from pystac.extensions.projection import ProjectionExtension
from pystac.utils import make_absolute_href
from pystac.validation.local_validator import get_local_schema_cache
from rasterio.warp import transform_bounds
from referencing import Registry, Resource
from shapely.geometry import box

with warnings.catch_warnings():  # pystac flags the label extension as unmaintained
    warnings.simplefilter("ignore", DeprecationWarning)
    from pystac.extensions.label import LabelExtension, LabelType

from conftest import TEST_DATA

from osmseg.cli.main import cli
from osmseg.errors import DatasetError
from osmseg.output.manifest import DatasetManifest, RejectionRecord, SampleRecord
from osmseg.output.stac import write_stac as write_typed_stac

TINYCITY = TEST_DATA / "tinycity" / "tinycity.osm"
LON, LAT = 24.94, 60.17
SCHEMAS = get_local_schema_cache()


def _not_bundled(uri: str) -> Resource[Any]:
    raise LookupError(f"{uri} is not bundled with pystac; this check does not fetch")


REGISTRY = Registry(retrieve=_not_bundled).with_resources(  # type: ignore[call-arg]
    [(uri, Resource.from_contents(schema)) for uri, schema in SCHEMAS.items()])


def core_errors(doc: dict[str, Any]) -> list[str]:
    """Messages of every violation of the STAC core schema (item, collection, catalog) of ``doc``."""
    kind = {"Feature": "item", "Collection": "collection", "Catalog": "catalog"}[doc["type"]]
    schema = SCHEMAS[f"https://schemas.stacspec.org/v{doc['stac_version']}/{kind}-spec/json-schema/{kind}.json"]
    validator = Draft7Validator(schema, registry=REGISTRY)
    return [f"{list(e.absolute_path)}: {e.message}" for e in validator.iter_errors(doc)]


def build(out: Path, imagery: Path) -> dict[str, Any]:
    args = ["-q", "build", "--lat", str(LAT), "--lon", str(LON), "--radius-km", "0.08", "--samples", "3",
            "--seed", "1", "--imagery", f"geotiff:{imagery}", "--osm", str(TINYCITY), "--out", str(out),
            "--cache-dir", str(out.parent / "cache")]
    result = CliRunner().invoke(cli, args, catch_exceptions=False)
    assert result.exit_code == 0, result.output
    manifest: dict[str, Any] = json.loads((out / "manifest.json").read_text())
    return manifest


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory, imagery_tif: Path) -> tuple[Path, Path, dict[str, Any]]:
    """The same 3-sample dataset built twice, in two folders, from conftest's ``imagery_tif`` (tinycity
    painted into a GeoTIFF in EPSG:3067); and its manifest."""
    first = tmp_path_factory.mktemp("first") / "ds"
    second = tmp_path_factory.mktemp("second") / "elsewhere"
    manifest = build(first, imagery_tif)
    assert build(second, imagery_tif) == manifest
    return first, second, manifest


LABEL_SCHEMA = LabelExtension.get_schema_uri()
LABEL_ASSETS = ["labels", "labels_style", "labels_png", "segmented", "image"]  # the order of a label item's assets


def items_of(out: Path) -> tuple[pystac.Collection, list[pystac.Item], dict[str, pystac.Item]]:
    """The Collection, its label items in order, and its image items by id."""
    collection = pystac.Collection.from_file(str(out / "stac" / "collection.json"))
    items = list(collection.get_items())
    labels = [i for i in items if LabelExtension.has_extension(i)]
    return collection, labels, {i.id: i for i in items if not LabelExtension.has_extension(i)}


def parse_stac_like_raster_vision(catalog_json: Path) -> list[dict[str, Any]]:
    """Raster Vision's ``parse_stac`` (``rastervision.core.utils.stac``), step by step, with pystac alone.

    Two differences, both offline stand-ins: a label item is one listing the label extension's
    schema (Raster Vision downloads every schema of ``stac_extensions`` and looks for the title
    "Label Extension"), and each entry also keeps the ``image_item`` it found.
    """
    cat = pystac.Catalog.from_file(str(catalog_json))
    cat.make_all_asset_hrefs_absolute()
    with warnings.catch_warnings():  # pystac 1.x deprecates get_all_items (for get_items(recursive=True))
        warnings.simplefilter("ignore", DeprecationWarning)
        label_items = [item for item in cat.get_all_items() if LABEL_SCHEMA in item.stac_extensions]
    if not label_items:
        raise ValueError("Unable to find any label items in STAC catalog.")
    out = []
    for label_item in label_items:
        links = [link for link in label_item.links if link.rel.lower() == "source"]
        if len(links) > 1:
            raise NotImplementedError()
        image_item = links[0].resolve_stac_object().target if links else None
        label_bbox = box(*label_item.bbox)
        assert isinstance(image_item, pystac.Item), label_item.id
        image_bbox = box(*image_item.bbox)
        out.append({
            "label_uri": list(label_item.assets.values())[0].href,
            "image_uris": [a.href for a in image_item.get_assets().values()
                           if "image" in a.media_type],  # type: ignore[operator]  # None raises, as in RV
            "label_bbox": label_bbox, "image_bbox": image_bbox,
            "bboxes_intersect": label_bbox.intersects(image_bbox), "aoi_geometry": label_item.geometry,
            "image_item": image_item})
    return out


def test_catalog_collection_and_items_are_valid_stac_core(built: tuple[Path, Path, dict[str, Any]]) -> None:
    out, _, manifest = built
    collection, items, images = items_of(out)
    names = [s["name"] for s in manifest["samples"]]
    assert [i.id for i in items] == names and len(items) == 3 and sorted(images) == [f"{n}_image" for n in names]
    assert [i.id for i in collection.get_items()] == [i for n in names for i in (n, f"{n}_image")]
    docs = [json.loads(p.read_text()) for p in sorted((out / "stac").rglob("*.json"))]
    assert len(docs) == 8 and [d["type"] for d in docs[:2]] == ["Catalog", "Collection"]
    for doc in docs:
        assert core_errors(doc) == [], doc["id"]
    broken = copy.deepcopy(next(d for d in docs if d["type"] == "Feature"))
    del broken["properties"]["datetime"]
    broken["bbox"] = broken["bbox"][:3]
    assert len(core_errors(broken)) >= 2  # the check itself can fail
    assert all(i.collection_id == collection.id for i in [*items, *images.values()])
    catalog = pystac.Catalog.from_file(str(out / "stac" / "catalog.json"))
    assert [c.id for c in catalog.get_children()] == [collection.id]
    root_link = collection.get_root_link()
    assert root_link is not None and Path(root_link.get_absolute_href() or "") == out / "stac" / "catalog.json"
    with pytest.raises(pystac.STACTypeError):  # why the root is a Catalog: readers such as Raster Vision need one
        pystac.Catalog.from_file(str(out / "stac" / "collection.json"))
    assert collection.license == "other"
    licences = [Path(link.get_absolute_href() or "") for link in collection.get_links("license")]
    assert any(p.name == "ATTRIBUTION.md" and p.is_file() for p in licences)
    roles = {p.name: p.roles for p in collection.providers or []}
    assert roles["OpenStreetMap contributors"] == ["licensor", "producer"] and roles["osmseg"] == ["processor"]


def test_items_describe_the_labels_and_the_grid_of_the_cogs(built: tuple[Path, Path, dict[str, Any]]) -> None:
    out, _, manifest = built
    collection, items, images = items_of(out)
    ids = sorted(c["id"] for c in manifest["classes"]["classes"])
    by_name = {s["name"]: s for s in manifest["samples"]}
    for item in items:
        label = LabelExtension.ext(item)
        assert label.label_type == LabelType.RASTER and label.label_tasks == ["segmentation"]
        assert label.label_properties is None and len(label.label_classes or []) == 1
        assert sorted((label.label_classes or [])[0].classes) == ids
        proj = ProjectionExtension.ext(item)
        assert proj.code == "EPSG:3857"
        assert item.bbox is not None and item.datetime is not None
        with rasterio.open(item.assets["labels"].get_absolute_href() or "") as src:
            assert src.crs.to_epsg() == 3857 and src.tags(ns="IMAGE_STRUCTURE")["LAYOUT"] == "COG"
            assert proj.shape == [src.height, src.width] == [1280, 1280]
            assert proj.transform == pytest.approx(list(src.transform)[:6], rel=0, abs=1e-6)
            assert proj.bbox == pytest.approx(list(src.bounds), rel=0, abs=1e-6)
            assert item.bbox == pytest.approx(list(transform_bounds(src.crs, "EPSG:4326", *src.bounds)), abs=1e-9)
        with Image.open(item.assets["labels_png"].get_absolute_href() or "") as im:
            assert list(im.size) == proj.shape[::-1]
        stamp = by_name[item.id]["osm"]["timestamp"]
        assert item.datetime == datetime.fromisoformat(stamp.replace("Z", "+00:00"))
        west, south, east, north = collection.extent.spatial.bboxes[0]
        assert west <= item.bbox[0] and south <= item.bbox[1] and item.bbox[2] <= east and item.bbox[3] <= north
        start, end = collection.extent.temporal.intervals[0]
        assert start is not None and end is not None and start <= item.datetime <= end
        image = images[f"{item.id}_image"]  # the imagery: same place, time and grid, no labels
        assert (image.geometry, image.bbox, image.datetime) == (item.geometry, item.bbox, item.datetime)
        assert {k: v for k, v in image.properties.items() if k.startswith("proj:")} == \
            {k: v for k, v in item.properties.items() if k.startswith("proj:")}
        assert not any(k.startswith("label:") for k in image.properties)


def test_every_asset_is_a_file_with_the_recorded_checksum(built: tuple[Path, Path, dict[str, Any]]) -> None:
    out, _, manifest = built
    collection, items, images = items_of(out)
    listed = {(out / rel).resolve() for s in manifest["samples"] for rel in s["files"]}
    seen = set()
    for item in [*items, *images.values()]:
        for key, asset in item.assets.items():
            path = Path(asset.get_absolute_href() or "").resolve()
            assert path.is_file(), f"{item.id} {key}: {asset.href}"
            digest = hashlib.sha256(path.read_bytes()).hexdigest()
            assert FileExtension.ext(asset).checksum == "1220" + digest
            seen.add(path)
    for item in items:
        assert list(item.assets) == LABEL_ASSETS
        image = images[f"{item.id}_image"]
        assert list(image.assets) == ["image"] and image.assets["image"].to_dict() == item.assets["image"].to_dict()
        assert item.assets["image"].media_type == "image/png" and item.assets["image"].roles == ["data"]
        assert item.assets["labels"].media_type == pystac.MediaType.COG == "image/tiff; application=geotiff; " \
                                                                              "profile=cloud-optimized"
        assert item.assets["labels_png"].media_type == "image/png"
        assert item.assets["labels"].roles == ["labels"] and item.assets["labels_png"].roles == ["labels"]
        assert Path(item.assets["labels"].href).parts[-2:] == ("geo", f"{item.id}.tif")
        style = item.assets["labels_style"]  # the QGIS style beside the label COG: no classes, not labels
        assert Path(style.href).parts[-2:] == ("geo", f"{item.id}.qml")
        assert (style.media_type, style.roles) == ("application/xml", ["metadata"])
        assert "classification:classes" not in style.extra_fields and "license" not in style.extra_fields
    assert seen == listed
    assert list(collection.item_assets) == LABEL_ASSETS
    for asset in collection.assets.values():
        assert Path(asset.get_absolute_href() or "").is_file()


def test_overviews_count_the_label_pixels_of_each_class_id(built: tuple[Path, Path, dict[str, Any]]) -> None:
    out, _, manifest = built
    listed = [c["id"] for c in manifest["classes"]["classes"]]
    assert listed != sorted(listed)  # classes13 lists dirt road (12) second: position is not id
    _, items, _ = items_of(out)
    for item in items:
        png = item.assets["labels_png"]
        classes = ClassificationExtension.ext(png).classes or []
        cog_classes = ClassificationExtension.ext(item.assets["labels"]).classes or []
        assert [c.to_dict() for c in classes] == [c.to_dict() for c in cog_classes]
        id_of = {c.title: c.value for c in classes}
        assert id_of["dirt road"] == 12 and id_of["unlabeled"] == 0
        overviews = LabelExtension.ext(item).label_overviews or []
        counts = {c.name: c.count for c in overviews[0].counts or []}
        pixels = np.asarray(Image.open(png.get_absolute_href() or ""))
        per_id = np.bincount(pixels.ravel(), minlength=256)
        assert {id_of[name]: n for name, n in counts.items()} == {i: int(per_id[i]) for i in id_of.values()}
        assert sum(counts.values()) == pixels.size and sum(n > 0 for n in counts.values()) >= 3
        with rasterio.open(item.assets["labels"].get_absolute_href() or "") as src:  # names, colours as in the file
            colours, tags = src.colormap(1), src.tags(1)
            assert np.array_equal(src.read(1), pixels)
        for c in classes:
            assert tags[f"CLASS_{c.value}"] == c.title
            assert "{:02X}{:02X}{:02X}".format(*colours[c.value][:3]) == c.color_hint


def test_raster_vision_finds_label_cog_and_image_of_every_sample(built: tuple[Path, Path, dict[str, Any]]) -> None:
    out, _, manifest = built
    assert list(out.glob("**/catalog.json")) == [out / "stac" / "catalog.json"]  # what read_stac looks for in a zip
    parsed = parse_stac_like_raster_vision(out / "stac" / "catalog.json")
    samples = manifest["samples"]
    assert len(parsed) == len(samples) == 3
    ids = sorted(c["id"] for c in manifest["classes"]["classes"])
    for entry, sample in zip(parsed, samples):
        name = sample["name"]
        assert Path(entry["label_uri"]) == out.resolve() / "geo" / f"{name}.tif"  # absolute: parse_stac made it so
        with rasterio.open(entry["label_uri"]) as src:
            assert (src.count, src.dtypes, src.crs.to_epsg()) == (1, ("uint8",), 3857)
            assert src.tags(ns="IMAGE_STRUCTURE")["LAYOUT"] == "COG" and src.nodata is None
            assert set(np.unique(src.read(1))) <= set(ids)
        image_item = entry["image_item"]
        assert image_item.id == f"{name}_image" and not LabelExtension.has_extension(image_item)
        # parse_stac re-reads the linked image item, after making hrefs absolute: its hrefs stay
        # relative to that item's file (stac/items/), so they resolve against it, as pystac does
        files = [Path(make_absolute_href(uri, image_item.get_self_href())) for uri in entry["image_uris"]]
        image_rel = next(rel for rel in sample["files"] if rel.startswith("images/"))
        assert files == [out.resolve() / image_rel]
        assert entry["bboxes_intersect"] and entry["label_bbox"].equals(entry["image_bbox"])
        assert entry["aoi_geometry"] == image_item.geometry


def test_same_dataset_gives_identical_stac_bytes_and_the_folder_moves(built: tuple[Path, Path, dict[str, Any]],
                                                                       tmp_path: Path) -> None:
    first, second, _ = built
    tree, again = ({p.relative_to(root).as_posix(): p.read_bytes() for p in sorted((root / "stac").rglob("*"))
                    if p.is_file()} for root in (first, second))
    assert tree == again and len(tree) == 8
    assert not any(str(first).encode() in data or str(second).encode() in data for data in tree.values())
    moved = tmp_path / "moved"
    shutil.copytree(first, moved)
    _, items, images = items_of(moved)
    for item in [*items, *images.values()]:
        for asset in item.assets.values():
            assert Path(asset.get_absolute_href() or "").resolve().is_relative_to(moved.resolve())
    assert len(parse_stac_like_raster_vision(moved / "stac" / "catalog.json")) == 3


# -- write_stac on hand-written manifests ------------------------------------------------------

def write_stac(out: Path, manifest: dict[str, Any] | DatasetManifest) -> Path:
    """:func:`osmseg.output.stac.write_stac` of a manifest as it is read: from its JSON, checked."""
    return write_typed_stac(out, manifest if isinstance(manifest, DatasetManifest) else DatasetManifest.from_json(manifest))


def manifest_of(*samples: dict[str, Any]) -> dict[str, Any]:
    return {
        "format": "osmseg-dataset", "format_version": 1, "tool": {"name": "osmseg", "version": "0.1.0"},
        "command": "osmseg build --city Testville", "seed": 0, "zoom": 18, "grid_size": 5,
        "area": {"name": "Test ville", "kind": "urban", "lat": 60.17, "lon": 24.94, "radius_km": 1.0, "bbox": None},
        "classes": {"name": "two", "classes": [{"id": 0, "name": "unlabeled", "color": [0, 0, 0]},
                                                {"id": 7, "name": "dirt road", "color": [232, 116, 32]}]},
        "filters": {}, "imagery": {"provider": "xyz", "attribution": "© Example Aerial"},
        "osm": {"source": "api"}, "samples": list(samples), "rejected": [],
        "summary": {"accepted": len(samples)},
    }


def sample(name: str, timestamp: str | None, newest: str | None = None) -> dict[str, Any]:
    files = {f"{d}/{name}.{ext}": hashlib.sha256(f"{d}{name}".encode()).hexdigest()
             for d, ext in (("images", "tif"), ("labels", "png"), ("geo", "tif"), ("segmented", "png"))}
    return {"name": name, "center": {"lon": 24.94, "lat": 60.17}, "bbox_wgs84": [24.93, 60.16, 24.95, 60.18],
            "bounds_3857": [2775000.0, 8437000.0, 2775764.37, 8437764.37], "zoom": 18, "ground_resolution_m": 0.297,
            "tiles": [], "imagery": {}, "osm": {"timestamp": timestamp, "newest_element": newest},
            "class_histogram": {"unlabeled": 1638000, "dirt road": 400}, "files": files}


def test_an_undated_sample_spans_the_dates_the_manifest_knows(tmp_path: Path) -> None:
    manifest = manifest_of(sample("a_1", None, newest="2019-04-21T09:50:14Z"), sample("a_2", "2024-05-01T12:00:00Z"))
    manifest["imagery"].update(terms="no redistribution", url="https://t.example/{z}/{x}/{y}.png")
    assert write_stac(tmp_path, manifest) == (tmp_path / "stac" / "catalog.json").resolve()
    path = tmp_path / "stac" / "collection.json"
    imagery = json.loads(path.read_text())["providers"][1]
    assert imagery == {"name": "xyz", "description": "© Example Aerial; no redistribution",
                       "roles": ["licensor", "producer"]}  # a tile URL is not the provider's page
    undated = json.loads((tmp_path / "stac" / "items" / "a_1.json").read_text())
    assert core_errors(undated) == [] and core_errors(json.loads(path.read_text())) == []
    image_item = json.loads((tmp_path / "stac" / "items" / "a_1_image.json").read_text())
    assert core_errors(image_item) == []
    for props in (undated["properties"], image_item["properties"]):
        assert props["datetime"] is None
        assert (props["start_datetime"], props["end_datetime"]) == ("2019-04-21T09:50:14Z", "2024-05-01T12:00:00Z")
    cog = "image/tiff; application=geotiff; profile=cloud-optimized"  # images/*.tif (--image-format cog), geo/*.tif
    assert undated["assets"]["image"]["type"] == image_item["assets"]["image"]["type"] == cog
    assert undated["assets"]["labels"]["type"] == cog and undated["assets"]["labels"]["href"] == "../../geo/a_1.tif"
    for key in ("labels", "labels_png"):
        names = {c["title"]: c["name"] for c in undated["assets"][key]["classification:classes"]}
        assert names == {"unlabeled": "unlabeled", "dirt road": "dirt_road"}
    interval = json.loads(path.read_text())["extent"]["temporal"]["interval"]
    assert interval == [["2019-04-21T09:50:14Z", "2024-05-01T12:00:00Z"]]


def test_write_stac_is_repeatable_and_drops_items_of_removed_samples(tmp_path: Path) -> None:
    manifest = manifest_of(sample("a_1", "2024-05-01T12:00:00Z"), sample("a_2", "2024-05-01T12:00:00Z"))
    manifest["samples"][0]["files"]["extra/a_1.txt"] = hashlib.sha256(b"extra").hexdigest()
    write_stac(tmp_path, manifest)
    before = {p.name: p.read_bytes() for p in (tmp_path / "stac").rglob("*.json")}
    assert len(before) == 6
    write_stac(tmp_path, copy.deepcopy(manifest))
    assert {p.name: p.read_bytes() for p in (tmp_path / "stac").rglob("*.json")} == before
    doc = json.loads(before["a_1.json"])  # keys sorted, but the assets in their order: the label raster first
    assert list(doc) == sorted(doc) and list(doc["properties"]) == sorted(doc["properties"])
    assert list(doc["assets"]) == ["labels", "labels_png", "segmented", "extra", "image"]
    assert all(list(a) == sorted(a) for a in doc["assets"].values())
    assert [link["rel"] for link in doc["links"]].count("source") == 1
    collection = json.loads(before["collection.json"])
    assert list(collection["item_assets"]) == list(doc["assets"])
    assert list(collection["assets"]) == ["manifest", "datasheet", "attribution", "overview"]
    write_stac(tmp_path, manifest_of(manifest["samples"][1]))
    assert sorted(p.name for p in (tmp_path / "stac" / "items").iterdir()) == ["a_2.json", "a_2_image.json"]


class Entry(SampleRecord):
    """A sample record that counts how many are alive (CPython frees it as soon as nothing refers to it)."""

    alive = 0

    def __del__(self) -> None:
        Entry.alive -= 1


class LazySamples(Sequence[Any]):
    """Records decoded from JSON text at every access, as a build's finaliser reads them from disk:
    counts the reads of each entry and the most entries alive at once."""

    def __init__(self, entries: list[dict[str, Any]], read: Callable[[Any], Any] = Entry.from_json) -> None:
        self.texts = [json.dumps(e) for e in entries]
        self.reads = [0] * len(entries)
        self.most_alive = 0
        self.read = read

    def __len__(self) -> int:
        return len(self.texts)

    @overload
    def __getitem__(self, i: int) -> Any: ...
    @overload
    def __getitem__(self, i: slice) -> list[Any]: ...
    def __getitem__(self, i: int | slice) -> Any:
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        self.reads[i] += 1
        entry = self.read(json.loads(self.texts[i]))
        if isinstance(entry, Entry):
            Entry.alive += 1
            self.most_alive = max(self.most_alive, Entry.alive)
        return entry


def test_write_stac_reads_a_lazy_sequence_of_samples_a_few_times(tmp_path: Path) -> None:
    entries = [sample("a_1", None, newest="2019-04-21T09:50:14Z"), sample("a_2", "2024-05-01T12:00:00Z"),
               sample("a_3", None)]
    write_stac(tmp_path / "list", manifest_of(*entries))
    lazy = LazySamples(entries)
    rejected = LazySamples([{"center": {"lon": 24.9, "lat": 60.2}, "reason": "unlabeled", "detail": "-"}],
                           RejectionRecord.from_json)
    write_stac(tmp_path / "lazy", replace(DatasetManifest.from_json(manifest_of()), samples=lazy, rejected=rejected))
    tree, again = ({p.relative_to(root).as_posix(): p.read_bytes() for p in sorted((root / "stac").rglob("*"))
                    if p.is_file()} for root in (tmp_path / "list", tmp_path / "lazy"))
    assert again == tree and len(tree) == 8
    assert all(1 <= n <= 3 for n in lazy.reads), lazy.reads  # validation, the Collection's facts, the items
    assert lazy.most_alive <= 2, "entries are dropped as they are used"  # the one in hand and the one before


@pytest.mark.parametrize(("damage", "says"), [
    (lambda m: m["samples"][0].update(bbox_wgs84=[1, 2, 3]), "bbox_wgs84"),
    (lambda m: m["samples"][0]["files"].update({"labels/a_1.png": "not-a-digest"}), "sha256"),
    (lambda m: m["samples"][0]["class_histogram"].update(lava=3), "class_histogram"),
    (lambda m: m["samples"][0]["files"].pop("geo/a_1.tif"), "0 geo/ files"),
    (lambda m: m["samples"][0]["files"].update({"images/a_1.png": "0" * 64}), "2 images/ files"),
    (lambda m: m["samples"].append(sample("a_1_image", None)), "image item id of sample 'a_1'"),
    (lambda m: m["samples"][0]["osm"].update(timestamp="yesterday"), "ISO 8601"),
    (lambda m: m["samples"][0].update(name="../escape"), "file stem"),
    (lambda m: m.pop("samples"), "missing keys"),
    (lambda m: m.update(samples="a_1"), "must be lists"),  # any sequence, but not a string
    (lambda m: m["classes"]["classes"].pop(0), "class ids"),
])
def test_a_malformed_manifest_gives_one_line(tmp_path: Path, damage: Any, says: str) -> None:
    manifest = manifest_of(sample("a_1", "2024-05-01T12:00:00Z"))
    damage(manifest)
    with pytest.raises(DatasetError) as info:
        write_stac(tmp_path, manifest)
    assert says in str(info.value) and "\n" not in str(info.value)
    assert not (tmp_path / "stac" / "collection.json").exists() and not (tmp_path / "stac" / "catalog.json").exists()
