"""Honest samples and splits: overlap reported, sampling that never overlaps, splits by area.

Overlap is checked here with shapely on the manifest's EPSG:3857 boxes, independently of
``osmseg.builder.sampling``. The builds use a GeoJSON source with one large grass polygon (every
sample has a label) and an empty tile folder as imagery (no tile at all: the filters are
opened for it), so a build of a few samples takes a second.
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest
import shapely
from click.testing import CliRunner, Result
from conftest import TEST_DATA

from osmseg.builder.sampling import block_centre, candidate_blocks
from osmseg.cli.main import cli
from osmseg.grid import LngLatBBox, sample_grid
from osmseg.overlap import overlap_groups
from osmseg.places import Area

LON, LAT = 24.94, 60.17


def brute_groups(boxes: list[tuple[float, float, float, float]]) -> list[set[int]]:
    """Connected groups of boxes sharing area, by shapely and breadth-first search."""
    shapes = [shapely.box(*b) for b in boxes]
    linked = {i: {j for j in range(len(boxes)) if j != i and shapes[i].intersection(shapes[j]).area > 0}
              for i in range(len(boxes))}
    seen: set[int] = set()
    groups = []
    for start in range(len(boxes)):
        if start in seen:
            continue
        group, todo = set(), [start]
        while todo:
            i = todo.pop()
            if i not in group:
                group.add(i)
                todo.extend(linked[i] - group)
        seen |= group
        groups.append(group)
    return groups


def test_overlap_groups_are_the_connected_groups_of_boxes_that_share_area() -> None:
    rng = np.random.default_rng(4)
    for _ in range(20):
        corners = rng.integers(0, 40, size=(25, 2)).astype(float)
        boxes = [(x, y, x + 5, y + 5) for x, y in corners]  # integer corners: many boxes only touch
        ids = overlap_groups(boxes)
        found = sorted(sorted(i for i, g in enumerate(ids) if g == k) for k in set(ids))
        assert found == sorted(sorted(g) for g in brute_groups(boxes))


@pytest.mark.parametrize("area", [Area("disc", LAT, LON, radius_km=1.5),
                                  Area("box", LAT, LON, bbox=LngLatBBox(24.90, 60.15, 24.98, 60.19))])
def test_candidate_blocks_tile_the_area_without_overlap(area: Area) -> None:
    blocks = candidate_blocks(area, 18, 5, seed=3)
    assert len(blocks) > 10 and len({tuple(b) for b in blocks}) == len(blocks)
    grids = [sample_grid(*block_centre(int(x), int(y), 18, 5), 18, 5) for x, y in blocks]
    for grid, (bx, by) in zip(grids, blocks):  # the sample grid of a block is the block itself
        assert grid.tiles[0].x == bx * 5 and grid.tiles[0].y == by * 5
    boxes = [tuple(g.xy_bounds) for g in grids]
    assert all(len(g) == 1 for g in brute_groups(boxes))
    assert candidate_blocks(area, 18, 5, seed=3).tolist() == blocks.tolist()  # the seed decides the order
    assert candidate_blocks(area, 18, 5, seed=4).tolist() != blocks.tolist()


# -- through the command line ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def grass(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A GeoJSON polygon of 6 km around the centre: every sample holds one class."""
    path = tmp_path_factory.mktemp("grass") / "grass.geojson"
    d = 0.05
    ring = [[LON - d, LAT - d / 2], [LON + d, LAT - d / 2], [LON + d, LAT + d / 2], [LON - d, LAT + d / 2],
            [LON - d, LAT - d / 2]]
    path.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [ring]}}]}))
    return path


def build(out: Path, grass: Path, *extra: str, samples: int = 6, radius: str = "0.8") -> Result:
    tiles = grass.parent / "no-tiles"  # one empty folder for every build, so their commands match
    tiles.mkdir(exist_ok=True)
    return CliRunner().invoke(cli, [
        "build", "--lat", str(LAT), "--lon", str(LON), "--radius-km", radius, "--samples", str(samples),
        "--seed", "2", "--osm", f"geojson:{grass}:landuse=grass", "--min-classes", "1",
        "--imagery", f"xyz:file://{tiles}/{{z}}/{{x}}/{{y}}.png", "--max-missing-imagery", "1",
        "--max-placeholder-tiles", "25", "--min-contrast", "0", "--out", str(out),
        "--cache-dir", str(out.parent / "cache"), *extra])


def boxes_of(out: Path) -> tuple[list[tuple[float, float, float, float]], dict]:
    manifest = json.loads((out / "manifest.json").read_text())
    return [tuple(s["bounds_3857"]) for s in manifest["samples"]], manifest


def tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and ".osmseg-build" not in p.parts}


def test_random_sampling_reports_overlap_and_no_overlap_sampling_has_none(tmp_path: Path, grass: Path) -> None:
    random = build(tmp_path / "random" / "ds", grass)
    assert random.exit_code == 0, random.output
    boxes, manifest = boxes_of(tmp_path / "random" / "ds")
    groups = brute_groups(boxes)
    overlapping = sum(len(g) for g in groups if len(g) > 1)
    assert overlapping > 0, "pick another seed: these random samples happen not to overlap"
    assert manifest["summary"]["overlapping_samples"] == overlapping
    assert manifest["summary"]["overlap_groups"] == len(groups)
    assert f"{overlapping} of 6 samples overlap another ({len(groups)} spatial group" in random.stderr
    assert "--no-overlap" in random.stderr

    # labels from a GeoJSON file of unknown origin: no OpenStreetMap/ODbL claim anywhere
    ds = tmp_path / "random" / "ds"
    attribution = (ds / "ATTRIBUTION.md").read_text()
    assert "are made from OpenStreetMap data" not in attribution and "does not know where" in attribution
    assert "derive from OpenStreetMap" not in (ds / "DATASHEET.md").read_text()
    item = json.loads(next((ds / "stac" / "items").glob("*[0-9].json")).read_text())
    assert item["assets"]["labels"]["license"] == "other" and "OpenStreetMap data" not in item["properties"][
        "label:description"]

    single = build(tmp_path / "blocks" / "ds", grass, "--no-overlap")
    assert single.exit_code == 0, single.output
    boxes, manifest = boxes_of(tmp_path / "blocks" / "ds")
    assert len(boxes) == 6 and all(len(g) == 1 for g in brute_groups(boxes))
    assert manifest["summary"]["overlapping_samples"] == 0 and "overlap another" not in single.stderr
    assert "--no-overlap" in manifest["command"]

    # exact under --shard: two shards into one folder give the single run's bytes
    sharded = tmp_path / "sharded" / "ds"
    assert build(sharded, grass, "--no-overlap", "--shard", "2/2").exit_code == 0
    assert build(sharded, grass, "--no-overlap", "--shard", "1/2").exit_code == 0
    assert tree(sharded) == tree(tmp_path / "blocks" / "ds")


def test_smaller_samples_fit_more_of_them_in_an_area_without_overlap(tmp_path: Path, grass: Path) -> None:
    """``--sample-tiles 3``: 768 px samples (3x3 tiles), so an area too small for 12 samples of 5x5 tiles
    holds them; every file is that size (read with PIL and rasterio), no two share a pixel, the manifest
    and the STAC catalog say the size, and the recorded command gives it back."""
    import rasterio
    from PIL import Image

    too_small = build(tmp_path / "large", grass, "--no-overlap", samples=12, radius="0.5")
    assert too_small.exit_code == 2 and "holds only" in too_small.output
    out = tmp_path / "ds"
    result = build(out, grass, "--no-overlap", "--sample-tiles", "3", samples=12, radius="0.5")
    assert result.exit_code == 0, result.output
    boxes, manifest = boxes_of(out)
    assert len(boxes) == 12 and all(len(g) == 1 for g in brute_groups(boxes))
    assert manifest["grid_size"] == 3 and "--sample-tiles 3" in manifest["command"]
    sample = manifest["samples"][0]
    with Image.open(out / "labels" / f"{sample['name']}.png") as label, Image.open(
            out / "images" / f"{sample['name']}.png") as image:
        assert label.size == image.size == (768, 768)
    with rasterio.open(out / "geo" / f"{sample['name']}.tif") as geo:
        assert (geo.width, geo.height) == (768, 768)
        left, bottom, right, top = geo.bounds
        assert [left, bottom, right, top] == pytest.approx(sample["bounds_3857"])
    item = json.loads((out / "stac" / "items" / f"{sample['name']}.json").read_text())
    assert item["properties"]["proj:shape"] == [768, 768]
    bad = build(tmp_path / "bad", grass, "--sample-tiles", "4")
    assert bad.exit_code == 2 and "--sample-tiles" in bad.output


def test_no_overlap_refuses_an_area_too_small_for_the_samples(tmp_path: Path, grass: Path) -> None:
    result = build(tmp_path / "ds", grass, "--no-overlap", samples=40, radius="0.5")
    assert result.exit_code == 2, result.output
    assert "holds only" in result.output and "--samples" in result.output
    assert not (tmp_path / "ds").exists()


torch = pytest.importorskip("torch")


def train(dataset: Path, out: Path, *extra: str) -> Result:
    return CliRunner().invoke(cli, ["-q", "train", str(dataset), "--out", str(out), "--config",
                                    str(TEST_DATA / "train" / "tiny.yaml"), "--model", "airsegnet13",
                                    "--epochs", "1", "--max-steps-per-epoch", "1", *extra])


def test_training_keeps_overlapping_samples_in_one_split(tmp_path: Path, grass: Path) -> None:
    data = tmp_path / "ds"
    assert build(data, grass, samples=12, radius="1.2").exit_code == 0
    boxes, manifest = boxes_of(data)
    names = [s["name"] for s in manifest["samples"]]
    groups = [{names[i] for i in g} for g in brute_groups(boxes)]
    assert any(len(g) > 1 for g in groups) and len(groups) >= 3

    result = train(data, tmp_path / "run")
    assert result.exit_code == 0, result.output
    doc = json.loads((tmp_path / "run" / "splits.json").read_text())
    where = {n: split for split, members in doc["splits"].items() for n in members}
    assert set(where) == set(names) and doc["split_by"] == "groups"
    for group in groups:  # every group of samples that share ground sits in one split
        assert len({where[n] for n in group}) == 1, (group, where)
    assert sorted(map(sorted, doc["overlap_groups"])) == sorted(sorted(g) for g in groups if len(g) > 1)
    assert all(doc["splits"][k] for k in ("train", "val", "test"))


def test_samples_that_all_overlap_cannot_be_split_honestly(tmp_path: Path, grass: Path) -> None:
    data = tmp_path / "ds"
    assert build(data, grass, samples=4, radius="0.05").exit_code == 0
    boxes, _ = boxes_of(data)
    assert len(brute_groups(boxes)) == 1
    refused = train(data, tmp_path / "run")
    assert refused.exit_code == 1
    assert "overlap on the ground in 1 separate area," in refused.output and "--no-overlap" in refused.output
    assert not (tmp_path / "run" / "splits.json").exists()
    # asked for explicitly, the old split by image still works, and says what it is
    by_image = train(data, tmp_path / "run-image", "--split-by", "image")
    assert by_image.exit_code == 0, by_image.output
    assert json.loads((tmp_path / "run-image" / "splits.json").read_text())["split_by"] == "image"


def test_splits_of_a_dataset_without_footprints_are_by_image() -> None:
    from training.datasets.splits import make_splits, sample_groups

    names = [f"tinyseg_{i:03d}" for i in range(12)]
    groups = sample_groups(TEST_DATA / "tinyseg", names)  # its manifest has no bounds
    assert len(set(groups.values())) == 12
    assert make_splits(names, 0, groups=groups) == make_splits(names, 0)
    assert list(itertools.chain(*make_splits(names, 0).values()))


def test_georeferenced_images_without_a_manifest_are_grouped_by_their_extents(tmp_path: Path) -> None:
    import rasterio
    from rasterio.transform import from_origin

    from training.datasets.splits import sample_groups

    paths = {}
    for name, x0 in (("a", 400000.0), ("b", 400150.0), ("c", 401000.0)):  # a and b overlap by half
        paths[name] = tmp_path / f"{name}.tif"
        with rasterio.open(paths[name], "w", driver="GTiff", width=1000, height=1000, count=3, dtype="uint8",
                           crs="EPSG:32633", transform=from_origin(x0, 5800000.0, 0.3, 0.3)) as dst:
            dst.write(np.zeros((3, 1000, 1000), np.uint8))
    groups = sample_groups(tmp_path, paths, paths)
    assert groups["a"] == groups["b"] != groups["c"]


def test_no_overlap_blocks_wrap_across_the_antimeridian() -> None:
    east = candidate_blocks(Area("east", 0.0, 179.99, radius_km=5.0), 16, 5, seed=0)
    columns = {int(x) for x in east[:, 0]}
    assert 0 in columns and max(columns) == 2**16 // 5 - 1  # both sides of the 180th meridian
    centres = [block_centre(int(x), int(y), 16, 5) for x, y in east]
    assert all(abs(abs(lon) - 180.0) < 0.1 for lon, _ in centres)
