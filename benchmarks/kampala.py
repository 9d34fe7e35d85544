"""A real held-out dataset: Kampala z21 drone tiles + OSM building footprints, in CamVid layout.

Used by ``bench_real_heldout.py`` (and ``tests/train/test_bench_baseline.py``). The source is
``../shared/data/kampala-oam`` (OpenAerialMap contributors, CC-BY 4.0; footprints
OpenStreetMap contributors, ODbL), which is not part of the project: it is read in place and
the dataset is written wherever the caller says (a temporary folder).

The complete z21 block (x 1238448-1238459, y 1046528-1046535: 12 columns x 8 rows of
256 px tiles, ~0.075 m/px) is cut into mosaics that never share a tile:

* the **west 7 columns** are four strips of 7x2 tiles (1792x512 px); one of them, drawn with
  the seed, is the validation split, the other three the training split;
* the **east 5 columns** are two mosaics of 5x4 tiles (1280x1024 px): the test split. They
  are spatially separate from everything the network or the baseline learns from.

A second, smaller complete z21 block, 4x4 tiles (x 1238424-1238427, y 1046544-1046547, about
450 m south-west of the first), is a fourth training mosaic (1024x1024 px): a dense quarter
of corrugated-metal roofs, the kind of roof the west strips hold few of and the test columns
many. It is further from the test split than the west strips are. The 16 z19/z20 tiles of the
folder repeat ground of these two blocks at a coarser zoom and are not used.

Each mosaic is a GeoTIFF in Web Mercator (EPSG:3857, bounds from ``mercantile.xy_bounds``),
so the trainer records the ground resolution and ``osmseg predict --resolution model`` can
bring other imagery to it. Labels are the footprints reprojected to EPSG:3857 (pyproj,
shapely) and burnt with ``rasterio.features.rasterize`` on the mosaic's transform: 1 background,
2 building, and 0 "unlabeled" (the trainer's ignored class, ``classes.toml``) where the tile is
transparent (alpha 0: the drone did not fly there).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import mercantile
import numpy as np
import rasterio
import shapely
from PIL import Image
from pyproj import Transformer
from rasterio.features import rasterize
from rasterio.transform import from_bounds
from shapely.geometry import shape as geojson_shape

ZOOM = 21
BLOCK_X = tuple(range(1238448, 1238460))  # 12 columns, west to east
BLOCK_Y = tuple(range(1046528, 1046536))  # 8 rows, north to south
WEST_COLUMNS = 7  # train + val; the other 5 columns are the test split
SOUTH_WEST_X = tuple(range(1238424, 1238428))  # a second complete block: training only
SOUTH_WEST_Y = tuple(range(1046544, 1046548))
TILE = 256
UNLABELED, BACKGROUND, BUILDING = 0, 1, 2
CLASSES_TOML = """\
# Kampala buildings (bench_real_heldout.py): 0 is unlabeled (transparent drone pixels,
# ignored by the loss and the metrics), 1 background, 2 building (OSM footprints).
name = "kampala-buildings"
description = "background / building from OSM footprints; unlabeled where the drone image is empty"
unlabeled = { id = 0, name = "unlabeled", color = [0, 0, 0] }

[[classes]]
id = 1
name = "background"
color = [128, 128, 128]

[[classes]]
id = 2
name = "building"
color = [255, 255, 0]
"""


@dataclass(frozen=True)
class Mosaic:
    """A rectangle of z21 tiles of the block, written as one image of a split."""

    split: str
    xs: tuple[int, ...]
    ys: tuple[int, ...]

    @property
    def name(self) -> str:
        return f"kampala-z{ZOOM}-x{self.xs[0]}-{self.xs[-1]}-y{self.ys[0]}-{self.ys[-1]}"

    @property
    def tiles(self) -> list[mercantile.Tile]:
        return [mercantile.Tile(x, y, ZOOM) for y in self.ys for x in self.xs]

    @property
    def shape(self) -> tuple[int, int]:
        return len(self.ys) * TILE, len(self.xs) * TILE

    @property
    def transform(self) -> Any:
        """The mosaic's affine transform in EPSG:3857 (from the corner tiles' Mercator bounds)."""
        nw = mercantile.xy_bounds(self.xs[0], self.ys[0], ZOOM)
        se = mercantile.xy_bounds(self.xs[-1], self.ys[-1], ZOOM)
        height, width = self.shape
        return from_bounds(nw.left, se.bottom, se.right, nw.top, width, height)


def layout(seed: int) -> list[Mosaic]:
    """The mosaics of the three splits; ``seed`` picks which west strip is validation."""
    west, east = BLOCK_X[:WEST_COLUMNS], BLOCK_X[WEST_COLUMNS:]
    strips = [BLOCK_Y[i:i + 2] for i in range(0, len(BLOCK_Y), 2)]
    val = int(np.random.default_rng(seed).integers(len(strips)))
    mosaics = [Mosaic("val" if i == val else "train", west, ys) for i, ys in enumerate(strips)]
    mosaics.append(Mosaic("train", SOUTH_WEST_X, SOUTH_WEST_Y))
    mosaics += [Mosaic("test", east, BLOCK_Y[i:i + 4]) for i in (0, 4)]
    return mosaics


def read_mosaic(tiles_dir: Path, mosaic: Mosaic) -> np.ndarray:
    """The mosaic's pixels, ``(H, W, 4)`` RGBA uint8 (alpha 0 where a tile is empty)."""
    canvas = Image.new("RGBA", (mosaic.shape[1], mosaic.shape[0]))
    for tile in mosaic.tiles:
        path = tiles_dir / f"OAM-{tile.x}-{tile.y}-{tile.z}.png"
        with Image.open(path) as im:
            canvas.paste(im.convert("RGBA"), ((tile.x - mosaic.xs[0]) * TILE, (tile.y - mosaic.ys[0]) * TILE))
    return np.asarray(canvas)


def footprints_3857(geojson: Path) -> list[Any]:
    """The building polygons of a WGS84 GeoJSON, reprojected to Web Mercator metres (and made
    valid: one Kampala footprint crosses itself)."""
    to_3857 = Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True)
    features = json.loads(geojson.read_text(encoding="utf-8"))["features"]
    polygons = [geojson_shape(f["geometry"]) for f in features if f.get("geometry")]
    def to_metres(xy: np.ndarray) -> np.ndarray:
        return np.column_stack(to_3857.transform(xy[:, 0], xy[:, 1]))

    return [shapely.make_valid(shapely.transform(p, to_metres)) for p in polygons]


def mosaic_labels(mosaic: Mosaic, polygons: list[Any], alpha: np.ndarray) -> np.ndarray:
    """Class ids on the mosaic's grid: footprints burnt as building, the rest background,
    transparent pixels unlabeled."""
    labels = rasterize([(p, BUILDING) for p in polygons], out_shape=mosaic.shape, transform=mosaic.transform,
                       fill=BACKGROUND, dtype="uint8")
    labels[alpha == 0] = UNLABELED
    return cast("np.ndarray", labels)


def write_geotiff(path: Path, bands: np.ndarray, transform: Any) -> None:
    """``bands`` ``(H, W)`` or ``(H, W, C)`` uint8 as a DEFLATE GeoTIFF in EPSG:3857."""
    array = bands[:, :, None] if bands.ndim == 2 else bands
    with rasterio.open(path, "w", driver="GTiff", width=array.shape[1], height=array.shape[0],
                       count=array.shape[2], dtype="uint8", crs="EPSG:3857", transform=transform,
                       compress="deflate") as dst:
        dst.write(array.transpose(2, 0, 1))


def build_kampala(shared_data: Path, out: Path, seed: int = 0, fit_test: bool = False) -> dict[str, Any]:
    """Write the CamVid-layout dataset into ``out`` (``train/`` + ``trainannot/``, ``val/`` +
    ``valannot/``, ``test/`` + ``testannot/``, ``classes.toml``); returns what was written, per
    mosaic: split, tiles, size and class fractions (counted on the arrays written).

    ``fit_test``: a ceiling, not a benchmark: each test mosaic is *also* a training mosaic
    (``train/fit-NAME.tif``), so a network is scored on ground it learnt from; what it reaches
    there bounds what the held-out split can show with these labels and this budget."""
    source = Path(shared_data) / "kampala-oam"
    polygons = footprints_3857(source / "osm-buildings.geojson")
    out.mkdir(parents=True, exist_ok=True)
    (out / "classes.toml").write_text(CLASSES_TOML, encoding="utf-8")
    written: list[dict[str, Any]] = []
    for mosaic in layout(seed):
        rgba = read_mosaic(source / "tiles", mosaic)
        labels = mosaic_labels(mosaic, polygons, rgba[:, :, 3])
        copies = [(mosaic.split, mosaic.name)] + ([("train", f"fit-{mosaic.name}")] if fit_test and
                                                   mosaic.split == "test" else [])
        for split, name in copies:
            for folder in (split, f"{split}annot"):
                (out / folder).mkdir(exist_ok=True)
            write_geotiff(out / split / f"{name}.tif", rgba[:, :, :3], mosaic.transform)
            write_geotiff(out / f"{split}annot" / f"{name}.tif", labels, mosaic.transform)
        labelled = labels != UNLABELED
        written.append({
            "name": mosaic.name, "split": mosaic.split, "tiles": [[t.x, t.y, t.z] for t in mosaic.tiles],
            "width": mosaic.shape[1], "height": mosaic.shape[0],
            "unlabeled_fraction": round(float(1 - labelled.mean()), 4),
            "building_fraction": round(float((labels == BUILDING).sum() / max(1, labelled.sum())), 4),
        })
    return {"root": str(out), "seed": seed, "zoom": ZOOM, "mosaics": written,
            "source": "kampala-oam: OpenAerialMap contributors (CC-BY 4.0), OSM footprints (ODbL)"}
