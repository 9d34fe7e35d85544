"""Bilinear warping of a raster window onto a sample grid: exact coordinates, OpenCV's resampler.

Why not GDAL's warper for this step: on a 1280 x 1280 RGB sample, ``rasterio.warp.reproject``
(bilinear) costs about 80 ms of CPU, 40 % of all the work a sample needs, where OpenCV's
``cv2.remap`` does the same bilinear interpolation in about 11 ms. What GDAL adds around the
interpolation is kept, in the same terms:

* **Where each pixel comes from.** The grid pixel centres are projected exactly (PROJ, through
  pyproj) on a lattice and interpolated linearly in between, as GDAL's
  approximating transformer does; here the lattice is refined until the interpolation is
  within 0.02 source pixels of the exact projection halfway between its nodes (GDAL's default
  allows 0.125). OpenCV then places each sample to 1/32 of a source pixel.
* **Validity.** With an alpha band (the raster's own, or its nodata / mask as one) colour is
  interpolated premultiplied by alpha and divided by the interpolated alpha: an invalid source
  pixel adds nothing to its neighbours, as in GDAL's warper, and the output alpha says how much
  of each pixel's kernel was valid. Outside the window is alpha 0.
* **Downsampling** is the caller's: a plain bilinear kernel aliases when a grid pixel spans
  more than one source pixel, so the caller reads the window averaged to about the grid's
  resolution first (``out_shape`` with ``Resampling.average``).

Pure functions over numpy arrays; imports numpy, OpenCV and pyproj only.

>>> import numpy as np
>>> mapx = np.array([[0.5, 1.0]], np.float32); mapy = np.zeros((1, 2), np.float32)
>>> warp_bilinear(np.array([[[0, 100, 200]]], np.uint8), mapx, mapy, alpha=False)[..., 0].tolist()
[[50, 100]]
"""

from __future__ import annotations

import functools
import math
from typing import Any

import cv2
import numpy as np
from affine import Affine
from pyproj import CRS, Transformer

# lattice refinement: start with nodes every FIRST_STEP grid pixels, halve until the linear
# interpolation is within TOLERANCE source pixels of the exact projection, never below LAST_STEP
FIRST_STEP = 64
LAST_STEP = 2
TOLERANCE = 0.02


def _nodes(size: int, step: int) -> np.ndarray:
    """Lattice positions (pixel indices) every ``step`` pixels, the last pixel included.

    >>> _nodes(10, 4).tolist()
    [0, 4, 8, 9]
    """
    nodes = np.arange(0, size, step)
    return nodes if nodes[-1] == size - 1 else np.append(nodes, size - 1)


def _cells(nodes: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each of ``positions``, the lattice cell it lies in (index of its first node) and how
    far along it (0..1): linear interpolation between ``nodes``.

    >>> cell, t = _cells(np.array([0, 2, 3]), np.arange(4))
    >>> cell.tolist(), t.tolist()
    ([0, 0, 1, 1], [0.0, 0.5, 0.0, 1.0])
    """
    if len(nodes) == 1:
        return np.zeros(len(positions), np.intp), np.zeros(len(positions))
    cell = np.clip(np.searchsorted(nodes, positions, side="right") - 1, 0, len(nodes) - 2)
    return cell, (positions - nodes[cell]) / (nodes[cell + 1] - nodes[cell])


def _interpolate(values: np.ndarray, rows: tuple[np.ndarray, np.ndarray],
                 cols: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Lattice ``values`` interpolated bilinearly at the (cell, fraction) ``rows`` x ``cols``, as
    float32 (relative to their mean meanwhile, so float32 keeps 1e-4 pixel precision far from the
    origin). Gathers and multiplies only: no matrix product, so no BLAS threads."""
    centre = float(values.mean())
    lattice = (values - centre).astype(np.float32)
    (ry, ty), (cx, tx) = rows, cols
    lattice = _along(lattice, ry, ty[:, None], axis=0)
    full = _along(lattice, cx, tx, axis=1)
    full += np.float32(centre)
    return full


def _along(lattice: np.ndarray, cell: np.ndarray, t: np.ndarray, axis: int) -> np.ndarray:
    """``lattice`` interpolated linearly along ``axis`` at (cell, fraction) positions: C-ordered
    float32 (OpenCV copies a strided map, slowly)."""
    if lattice.shape[axis] == 1:
        return np.ascontiguousarray(np.repeat(lattice, len(cell), axis=axis))
    steps = np.diff(lattice, axis=axis)
    out = np.take(steps, cell, axis=axis)
    out *= t.astype(np.float32)
    out += np.take(lattice, cell, axis=axis)
    return out


@functools.lru_cache(maxsize=16)
def _transformer(dst_wkt: str, src_wkt: str) -> Transformer:
    """PROJ's transformation between two CRSs (x/y order), made once per process and pair."""
    return Transformer.from_crs(CRS.from_wkt(dst_wkt), CRS.from_wkt(src_wkt), always_xy=True)


def _exact(cols: np.ndarray, rows: np.ndarray, dst_crs: Any, dst_transform: Affine, src_crs: Any,
           src_transform: Affine) -> tuple[np.ndarray, np.ndarray]:
    """Source (col, row) of destination pixel centres ``(cols, rows)`` (same shape), in OpenCV's
    convention (pixel centres at integers); NaN or inf where the projection fails."""
    d, s = dst_transform, ~src_transform
    c, r = cols + 0.5, rows + 0.5
    x, y = d.a * c + d.b * r + d.c, d.d * c + d.e * r + d.f
    with np.errstate(invalid="ignore"):
        xs, ys = _transformer(_wkt(dst_crs), _wkt(src_crs)).transform(x, y, errcheck=False)
        xs, ys = np.asarray(xs, float), np.asarray(ys, float)
        u, v = s.a * xs + s.b * ys + s.c, s.d * xs + s.e * ys + s.f
    return u - 0.5, v - 0.5


def _mesh(cols: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every (col, row) pair as two 2-D arrays, rows along the first axis."""
    c, r = np.meshgrid(cols.astype(float), rows.astype(float))
    return c, r


def _wkt(crs: Any) -> str:
    """A CRS (rasterio's, an EPSG string) as WKT, the key of the transformer cache."""
    return crs.to_wkt() if hasattr(crs, "to_wkt") else CRS.from_user_input(crs).to_wkt()


def source_pixels(dst_crs: Any, dst_transform: Affine, shape: tuple[int, int], src_crs: Any,
                  src_transform: Affine) -> tuple[np.ndarray, np.ndarray]:
    """float32 maps ``(mapx, mapy)`` of ``shape`` (rows, cols): where each destination pixel's
    centre lies in the source raster, in source pixels with centres at integers (``cv2.remap``'s
    convention). Pixels the projection cannot place get -1e6 (outside: invalid)."""
    height, width = shape
    step = FIRST_STEP
    while True:
        ny, nx = _nodes(height, step), _nodes(width, step)
        u, v = _exact(*_mesh(nx, ny), dst_crs, dst_transform, src_crs, src_transform)
        if not (np.isfinite(u).all() and np.isfinite(v).all()):
            break  # projected pixel by pixel below
        if step > LAST_STEP:
            # fine enough when the interpolation meets the exact projection halfway between nodes,
            # along the cells' edges as well as at their centres: a conformal projection curves
            # one way along x and the other along y, which cancel at the centre
            hy = np.union1d(ny, (ny[:-1] + ny[1:]) // 2)
            hx = np.union1d(nx, (nx[:-1] + nx[1:]) // 2)
            eu, ev = _exact(*_mesh(hx, hy), dst_crs, dst_transform, src_crs, src_transform)
            at = (_cells(ny, hy), _cells(nx, hx))
            if not (np.isfinite(eu).all() and np.isfinite(ev).all()) or max(
                    np.abs(_interpolate(u, *at) - eu).max(), np.abs(_interpolate(v, *at) - ev).max()) > TOLERANCE:
                step //= 2
                continue
        every = (_cells(ny, np.arange(height)), _cells(nx, np.arange(width)))
        return _interpolate(u, *every), _interpolate(v, *every)
    u, v = _exact(*_mesh(np.arange(width), np.arange(height)), dst_crs, dst_transform, src_crs, src_transform)
    bad = ~(np.isfinite(u) & np.isfinite(v))
    u[bad], v[bad] = -1e6, -1e6
    return u.astype(np.float32), v.astype(np.float32)


def warp_bilinear(data: np.ndarray, mapx: np.ndarray, mapy: np.ndarray, *, alpha: bool) -> np.ndarray:
    """``data`` (bands, rows, cols; uint8) interpolated bilinearly at ``(mapx, mapy)``, as
    ``(H, W, bands)`` uint8. With ``alpha`` the last band is alpha: colour is interpolated
    premultiplied by it and divided by the interpolated alpha (invalid pixels do not bleed into
    valid ones), and the returned alpha is the interpolated one. Outside ``data`` is black, and
    alpha 0."""
    count = data.shape[0]
    if math.prod(data.shape[1:]) == 0:
        return np.zeros((*mapx.shape, count), np.uint8)
    if not alpha:
        # four interleaved channels take OpenCV's vectorised path (3 take twice as long)
        planes = list(data) + ([np.full(data.shape[1:], 255, np.uint8)] if count == 3 else [])
        out = _remap(cv2.merge(planes) if len(planes) > 1 else data[0], mapx, mapy)
        return out.reshape(*mapx.shape, len(planes))[..., :count]
    # colour x alpha and alpha x 255 both fit uint16 (255 x 255): premultiplied, exact to 1/65025
    weight = data[-1]
    planes = [cv2.multiply(band, weight, dtype=cv2.CV_16U) for band in data[:-1]]
    planes.append(cv2.multiply(weight, np.full_like(weight, 255), dtype=cv2.CV_16U))
    out = _remap(cv2.merge(planes), mapx, mapy).reshape(*mapx.shape, count)
    kept = out[..., -1]
    result = np.empty((*mapx.shape, count), np.uint8)
    for i in range(count - 1):  # colour = premultiplied / alpha; 0 where nothing was kept
        result[..., i] = cv2.divide(out[..., i], kept, scale=255.0, dtype=cv2.CV_8U)
    result[..., -1] = ((kept.astype(np.uint32) + 127) // 255).astype(np.uint8)
    return result


def _remap(image: np.ndarray, mapx: np.ndarray, mapy: np.ndarray) -> np.ndarray:
    """``cv2.remap`` bilinear, black (alpha 0) outside the image."""
    return cv2.remap(image, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
