"""``localize-bench --renderer geometry``: views drawn by :mod:`localization.bench.georender` from
the OSM the aerial mask was made of, at the benchmark's viewpoints.

The benchmark places its viewpoints on the aerial mask (pixels); here each is taken to the
ground (the mask's Web Mercator bounds: a dataset's ``manifest.json`` ``bounds_3857``, or a
GeoTIFF mask's own georeference), the 3-D scene around the mask is built once from
``--osm`` with heights from the tags (:mod:`localization.bench.georender_osm`), and the view is
ray-cast there. What the methods get back is the same as from the mask renderer: a labelled
panorama in the aerial table plus ``sky``, and its landmarks. They are never told the heights
the scene was drawn with.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path

import mercantile
import numpy as np

from localization.bench.georender import Camera, render
from localization.bench.georender_osm import OsmScene, scene_from_osm
from localization.bench.render import (
    SKY_NAME,
    NoiseConfig,
    Panorama,
    RenderConfig,
    RenderedView,
    apply_noise,
    offset_viewpoint,
    panorama_table,
)
from localization.common.landmarks import LandmarkClasses, landmarks_from_mask
from osmseg.classes import ClassTable
from osmseg.errors import ConfigError
from osmseg.grid import pixel_lonlat

__all__ = ["Bounds", "geotiff_bounds_3857", "scene_for_mask", "geometry_view"]

Bounds = tuple[float, float, float, float]  # left, bottom, right, top in EPSG:3857 metres


def geotiff_bounds_3857(path: Path) -> Bounds | None:
    """A GeoTIFF mask's bounds when it is in Web Mercator (EPSG:3857), else None."""
    import rasterio

    with rasterio.open(path) as ds:
        if ds.crs is None or ds.crs.to_epsg() != 3857:
            return None
        b = ds.bounds
        return (b.left, b.bottom, b.right, b.top)


def scene_for_mask(osm: Sequence[Path | str], bounds: Bounds, table: ClassTable, reach_m: float,
                   seed: int) -> OsmScene:
    """The 3-D scene of the mask's area and ``reach_m`` around it (what a camera at its edge sees)."""
    left, bottom, right, top = bounds
    lon, lat = mercantile.lnglat((left + right) / 2, (bottom + top) / 2)
    half_diagonal = math.hypot(right - left, top - bottom) / 2 * math.cos(math.radians(lat))
    return scene_from_osm(osm, lon, lat, table, radius_m=half_diagonal + reach_m, seed=seed)


def geometry_view(scene: OsmScene, bounds: Bounds, shape: tuple[int, int], resolution_m: float,
                  table: ClassTable, viewpoint: tuple[float, float], classes: LandmarkClasses, *,
                  config: RenderConfig, noise: NoiseConfig, mode: str = "centroid", min_size: int = 50,
                  stride: int = 50) -> RenderedView:
    """The view from mask pixel ``viewpoint`` ray-cast over ``scene``, its noise applied and its
    landmarks extracted as the mask renderer's are (``truth`` stays ``viewpoint``)."""
    if config.vfov_deg is not None:
        raise ConfigError("the geometry renderer draws pixels square in angle: leave the vertical field of view out")
    camera_xy = (float(viewpoint[0]), float(viewpoint[1]))
    if noise.offset_m > 0:
        camera_xy = offset_viewpoint(camera_xy, noise.offset_m, resolution_m, np.random.default_rng([noise.seed, 0]),
                                     shape)
    x, y = scene.to_local(*pixel_lonlat(bounds, shape, camera_xy))
    pano_table = panorama_table(table)
    far = pano_table.by_name[SKY_NAME].id if config.far == SKY_NAME else pano_table.by_name[config.far].id
    camera = Camera(x, y, eye_m=config.camera_height_m, heading_deg=config.heading_deg, width=config.width,
                    height=config.height, max_range_m=config.max_range_m)
    labels = render(scene.scene, camera, pano_table.by_name[SKY_NAME].id, far)
    pano = Panorama(labels=labels, table=pano_table, camera=camera_xy, heading_deg=config.heading_deg,
                    resolution_m=resolution_m)
    if noise.active:
        pano = dataclasses.replace(pano, labels=apply_noise(pano.labels, pano.table, classes, noise))
    marks = landmarks_from_mask(pano.labels, pano.table, classes, mode=mode, min_size=min_size, stride=stride,
                                panorama=True)
    return RenderedView(panorama=pano, landmarks=marks, truth=(float(viewpoint[0]), float(viewpoint[1])))
