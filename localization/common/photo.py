"""A photo as a user holds it: what its EXIF says of how and where it was taken.

A phone or camera JPEG carries, besides its pixels, the lens's focal length (and often its 35 mm
equivalent), the orientation the camera was held in, and with location on a GPS fix, its
accuracy and the compass direction the camera faced. :func:`photo_facts` reads them with Pillow
(``Image.getexif``: the Exif and GPS sub-IFDs) into a :class:`PhotoFacts`:

* **Field of view**: from ``FocalLengthIn35mmFilm``, by the diagonal (a 35 mm frame's diagonal,
  43.27 mm, over the photo's aspect: the CIPA definition of the equivalent), else from
  ``FocalLength`` and the sensor width ``FocalPlaneXResolution`` gives
  (``ExifImageWidth / FocalPlaneXResolution`` in its unit). Neither: None (the user gives ``--fov``).
* **Orientation**: ``Orientation`` 5-8 mean the camera was held on its side: the picture a person
  sees is the stored one turned, its width and height swapped (:func:`upright_pixels` turns it
  so, as ``ImageOps.exif_transpose`` does).
* **Heading**: ``GPSImgDirection`` (degrees) with ``GPSImgDirectionRef`` T (true north) or M
  (magnetic north: not corrected here for the declination, a few degrees in most places).
* **Position**: ``GPSLatitude``/``GPSLongitude`` with their N/S, E/W references, and
  ``GPSHPositioningError`` (metres) when the device wrote it.

A compass is a prior, not a fact: a phone's is often off by 10-30 degrees, so the search keeps
the heading free within ``--heading-within`` of it (:data:`COMPASS_WITHIN_DEG` by default).

Imports: PIL, numpy, osmseg core.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from osmseg.errors import ConfigError

__all__ = ["COMPASS_WITHIN_DEG", "PhotoFacts", "fov_from_35mm", "photo_facts", "upright_pixels"]

#: How far a photo's compass heading is taken to be off, by default (degrees either way).
COMPASS_WITHIN_DEG = 25.0
#: The diagonal of a 35 mm film frame (36 x 24 mm), which an "equivalent focal length" refers to.
FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)
#: EXIF tags (Exif sub-IFD 0x8769, GPS sub-IFD 0x8825)
EXIF_IFD, GPS_IFD = 0x8769, 0x8825
ORIENTATION, FOCAL_LENGTH, FOCAL_35MM = 0x0112, 0x920A, 0xA405
FOCAL_PLANE_XRES, FOCAL_PLANE_UNIT, EXIF_WIDTH = 0xA20E, 0xA210, 0xA002
GPS_LAT_REF, GPS_LAT, GPS_LON_REF, GPS_LON, GPS_DIR_REF, GPS_DIR, GPS_ERROR = 1, 2, 3, 4, 16, 17, 31
#: FocalPlaneResolutionUnit: 2 inch, 3 centimetre (EXIF 2.3); 4 and 5 (mm, um) as some cameras write
UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}


@dataclass(frozen=True)
class PhotoFacts:
    """What a photo's EXIF says; None where it says nothing. ``width``/``height``: the picture upright."""

    width: int
    height: int
    hfov_deg: float | None = None
    fov_from: str = ""                      # which tags gave the field of view, for the user
    heading_deg: float | None = None
    heading_ref: str = ""                   # "true north" or "magnetic north"
    lonlat: tuple[float, float] | None = None
    position_error_m: float | None = None

    def describe(self) -> str:
        """One line of what was read, as the command says it."""
        parts = [f"{self.width}x{self.height} px"]
        parts.append(f"field of view {self.hfov_deg:.1f}° ({self.fov_from})" if self.hfov_deg is not None
                     else "no focal length")
        parts.append(f"compass heading {self.heading_deg:.1f}° ({self.heading_ref})" if self.heading_deg is not None
                     else "no compass heading")
        if self.lonlat is not None:
            error = f" ±{self.position_error_m:g} m" if self.position_error_m is not None else ""
            parts.append(f"GPS {self.lonlat[0]:.6f},{self.lonlat[1]:.6f}{error}")
        else:
            parts.append("no GPS fix")
        return ", ".join(parts)


def fov_from_35mm(focal_35mm: float, width: int, height: int) -> float:
    """Horizontal field of view (degrees) of a ``width`` x ``height`` picture whose 35 mm equivalent
    focal length is ``focal_35mm``: the equivalent is taken on the diagonal.

    >>> round(fov_from_35mm(26, 4032, 3024), 1), round(fov_from_35mm(50, 6000, 4000), 1)
    (67.3, 39.6)
    """
    across = FRAME_DIAGONAL_MM * width / math.hypot(width, height)
    return math.degrees(2 * math.atan(across / (2 * focal_35mm)))


def _number(value: Any) -> float | None:
    """An EXIF rational (or number) as a float; None when absent, zero-denominated or not a number."""
    try:
        out = float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return out if math.isfinite(out) else None


def _degrees(dms: Any, ref: Any, negative: str) -> float | None:
    """GPS degrees, minutes, seconds and a hemisphere letter as signed degrees."""
    try:
        d, m, s = (_number(v) for v in dms)
    except (TypeError, ValueError):
        return None
    if d is None or m is None or s is None:
        return None
    value = abs(d) + m / 60.0 + s / 3600.0  # some writers sign the degrees as well as the reference
    return -value if str(ref).strip().upper() == negative or d < 0 else value


def _fov(exif: Any, stored: tuple[int, int], turned: bool) -> tuple[float | None, str]:
    """The upright picture's field of view and the tags it came from (see the module doc); ``stored``:
    the size as stored, ``turned``: whether the orientation swaps width and height."""
    sw, sh = stored
    width, height = (sh, sw) if turned else (sw, sh)
    sub = exif.get_ifd(EXIF_IFD)
    f35 = _number(sub.get(FOCAL_35MM))
    if f35 is not None and f35 > 0:
        return fov_from_35mm(f35, width, height), f"35 mm equivalent focal length {f35:g} mm"
    focal, xres = _number(sub.get(FOCAL_LENGTH)), _number(sub.get(FOCAL_PLANE_XRES))
    unit = UNIT_MM.get(int(sub.get(FOCAL_PLANE_UNIT, 2) or 2))
    if focal and focal > 0 and xres and xres > 0 and unit is not None:
        sensor_x = int(sub.get(EXIF_WIDTH) or sw) / xres * unit   # the stored picture's width on the sensor, mm
        across = sensor_x * sh / sw if turned else sensor_x
        return (math.degrees(2 * math.atan(across / (2 * focal))),
                f"focal length {focal:g} mm, {across:.2f} mm of sensor across")
    return None, ""


def photo_facts(path: Path | str) -> PhotoFacts:
    """Read what ``path``'s EXIF says (see the module doc); ConfigError when it is not an image."""
    try:
        with Image.open(path) as im:
            exif = im.getexif()
            stored = im.size
    except (OSError, ValueError) as exc:
        raise ConfigError(f"--photo {path}: cannot read it as an image ({exc}); give a JPEG, PNG or TIFF photo") from None
    turned = int(exif.get(ORIENTATION, 1) or 1) in (5, 6, 7, 8)  # held on its side: the picture a person sees is turned
    width, height = (stored[1], stored[0]) if turned else stored
    hfov, fov_from = _fov(exif, stored, turned)
    gps = exif.get_ifd(GPS_IFD)
    heading = _number(gps.get(GPS_DIR))
    ref = "magnetic north" if str(gps.get(GPS_DIR_REF, "T")).strip().upper() == "M" else "true north"
    lat, lon = _degrees(gps.get(GPS_LAT), gps.get(GPS_LAT_REF), "S"), _degrees(gps.get(GPS_LON), gps.get(GPS_LON_REF), "W")
    lonlat = (lon, lat) if lat is not None and lon is not None and abs(lat) <= 90 and abs(lon) <= 180 else None
    error = _number(gps.get(GPS_ERROR))
    return PhotoFacts(width, height, hfov, fov_from, None if heading is None else heading % 360.0,
                      ref if heading is not None else "", lonlat, error if lonlat is not None else None)


#: EXIF orientation -> the numpy turn that shows the stored pixels upright (as ``ImageOps.exif_transpose``)
_TURNS = {2: lambda a: a[:, ::-1], 3: lambda a: a[::-1, ::-1], 4: lambda a: a[::-1],
          5: lambda a: np.swapaxes(a, 0, 1), 6: lambda a: np.rot90(a, -1), 7: lambda a: np.swapaxes(a, 0, 1)[::-1, ::-1],
          8: lambda a: np.rot90(a, 1)}


def upright_pixels(pixels: np.ndarray, path: Path | str) -> np.ndarray:
    """``pixels`` read from ``path`` (rows, columns, ...) turned upright by the file's EXIF orientation
    (unchanged without one): what a segmentation of the photo must see.

    >>> a = np.arange(6).reshape(2, 3)
    >>> _TURNS[6](a).tolist(), _TURNS[8](a).tolist()
    ([[3, 0], [4, 1], [5, 2]], [[2, 5], [1, 4], [0, 3]])
    """
    try:
        with Image.open(path) as im:
            orientation = int(im.getexif().get(ORIENTATION, 1) or 1)
    except (OSError, ValueError):
        return pixels
    turn = _TURNS.get(orientation)
    return pixels if turn is None else np.ascontiguousarray(turn(pixels))
