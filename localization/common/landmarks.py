"""Landmarks: the few labelled points (or regions) of one image that the localizer matches.

A landmark is a connected region of one *landmark class* (the paper's four: building, road,
vegetation, footway) in a segmentation mask, or a manually annotated ``x y Class`` line. Which
mask classes become which landmark class is a *class dictionary*
(``data_manifests/landmarks-*.toml``, :class:`LandmarkClasses`); mask classes it does not
mention are dropped.

:func:`landmarks_from_mask` finds the connected components (8-connectivity) of each landmark
class with :func:`scipy.ndimage.label`, drops those smaller than ``min_size`` pixels and turns
the rest into landmarks in one of three modes:

* ``"centroid"``: one landmark per component, at its centroid;
* ``"grid"``: one landmark per node of a global grid of spacing ``stride`` that the component
  covers (nodes at ``stride // 2 + i * stride`` in x and y, so a grid cell's node is its
  centre); a component covering no node still gets one landmark, at its centroid, so no
  component is lost;
* ``"component"``: the landmark is the whole component: :attr:`Landmarks.pixels` keeps its
  pixels (the graph puts it in every window holding any of them) and ``xy`` is its centroid.

A 360° panorama (``panorama=True``) is a cylinder: a component crossing the left/right edge
is one landmark (labels touching across ``x = 0`` / ``x = W - 1``, 8-connected, are merged),
and a component touching both edges gets the circular mean of its x as centroid x.

Coordinates are pixel coordinates: ``x`` is the column, ``y`` the row, both in
``[0, width) x [0, height)``. Landmark files (``x y Class`` lines, CSV, ``.npy``) are read by
:func:`localization.common.landmark_files.read_landmarks`.

>>> mask = np.zeros((8, 12), np.uint8); mask[1:4, 1:4] = 1; mask[5:7, 6:12] = 2
>>> lm = landmarks_from_mask(mask, {0: "sky", 1: "house", 2: "street"},
...                          LandmarkClasses(("building", "road"), {"house": "building", "street": "road"}),
...                          min_size=4)
>>> lm.xy.tolist(), [lm.classes[c] for c in lm.cls]
([[2.0, 2.0], [8.5, 5.5]], ['building', 'road'])
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from osmseg.classes import ClassDef, ClassTable, load_class_table
from osmseg.datafiles import DATA_DIR, load_toml
from osmseg.errors import ClassTableError, ConfigError

__all__ = ["MODES", "PAPER_CLASSES", "SKY_COLOR", "SKY_NAME", "LandmarkClasses", "Landmarks", "landmarks_from_mask",
           "circular_x", "landmark_colours", "landmark_dictionary_path", "load_landmark_classes", "panorama_table"]

#: The landmark classes of Verde et al. (2020), in the order the dictionaries list them.
PAPER_CLASSES = ("building", "road", "vegetation", "footway")
MODES = ("centroid", "grid", "component")
_EIGHT = np.ones((3, 3), dtype=bool)


@dataclass(frozen=True, eq=False)  # arrays: compare fields, not objects
class Landmarks:
    """K landmarks of one image: positions, classes and (optionally) the pixels they cover.

    ``cls`` indexes ``classes``; two images are compared class by class, so they must share
    the same ``classes`` tuple. ``pixels`` (component landmarks only) holds, per landmark, an
    ``(N_i, 2)`` integer array of ``(x, y)`` pixels. ``panorama`` marks a 360° image whose x
    wraps around at ``width``. Arrays are checked and converted (float64 ``xy``, int64 ``cls``)
    on construction; a bad one raises :class:`~osmseg.errors.ConfigError`.
    """

    xy: np.ndarray
    cls: np.ndarray
    classes: tuple[str, ...]
    width: int
    height: int
    pixels: tuple[np.ndarray, ...] | None = None
    panorama: bool = False

    def __post_init__(self) -> None:
        if not (_is_int(self.width) and _is_int(self.height) and self.width > 0 and self.height > 0):
            raise ConfigError(f"landmarks: image size must be positive integers, got {self.width}x{self.height}")
        xy = np.asarray(self.xy, dtype=np.float64)
        if xy.size == 0:
            xy = xy.reshape(0, 2)
        if xy.ndim != 2 or xy.shape[1] != 2:
            raise ConfigError(f"landmarks: xy must have shape (K, 2), got {xy.shape}")
        cls = np.asarray(self.cls)
        if cls.size == 0:
            cls = cls.reshape(0).astype(np.int64)
        if cls.shape != (len(xy),) or not np.issubdtype(cls.dtype, np.integer):
            raise ConfigError(f"landmarks: cls must be {len(xy)} integers, got {cls.dtype} of shape {cls.shape}")
        cls = cls.astype(np.int64)
        classes = tuple(self.classes)
        if len(cls) and (cls.min() < 0 or cls.max() >= len(classes)):
            raise ConfigError(f"landmarks: class indices must be in 0..{len(classes) - 1} (classes {classes})")
        if not np.isfinite(xy).all():
            raise ConfigError("landmarks: coordinates must be finite numbers")
        outside = (xy[:, 0] < 0) | (xy[:, 0] >= self.width) | (xy[:, 1] < 0) | (xy[:, 1] >= self.height)
        if outside.any():
            k = int(np.flatnonzero(outside)[0])
            raise ConfigError(f"landmarks: landmark {k} at {tuple(xy[k])} is outside the "
                              f"{self.width}x{self.height} image (x in [0, width), y in [0, height))")
        object.__setattr__(self, "xy", xy)
        object.__setattr__(self, "cls", cls)
        object.__setattr__(self, "classes", classes)
        if self.pixels is not None:
            object.__setattr__(self, "pixels", self._checked_pixels(self.pixels, len(xy)))

    def _checked_pixels(self, pixels: Sequence[np.ndarray], k: int) -> tuple[np.ndarray, ...]:
        if len(pixels) != k:
            raise ConfigError(f"landmarks: pixels must hold one array per landmark ({k}), got {len(pixels)}")
        out = []
        for i, p in enumerate(pixels):
            p = np.asarray(p)
            if p.ndim != 2 or p.shape[1] != 2 or len(p) == 0 or not np.issubdtype(p.dtype, np.integer):
                raise ConfigError(f"landmarks: pixels[{i}] must be a non-empty (N, 2) integer array, got {p.shape}")
            if p[:, 0].min() < 0 or p[:, 0].max() >= self.width or p[:, 1].min() < 0 or p[:, 1].max() >= self.height:
                raise ConfigError(f"landmarks: pixels[{i}] has pixels outside the {self.width}x{self.height} image")
            out.append(p)
        return tuple(out)

    def __len__(self) -> int:
        return len(self.xy)

    def select(self, keep: np.ndarray | Sequence[int]) -> Landmarks:
        """The landmarks picked by ``keep`` (a boolean mask or indices), same classes tuple.

        >>> lm = Landmarks(np.array([[1.0, 1], [2, 2], [3, 3]]), np.array([0, 1, 0]), ("a", "b"), 9, 9)
        >>> lm.select(lm.cls == 0).xy[:, 0].tolist()
        [1.0, 3.0]
        """
        idx = np.arange(len(self))[np.asarray(keep)] if len(self) else np.zeros(0, dtype=np.int64)
        pixels = tuple(self.pixels[i] for i in idx) if self.pixels is not None else None
        return dataclasses.replace(self, xy=self.xy[idx], cls=self.cls[idx], pixels=pixels)

    def of_classes(self, names: Sequence[str]) -> Landmarks:
        """Only the landmarks of classes ``names``; ``classes`` (and so the indices) unchanged."""
        unknown = [n for n in names if n not in self.classes]
        if unknown:
            raise ConfigError(f"landmarks: unknown classes {unknown}; known: {', '.join(self.classes)}")
        wanted = [self.classes.index(n) for n in names]
        return self.select(np.isin(self.cls, wanted))


@dataclass(frozen=True)
class LandmarkClasses:
    """A class dictionary: landmark class ``names`` and ``mapping`` mask class name -> landmark class.

    Mask classes absent from ``mapping`` are dropped. ``other_ground`` lists mask classes that
    are known flat ground of no landmark class (grass, parking...): the ``profile`` method
    (:mod:`localization.profile.profiles`) matches them as one more class, "other", on both sides; they
    never become landmarks. ``mask_table`` (a class table in
    ``data_manifests/``) or ``mask_classes`` (names by label value 0, 1, ...) say which mask
    labels the names refer to, so a mask can be read without passing its table; with both,
    ``mask_classes`` name the labels and ``mask_table`` (the same names and ids) gives their
    colours (:func:`landmark_colours`).
    """

    names: tuple[str, ...]
    mapping: dict[str, str]
    name: str = ""
    mask_table: str | None = None
    mask_classes: tuple[str, ...] | None = None
    description: str = field(default="", compare=False)
    other_ground: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        names = tuple(self.names)
        where = f"landmark dictionary {self.name or '(unnamed)'}"
        if not names or len(set(names)) != len(names) or not all(isinstance(n, str) and n for n in names):
            raise ClassTableError(f"{where}: names must be distinct non-empty strings, got {names!r}")
        bad = {k: v for k, v in self.mapping.items() if v not in names}
        if bad:
            raise ClassTableError(f"{where}: mapping targets {sorted(set(bad.values()))} are not landmark classes "
                                  f"{list(names)}")
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "mapping", dict(self.mapping))
        object.__setattr__(self, "other_ground", tuple(self.other_ground))
        clash = sorted(set(self.other_ground) & set(self.mapping))
        if clash:
            raise ClassTableError(f"{where}: classes {clash} are both mapped to landmarks and listed as other_ground")
        if self.mask_classes is not None:
            object.__setattr__(self, "mask_classes", tuple(self.mask_classes))

    def mask_ids(self) -> dict[int, str] | None:
        """Mask label value -> mask class name, from ``mask_classes`` or ``mask_table`` (None if neither)."""
        if self.mask_classes is not None:
            return dict(enumerate(self.mask_classes))
        if self.mask_table is not None:
            return _table_ids(load_class_table(self.mask_table))
        return None


def landmark_colours(classes: LandmarkClasses, table: ClassTable | None = None) -> dict[str, tuple[int, int, int]]:
    """Each landmark class's colour in pictures: the colour ``table`` (default: the dictionary's own
    ``mask_table``) gives the first mask class the dictionary maps to it, in the dictionary's order.
    A landmark is then drawn in the colour of the mask under it and of the class in every legend;
    landmark classes no coloured mask class maps to are left out.

    >>> landmark_colours(load_landmark_classes("aerial13"))
    {'building': (255, 255, 0), 'road': (50, 50, 255), 'vegetation': (69, 237, 114), 'footway': (128, 181, 255)}
    >>> landmark_colours(load_landmark_classes("camvid"))["footway"]   # CamVid's Pavement
    (60, 40, 222)
    """
    if table is None:
        if classes.mask_table is None:
            return {}
        table = load_class_table(classes.mask_table)
    by_name = {c.name: c.color for c in (table.unlabeled, *table.classes)}
    out: dict[str, tuple[int, int, int]] = {}
    for mask_class, landmark in classes.mapping.items():
        if landmark not in out and mask_class in by_name:
            r, g, b = by_name[mask_class][:3]
            out[landmark] = (int(r), int(g), int(b))
    return out


def load_landmark_classes(name_or_path: str) -> LandmarkClasses:
    """Read a class dictionary by short name, full name or path (see :func:`landmark_dictionary_path`).

    >>> d = load_landmark_classes("camvid")
    >>> d.names, d.mapping["Pavement"], "Sky" in d.mapping
    (('building', 'road', 'vegetation', 'footway'), 'footway', False)
    """
    path = landmark_dictionary_path(name_or_path)
    raw = load_toml(str(path))
    try:
        names = tuple(raw["landmark_classes"])
        mapping = raw.get("mapping", {})
        if not isinstance(mapping, dict) or not all(isinstance(v, str) for v in mapping.values()):
            raise TypeError("mapping must be a table of mask class = landmark class")
        mask_classes = raw.get("mask_classes")
        return LandmarkClasses(names=names, mapping=mapping, name=str(raw.get("name", path.stem)),
                               mask_table=raw.get("mask_table"),
                               mask_classes=tuple(mask_classes) if mask_classes is not None else None,
                               description=str(raw.get("description", "")),
                               other_ground=tuple(raw.get("other_ground", ())))
    except (KeyError, TypeError) as exc:
        raise ClassTableError(f"{path}: malformed landmark dictionary ({exc}); "
                              "see data_manifests/landmarks-aerial13.toml") from None


def landmark_dictionary_path(name_or_path: str) -> Path:
    """The file of a class dictionary: an existing path, else ``data_manifests/landmarks-SHORT.toml``.

    ``"aerial13"``, ``"aerial13.toml"``, ``"landmarks-aerial13"`` and ``"landmarks-aerial13.toml"``
    all name ``data_manifests/landmarks-aerial13.toml``.

    >>> [landmark_dictionary_path(n).name for n in ("aerial13", "landmarks-aerial13", "landmarks-aerial13.toml")]
    ['landmarks-aerial13.toml', 'landmarks-aerial13.toml', 'landmarks-aerial13.toml']
    """
    given = str(name_or_path)
    if Path(given).is_file():
        return Path(given)
    short = given.removesuffix(".toml").removeprefix("landmarks-")
    candidate = DATA_DIR / f"landmarks-{short}.toml"
    if "/" not in given and "\\" not in given and short and candidate.is_file():
        return candidate
    known = sorted(p.stem.removeprefix("landmarks-") for p in DATA_DIR.glob("landmarks-*.toml"))
    raise ConfigError(f"landmark dictionary {given!r} not found: give one of {', '.join(known)} "
                      f"(data_manifests/landmarks-NAME.toml) or a path to a .toml file")


# ------------------------------------------------------------------------------------- from a mask


def landmarks_from_mask(mask: np.ndarray, mask_table: ClassTable | Mapping[int, str] | None,
                        classes: LandmarkClasses, *, mode: str = "centroid", stride: int = 50,
                        min_size: int = 50, panorama: bool = False) -> Landmarks:
    """The landmarks of a label ``mask`` (H, W) whose values are class ids of ``mask_table``.

    ``mask_table`` is a :class:`~osmseg.classes.ClassTable`, a mapping label value -> class
    name, or None to use the dictionary's own (``mask_table``/``mask_classes``). Components
    (8-connected) smaller than ``min_size`` pixels are dropped; ``mode`` and ``stride`` are
    described in the module docstring. Landmarks come ordered by class, then by the raster
    position of their component's first pixel. A mask with no landmark gives ``len(...) == 0``.
    """
    if mode not in MODES:
        raise ConfigError(f"landmark mode must be one of {', '.join(MODES)}, got {mode!r}")
    if not (_is_int(stride) and stride >= 1):
        raise ConfigError(f"grid stride must be a positive integer (e.g. 20, 50, 100), got {stride!r}")
    if not (_is_int(min_size) and min_size >= 0):
        raise ConfigError(f"min_size must be a non-negative integer (pixels), got {min_size!r}")
    mask = np.asarray(mask)
    if mask.ndim != 2 or mask.size == 0 or not np.issubdtype(mask.dtype, np.integer):
        raise ConfigError(f"a label mask must be a non-empty 2-D integer array, got {mask.dtype} {mask.shape}")
    lut = _landmark_lut(mask, mask_table, classes)
    height, width = mask.shape
    xy: list[np.ndarray] = []
    cls: list[np.ndarray] = []
    pixels: list[np.ndarray] = []
    landmark_of = (lut.astype(np.int8) if len(classes.names) < 127 else lut)[mask]  # 1 byte a pixel
    for c in range(len(classes.names)):
        labels, n = ndimage.label(landmark_of == c, structure=_EIGHT)
        if n == 0:
            del labels  # not two int32 label images at once
            continue
        if panorama:
            labels, n = _merge_across_seam(labels, n)
        kept, comp_xy = _centroids(labels, n, min_size, panorama)
        if mode == "grid":
            comp_xy = _grid_points(labels, kept, comp_xy, stride)
        if mode == "component":
            pixels.extend(_pixels(labels, n, kept))
        xy.append(comp_xy)
        cls.append(np.full(len(comp_xy), c, dtype=np.int64))
        del labels
    return Landmarks(xy=np.concatenate(xy) if xy else np.zeros((0, 2)),
                     cls=np.concatenate(cls) if cls else np.zeros(0, dtype=np.int64),
                     classes=classes.names, width=width, height=height,
                     pixels=tuple(pixels) if mode == "component" else None, panorama=panorama)


def _table_ids(table: ClassTable) -> dict[int, str]:
    return {c.id: c.name for c in (table.unlabeled, *table.classes)}


def _mask_names(mask_table: ClassTable | Mapping[int, str] | None,
                classes: LandmarkClasses) -> tuple[dict[int, str], str]:
    """Mask label value -> class name, from the table given or the dictionary's own, and what to call it."""
    if isinstance(mask_table, ClassTable):
        return _table_ids(mask_table), mask_table.name
    if mask_table is not None:
        return {int(k): str(v) for k, v in mask_table.items()}, "the given mask classes"
    found = classes.mask_ids()
    if found is None:
        raise ConfigError(f"landmark dictionary {classes.name!r} names no mask table: pass the mask's class table")
    return found, classes.mask_table or f"{classes.name} mask_classes"


def _landmark_lut(mask: np.ndarray, mask_table: ClassTable | Mapping[int, str] | None,
                  classes: LandmarkClasses) -> np.ndarray:
    """Lookup table mask label value -> landmark class index (-1: dropped), checking both sides."""
    ids, table_name = _mask_names(mask_table, classes)
    known = set(ids.values())
    unknown = sorted(k for k in classes.mapping if k not in known)
    if unknown:
        raise ConfigError(f"landmark dictionary {classes.name!r} maps classes {unknown} that {table_name} does not "
                          "have: use the dictionary made for this class table")
    present = _values_present(mask)
    stray = [int(v) for v in present if int(v) not in ids]
    if stray:
        raise ConfigError(f"the mask has label values {stray[:10]} that {table_name} does not define: pass the class "
                          "table the mask was made with")
    lut = np.full(int(max(max(ids), present.max())) + 1, -1, dtype=np.int64)
    for value, name in ids.items():
        target = classes.mapping.get(name)
        if target is not None:
            lut[value] = classes.names.index(target)
    return lut


def _values_present(mask: np.ndarray, rows: int = 512) -> np.ndarray:
    """The distinct values of an integer ``mask``, sorted: ``np.unique`` without its sorted copy of
    the whole mask (eight bytes a pixel for a large aerial mask), counted ``rows`` rows at a time.

    >>> _values_present(np.array([[3, 1], [1, 0]], dtype=np.uint8)).tolist()
    [0, 1, 3]
    """
    if mask.dtype.kind != "u" or mask.dtype.itemsize > 2:
        return np.unique(mask)
    counts = np.zeros(1 << (8 * mask.dtype.itemsize), dtype=np.int64)
    for top in range(0, mask.shape[0], rows):
        counts += np.bincount(mask[top:top + rows].ravel(), minlength=len(counts))
    return np.flatnonzero(counts).astype(mask.dtype)


def _merge_across_seam(labels: np.ndarray, n: int) -> tuple[np.ndarray, int]:
    """Merge labels that touch across the panorama's left/right edge (8-connectivity)."""
    left, right = labels[:, 0], labels[:, -1]
    pairs = [(left, right), (left[1:], right[:-1]), (left[:-1], right[1:])]
    a = np.concatenate([p[0] for p in pairs])
    b = np.concatenate([p[1] for p in pairs])
    both = (a > 0) & (b > 0)
    if not both.any():
        return labels, n
    graph = coo_matrix((np.ones(both.sum()), (a[both], b[both])), shape=(n + 1, n + 1))
    _, group = connected_components(graph, directed=False)
    first = np.full(group.max() + 1, n + 1)
    np.minimum.at(first, group, np.arange(n + 1))  # lowest old label of each group
    keep_order = np.unique(first[group[1:]])  # groups ordered by their lowest (first in raster) label
    new = np.zeros(n + 1, dtype=labels.dtype)
    new[1:] = np.searchsorted(keep_order, first[group[1:]]) + 1
    return new[labels], len(keep_order)


#: Rows of an aerial mask's component labels summed at once by :func:`_centroids`.
CENTROID_ROWS = 256


def _centroids(labels: np.ndarray, n: int, min_size: int, panorama: bool) -> tuple[np.ndarray, np.ndarray]:
    """Labels of the components of at least ``min_size`` pixels, and their ``(x, y)`` centroids."""
    width = labels.shape[1]
    if not panorama:  # an aerial mask: its sums row block by row block (the same sums: integers, exact)
        sizes, sum_x, sum_y = np.zeros(n + 1, dtype=np.int64), np.zeros(n + 1), np.zeros(n + 1)
        for top in range(0, labels.shape[0], CENTROID_ROWS):
            flat = labels[top:top + CENTROID_ROWS].ravel()
            rows = len(flat) // width
            sizes += np.bincount(flat, minlength=n + 1)
            sum_x += np.bincount(flat, weights=np.tile(np.arange(width, dtype=np.float64), rows), minlength=n + 1)
            sum_y += np.bincount(flat, weights=np.repeat(np.arange(top, top + rows, dtype=np.float64), width),
                                 minlength=n + 1)
        kept = np.flatnonzero(sizes[1:] >= max(min_size, 1)) + 1
        return kept, np.stack([sum_x[kept] / sizes[kept], sum_y[kept] / sizes[kept]], axis=1)
    flat = labels.ravel()
    where = np.flatnonzero(flat)
    lab = flat[where]
    ys, xs = np.divmod(where, width)
    sizes = np.bincount(lab, minlength=n + 1)
    kept = np.flatnonzero(sizes[1:] >= max(min_size, 1)) + 1
    cx = np.bincount(lab, weights=xs, minlength=n + 1)[kept] / sizes[kept]
    cy = np.bincount(lab, weights=ys, minlength=n + 1)[kept] / sizes[kept]
    # a panorama: components touching both edges get the circular mean of x, from their column histograms
    wraps = np.isin(kept, np.intersect1d(labels[:, 0], labels[:, -1]))
    if wraps.any():
        row = np.full(n + 1, -1)
        row[kept[wraps]] = np.arange(wraps.sum())
        r = row[lab]
        hist = np.bincount(r[r >= 0] * width + xs[r >= 0], minlength=int(wraps.sum()) * width)
        angle = 2 * np.pi * np.arange(width) / width
        hist = hist.reshape(-1, width).astype(np.float64)
        cx[wraps] = circular_x(hist @ np.sin(angle), hist @ np.cos(angle), width)
    return kept, np.stack([cx, cy], axis=1)


def circular_x(sin: np.ndarray, cos: np.ndarray, period: int) -> np.ndarray:
    """x in ``[0, period)`` of the mean direction of summed unit vectors ``(cos, sin)``.

    >>> a = 2 * np.pi * np.array([98, 99, 0, 1]) / 100
    >>> circular_x(np.sin(a).sum(keepdims=True), np.cos(a).sum(keepdims=True), 100).round(6).tolist()
    [99.5]
    """
    x = (np.arctan2(sin, cos) / (2 * np.pi) * period) % period
    return np.where(x < period, x, 0.0)  # rounding can give exactly `period`


def _pixels(labels: np.ndarray, n: int, kept: np.ndarray) -> list[np.ndarray]:
    """``(N, 2)`` int32 ``(x, y)`` pixels of each kept label, in raster order."""
    if len(kept) == 0:  # np.split would return one empty array
        return []
    flat = labels.ravel()
    where = np.flatnonzero(np.isin(flat, kept))
    lab = flat[where]
    order = np.argsort(lab, kind="stable")
    where, lab = where[order], lab[order]
    ys, xs = np.divmod(where, labels.shape[1])
    xy = np.stack([xs, ys], axis=1).astype(np.int32)
    return np.split(xy, np.cumsum(np.bincount(lab, minlength=n + 1)[kept])[:-1])


def _grid_points(labels: np.ndarray, kept: np.ndarray, centroids: np.ndarray, stride: int) -> np.ndarray:
    """Grid-node landmarks of each kept component (in component order), its centroid if it covers none."""
    off = stride // 2
    nodes = labels[off::stride, off::stride]
    gy, gx = np.nonzero(np.isin(nodes, kept))  # raster order
    node_label = nodes[gy, gx]
    node_xy = np.stack([gx * stride + off, gy * stride + off], axis=1).astype(np.float64)
    bare = ~np.isin(kept, node_label)  # components covering no node
    xy = np.concatenate([node_xy, centroids[bare]])
    owner = np.searchsorted(kept, np.concatenate([node_label, kept[bare]]))
    return xy[np.argsort(owner, kind="stable")]


def _is_int(value: object) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


#: The class a ground view shows above everything (:func:`panorama_table`), and its colour.
SKY_NAME = "sky"
SKY_COLOR = (135, 206, 250)


def panorama_table(table: ClassTable | Mapping[str, object] | str) -> ClassTable:
    """The aerial class table plus ``sky`` (next free id), unless it already has a sky class: what a
    view from the ground shows (the renderers draw it; ``osmseg localize`` reads a ground mask so).

    >>> t = panorama_table("classes13.toml")
    >>> t.by_name["sky"].id, t.by_name["building"].id, t.name
    (14, 1, 'osm13+sky')
    """
    base = table if isinstance(table, ClassTable) else (
        load_class_table(table) if isinstance(table, str) else ClassTable.from_dict(table))
    if SKY_NAME in base.by_name:
        return base
    sky_id = max(c.id for c in (base.unlabeled, *base.classes)) + 1
    if sky_id > 255:
        raise ConfigError("class table has no free id for the sky class (ids must stay <= 255)")
    sky = ClassDef(id=sky_id, name=SKY_NAME, color=SKY_COLOR)
    return dataclasses.replace(base, name=f"{base.name}+{SKY_NAME}", classes=(*base.classes, sky))
