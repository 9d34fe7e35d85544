"""Landmark files: the ``x y Class`` lines of the paper's manual annotations, CSV and ``.npy``.

A landmark file lists one landmark per line (or row) as its pixel position and class; the
class may be a landmark class name, a mask class the dictionary maps, or an index. The
reader returns :class:`~localization.common.landmarks.Landmarks` (no pixels: point landmarks).
"""

from __future__ import annotations

import csv
import logging
import math
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from localization.common.landmarks import LandmarkClasses, Landmarks
from osmseg.errors import ConfigError, DatasetError

__all__ = ["read_landmarks"]

logger = logging.getLogger(__name__)


def read_landmarks(path: str | Path, classes: LandmarkClasses | Sequence[str], width: int, height: int,
                   panorama: bool = False) -> Landmarks:
    """Read landmarks from a file: ``x y Class`` lines, CSV (header ``x,y,class``) or ``.npy``.

    Text: one landmark per line, ``x y Class`` or ``x,y,Class`` (the K x 3 format of the
    paper's manual annotations, published with both separators); ``#`` starts a comment,
    blank lines are skipped, the class is the rest of the line (so it may contain spaces).
    ``.csv``: columns ``x``, ``y``, ``class`` (any order, any case). ``.npy``: a numeric
    ``(K, 3)`` array whose last column is the class index. A class is a landmark class name
    (any case), a mask class the dictionary maps (``Tree`` -> vegetation), or an index into
    the landmark classes; mask classes the dictionary drops (``Sky``) are skipped. Errors
    name the file and line.
    """
    path = Path(path)
    names = classes.names if isinstance(classes, LandmarkClasses) else tuple(classes)
    if not (_is_int(width) and _is_int(height) and width > 0 and height > 0):
        raise ConfigError(f"{path}: image size must be positive integers, got {width}x{height}")
    resolve = _ClassResolver(classes, names)
    if path.suffix.lower() == ".npy":
        xy, cls = _read_npy(path, len(names))
        where = [f"row {i}" for i in range(len(xy))]
    else:
        rows = _read_csv(path) if path.suffix.lower() == ".csv" else _read_text(path)
        xy_list, cls_list, where = [], [], []
        for line, x, y, token in rows:
            index = resolve(token, f"{path}:{line}")
            if index is not None:
                xy_list.append((x, y))
                cls_list.append(index)
                where.append(f"line {line}")
        if len(xy_list) < len(rows):
            logger.debug("%s: skipped %d landmarks of classes the dictionary drops", path, len(rows) - len(xy_list))
        xy = np.array(xy_list, dtype=np.float64).reshape(-1, 2)
        cls = np.array(cls_list, dtype=np.int64)
    for (x, y), at in zip(xy, where):
        if not (math.isfinite(x) and math.isfinite(y)):
            raise DatasetError(f"{path} {at}: coordinates must be finite numbers, got {x} {y}")
        if not (0 <= x < width and 0 <= y < height):
            raise DatasetError(f"{path} {at}: ({x:g}, {y:g}) is outside the {width}x{height} image "
                               "(x in [0, width), y in [0, height)); check the image size or the file")
    return Landmarks(xy=xy, cls=cls, classes=names, width=width, height=height, panorama=panorama)


class _ClassResolver:
    """Turns a class token of a landmark file into a landmark class index (None: dropped class)."""

    def __init__(self, classes: LandmarkClasses | Sequence[str], names: tuple[str, ...]) -> None:
        self.names = names
        self.index = {n.lower(): i for i, n in enumerate(names)}
        self.dropped: set[str] = set()
        if isinstance(classes, LandmarkClasses):
            for source, target in classes.mapping.items():
                self.index.setdefault(source.lower(), names.index(target))
            known = classes.mask_ids()
            self.dropped = {n.lower() for n in (known or {}).values()} - set(self.index)

    def __call__(self, token: str, where: str) -> int | None:
        key = token.strip().lower()
        if key in self.index:
            return self.index[key]
        if key in self.dropped:
            return None
        if re.fullmatch(r"\d+", key) and int(key) < len(self.names):
            return int(key)
        raise DatasetError(f"{where}: unknown landmark class {token.strip()!r}; known: {', '.join(self.names)} "
                           f"(or an index 0..{len(self.names) - 1})")


def _open_text(path: Path) -> list[str]:
    try:
        return path.read_text(encoding="utf-8-sig").splitlines()  # -sig: a byte-order mark is not text
    except FileNotFoundError:
        raise DatasetError(f"{path}: landmark file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DatasetError(f"{path}: cannot read the landmark file ({exc}); give a text, .csv or .npy file") from None


def _number(text: str, where: str, what: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise DatasetError(f"{where}: {what} must be a number, got {text!r}") from None


#: Fields of a text landmark file: separated by spaces or by a comma (the authors publish both).
_FIELDS = re.compile(r"\s*,\s*|\s+")


def _read_text(path: Path) -> list[tuple[int, float, float, str]]:
    """``(line number, x, y, class token)`` of an ``x y Class`` (or ``x,y,Class``) file.

    The class is the rest of the line, so it may contain spaces (``dirt road``).
    """
    rows: list[tuple[int, float, float, str]] = []
    for number, line in enumerate(_open_text(path), start=1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = [part.strip() for part in _FIELDS.split(line, maxsplit=2)]
        if not rows and [p.lower() for p in parts[:2]] == ["x", "y"]:
            continue  # a header line
        if len(parts) < 3 or not parts[2]:
            raise DatasetError(f"{path}:{number}: expected 'x y Class' (or x,y,Class), got {line!r}")
        where = f"{path}:{number}"
        rows.append((number, _number(parts[0], where, "x"), _number(parts[1], where, "y"), parts[2]))
    return rows


def _read_csv(path: Path) -> list[tuple[int, float, float, str]]:
    """``(line number, x, y, class token)`` of a CSV file with columns x, y, class."""
    reader = csv.reader(_open_text(path))
    header = next(reader, None)
    columns = {h.strip().lower(): i for i, h in enumerate(header or [])}
    if not {"x", "y", "class"} <= set(columns):
        raise DatasetError(f"{path}:1: a landmark CSV needs a header with columns x, y, class; got {header}")
    rows = []
    for fields in reader:
        number = reader.line_num
        if not fields or not "".join(fields).strip():
            continue
        if len(fields) < len(header or []):
            raise DatasetError(f"{path}:{number}: expected {len(header or [])} fields, got {len(fields)}")
        where = f"{path}:{number}"
        rows.append((number, _number(fields[columns["x"]], where, "x"), _number(fields[columns["y"]], where, "y"),
                     fields[columns["class"]]))
    return rows


def _read_npy(path: Path, n_classes: int) -> tuple[np.ndarray, np.ndarray]:
    try:
        array = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise DatasetError(f"{path}: landmark file not found") from None
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: not a readable .npy array ({exc})") from None
    if array.ndim != 2 or array.shape[1] != 3 or not np.issubdtype(array.dtype, np.number):
        raise DatasetError(f"{path}: expected a numeric (K, 3) array of x, y, class index; got {array.dtype} "
                           f"{array.shape}")
    array = array.astype(np.float64)
    cls = array[:, 2]
    bad = np.flatnonzero((cls != np.round(cls)) | (cls < 0) | (cls >= n_classes))
    if len(bad):
        raise DatasetError(f"{path} row {bad[0]}: class index {cls[bad[0]]:g} is not an integer in 0..{n_classes - 1}")
    return array[:, :2], cls.astype(np.int64)


def _is_int(value: object) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)
