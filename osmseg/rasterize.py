"""Features to a class-index mask in a sample's pixel grid.

One :func:`rasterio.features.rasterize` call burns all features, sorted by their class's draw
order: GDAL burns shapes in the order given and, with ``MergeAlg.replace``, a later shape
overwrites an earlier one, so areas end up under lines and buildings on top.  A pixel is
burnt when its centre is inside a shape (``all_touched=False``), the usual convention for
label masks; 0 means no feature covers the pixel.

>>> import shapely
>>> from osmseg.grid import sample_grid
>>> from osmseg.osm.features import Feature, FeatureSet
>>> g = sample_grid(24.94, 60.17, zoom=18, size=1)
>>> left, bottom, right, top = g.xy_bounds
>>> whole = shapely.box(left, bottom, right, top)
>>> west_half = shapely.box(left, bottom, (left + right) / 2, top)
>>> fs = FeatureSet((Feature(1, 90, west_half, "w1", "area"), Feature(11, 20, whole, "w2", "area")), g.xy_bounds)
>>> labels = rasterize(fs, g)
>>> labels.shape, labels.dtype.name, int(labels[0, 0]), int(labels[0, 255])
((256, 256), 'uint8', 1, 11)
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any, cast

import numpy as np
import shapely
from rasterio.enums import MergeAlg
from rasterio.features import rasterize as _burn
from shapely.geometry.base import BaseGeometry

from osmseg.classes import ClassTable
from osmseg.errors import ClassTableError
from osmseg.grid import SampleGrid
from osmseg.osm.features import Feature


def rasterize(features: Iterable[Feature], grid: SampleGrid, table: ClassTable | None = None) -> np.ndarray:
    """``(H, W)`` uint8 class ids of ``features`` (from :func:`read_features`) on ``grid``.

    ``table`` is the class table the features were read with; when given, feature ids are
    checked against it (a mask of a mapped table is made with :func:`to_table` afterwards).
    """
    items = sorted(features, key=lambda f: f.order)  # stable: file order within a draw order
    if table is not None:
        unknown = {f.class_id for f in items} - set(table.by_id)
        if unknown:
            raise ClassTableError(f"features have class ids {sorted(unknown)} not in table {table.name!r}; "
                                  "rasterize with the table they were read with")
    shape = (grid.height, grid.width)
    if not items:
        return np.zeros(shape, dtype=np.uint8)
    burned: np.ndarray = _burn(zip(geojson_polygons([f.geometry for f in items]), (f.class_id for f in items)),
                               out_shape=shape, transform=grid.transform, fill=0, all_touched=False,
                               merge_alg=MergeAlg.replace, dtype="uint8")
    return burned


def geojson_polygons(geometries: Sequence[BaseGeometry]) -> list[dict[str, Any]]:
    """GeoJSON MultiPolygon mappings of (Multi)Polygons, their coordinates taken out in bulk.

    What rasterio's rasterizer reads; shapely's own ``__geo_interface__`` walks every vertex in
    Python, which took three quarters of the time of rasterising a city sample.

    >>> import shapely
    >>> geojson_polygons([shapely.box(0, 0, 1, 1)])[0]["coordinates"][0][0][:2]
    [[1.0, 0.0], [1.0, 1.0]]
    """
    parts, owner = shapely.get_parts(np.asarray(geometries, dtype=object), return_index=True)
    rings, part = shapely.get_rings(parts, return_index=True)
    coords, ring = shapely.get_coordinates(rings, return_index=True)
    points = coords.tolist()  # one conversion, then a slice per ring
    cuts = [0, *(np.flatnonzero(np.diff(ring)) + 1).tolist(), len(points)]
    polygons: list[list[list[list[float]]]] = [[] for _ in parts]
    for start, end, p in zip(cuts, cuts[1:], part.tolist()):
        polygons[p].append(points[start:end])
    shapes: list[list[list[list[list[float]]]]] = [[] for _ in geometries]
    for polygon, g in zip(polygons, owner.tolist()):
        shapes[g].append(polygon)
    return [{"type": "MultiPolygon", "coordinates": c} for c in shapes]


def to_table(labels: np.ndarray, source: ClassTable, target: ClassTable) -> np.ndarray:
    """Labels made with ``source`` (e.g. classes13) re-expressed in ``target`` (e.g. classes6).

    ``target`` must be ``source`` itself or a table mapped from it (its ``base``); base classes
    that ``target`` does not list become unlabeled (0).
    """
    if target is source or target.name == source.name:
        return cast("np.ndarray", labels.copy())
    if target.base is None or target.base.name != source.name:
        raise ClassTableError(f"class table {target.name!r} is not a mapping of {source.name!r}; "
                              "its 'base' must name the table the labels were made with")
    return cast("np.ndarray", target.lookup_from_base()[labels])
