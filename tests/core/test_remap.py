"""osmseg.imagery.remap against independent references: PROJ pixel by pixel for the coordinates,
a numpy bilinear interpolation for the resampling."""

from __future__ import annotations

import numpy as np
import pytest
from affine import Affine
from pyproj import Transformer

from osmseg.grid import sample_grid
from osmseg.imagery.remap import TOLERANCE, source_pixels, warp_bilinear


def exact_positions(grid, src_crs: str, src_transform: Affine) -> tuple[np.ndarray, np.ndarray]:
    """Every grid pixel centre projected by pyproj, as source (col, row) with centres at integers."""
    cols, rows = np.meshgrid(np.arange(grid.width) + 0.5, np.arange(grid.height) + 0.5)
    x, y = grid.transform * (cols, rows)
    xs, ys = Transformer.from_crs("EPSG:3857", src_crs, always_xy=True).transform(x, y)
    with np.errstate(invalid="ignore"):  # inf where PROJ cannot project
        u, v = ~src_transform * (xs, ys)
    return np.asarray(u) - 0.5, np.asarray(v) - 0.5


@pytest.mark.parametrize(("crs", "lon", "lat", "zoom", "size"), [
    ("EPSG:3067", 24.94, 60.17, 18, 1),   # Finnish TM, rotated 1.8 degrees against Web Mercator
    ("EPSG:3067", 24.94, 60.17, 12, 1),   # 12 km across: the projections' curvature shows
    ("EPSG:2056", 8.54, 47.37, 14, 3),    # Swiss LV95 (oblique Mercator), 7 km across
    ("EPSG:4326", -97.74, 30.27, 16, 3),  # lon/lat degrees
])
def test_source_pixels_follow_proj_everywhere(crs, lon, lat, zoom, size):
    grid = sample_grid(lon, lat, zoom, size=size)
    x0, y0 = Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lon, lat)
    res = 1e-6 if crs == "EPSG:4326" else 0.5
    src_transform = Affine(res, 0, x0 - 1000 * res, 0, -res, y0 + 1000 * res)
    mapx, mapy = source_pixels("EPSG:3857", grid.transform, (grid.height, grid.width), crs, src_transform)
    assert mapx.dtype == np.float32 and mapx.shape == (grid.height, grid.width) and mapx.flags.c_contiguous
    u, v = exact_positions(grid, crs, src_transform)
    # cells are refined until their centres are within TOLERANCE; nowhere much worse in between
    assert max(np.abs(mapx - u).max(), np.abs(mapy - v).max()) < 2 * TOLERANCE
    assert np.abs(mapx - u).mean() < TOLERANCE / 2


@pytest.mark.parametrize(("lon_0", "visible"), [(-155.0, 0.0), (24.94 - 90, 0.5)])
def test_source_pixels_that_cannot_be_projected_are_outside(lon_0, visible):
    """An orthographic view of the far side of the Earth (PROJ gives inf), and one whose horizon
    runs through the sample: what cannot be projected is placed outside, the rest where PROJ says."""
    grid = sample_grid(24.94, 60.17, 16)
    crs = f"+proj=ortho +lat_0=0 +lon_0={lon_0} +ellps=WGS84"
    x0, y0 = Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(24.94 - 0.002, 60.17)
    src_transform = Affine(1.0, 0, x0 if np.isfinite(x0) else 0.0, 0, -1.0, y0 if np.isfinite(y0) else 0.0)
    mapx, mapy = source_pixels("EPSG:3857", grid.transform, (grid.height, grid.width), crs, src_transform)
    u, v = exact_positions(grid, crs, src_transform)
    seen = np.isfinite(u) & np.isfinite(v)
    assert abs(seen.mean() - visible) < 0.1
    assert (mapx[~seen] == -1e6).all() and (mapy[~seen] == -1e6).all()
    assert np.abs(mapx[seen] - u[seen]).max(initial=0) < 0.01
    out = warp_bilinear(np.full((4, 10, 10), 200, np.uint8), mapx, mapy, alpha=True)
    assert not out[~seen].any()


def numpy_bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Plain bilinear interpolation of (bands, rows, cols) at (x, y), centres at integers."""
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    img = image.astype(float)
    return (img[:, y0, x0] * (1 - fx) * (1 - fy) + img[:, y0, x0 + 1] * fx * (1 - fy)
            + img[:, y0 + 1, x0] * (1 - fx) * fy + img[:, y0 + 1, x0 + 1] * fx * fy)


def test_warp_bilinear_is_bilinear_interpolation():
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (3, 60, 70), dtype=np.uint8)
    y, x = np.mgrid[0:40, 0:50].astype(np.float32)
    mapx, mapy = (x * 1.1 + 0.3 * y + 2.37).astype(np.float32), (y * 0.9 - 0.2 * x + 12.81).astype(np.float32)
    got = warp_bilinear(image, mapx, mapy, alpha=False)
    want = numpy_bilinear(image, mapx.astype(float), mapy.astype(float)).transpose(1, 2, 0)
    # OpenCV places samples to 1/32 pixel: on noise (up to 255 per pixel) that is up to 4 levels
    assert got.shape == (40, 50, 3) and np.abs(got - want).max() <= 4.5 and np.abs(got - want).mean() < 1.0


def test_warp_bilinear_alpha_keeps_invalid_pixels_out():
    """The left half is nodata (alpha 0, colour 0): valid output is exactly the valid colour,
    never darkened by the invalid neighbours, and alpha falls off over the edge's one pixel."""
    image = np.zeros((4, 20, 20), np.uint8)
    image[0, :, 10:], image[1, :, 10:], image[2, :, 10:] = 90, 140, 60
    image[3, :, 10:] = 255
    y, x = np.mgrid[2:18, 0:20].astype(np.float32)
    got = warp_bilinear(image, x + 0.25, y, alpha=True)
    alpha = got[..., 3]
    assert (alpha[:, :9] == 0).all() and (alpha[:, 10:19] == 255).all()
    assert alpha[0, 9] == round(0.25 * 255)  # a quarter of its kernel is valid
    kept = alpha > 0
    assert (got[..., :3][kept] == (90, 140, 60)).all()
    assert (got[..., :3][~kept] == 0).all()
