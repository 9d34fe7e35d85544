"""Train/val/test splits by area: samples that overlap on the ground stay in one split.

:func:`make_splits` draws the splits from a seed, keeping the groups of overlapping samples
that :func:`sample_groups` finds (from a dataset's manifest, or its georeferenced images)
together, so that no pixel of a test image was seen in training; :func:`write_splits` and
:func:`read_splits` keep them in a run's ``splits.json``. Imports: osmseg core only.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
import rasterio.errors
from rasterio.warp import transform_bounds

from osmseg.errors import DatasetError
from osmseg.output.atomic import atomic_write_bytes
from osmseg.output.manifest import manifest_path, read_manifest
from osmseg.sampling import overlap_groups


def make_splits(names: Sequence[str], seed: int, test_fraction: float = 1 / 3,
                val_fraction: float = 0.15, groups: Mapping[str, int] | None = None) -> dict[str, list[str]]:
    """Split sample names into ``train``, ``val`` and ``test`` (each sorted), keeping groups together.

    ``groups`` (name -> group id; names not in it are alone) are samples that overlap on the
    ground (:func:`osmseg.sampling.overlap_groups`): a group always lands in one split, so no
    pixel of a test image was seen in training. ``round(n * test_fraction)`` images are the test
    target and ``round(m * val_fraction)`` of the remaining ``m`` the validation target
    (rounding half up; at least one each when there are enough images, ``n >= 3`` for a test
    image and ``m >= 2`` for a validation one; always at least one for training). Groups sorted
    by their first name are shuffled by a numpy Generator seeded with ``seed`` and dealt in that
    order: to test while it stays within its target, else to validation likewise, else to
    training; a split still empty then takes the smallest group of training (or of the other
    held-out split) that leaves its donor at least one image. With no groups this is exactly a split by image, and the result does
    not depend on the input order. Too few separate areas leave a split empty.

    >>> s = make_splits([f"s{i}" for i in range(12)], seed=0)
    >>> [len(s[k]) for k in ("train", "val", "test")]
    [7, 1, 4]
    >>> g = make_splits([f"s{i}" for i in range(12)], seed=0, groups={"s1": 0, "s2": 0, "s3": 0})
    >>> len({k for k in g for n in g[k] if n in ("s1", "s2", "s3")})
    1
    >>> big = make_splits([f"s{i:02d}" for i in range(12)], seed=0, groups={f"s{i:02d}": 0 for i in range(8)})
    >>> [len(big[k]) for k in ("train", "val", "test")]
    [8, 1, 3]
    """
    unique = sorted(set(names))
    if len(unique) != len(names):
        raise DatasetError("sample names must be unique to split by image")
    if not (0 <= test_fraction < 1 and 0 <= val_fraction < 1):
        raise DatasetError(f"split fractions must be in [0, 1), got test {test_fraction}, val {val_fraction}")
    n = len(unique)
    n_test = int(np.floor(n * test_fraction + 0.5))
    if test_fraction > 0 and n >= 3:
        n_test = max(n_test, 1)
    n_test = min(n_test, max(n - 1, 0))
    m = n - n_test
    n_val = int(np.floor(m * val_fraction + 0.5))
    if val_fraction > 0 and m >= 2:
        n_val = max(n_val, 1)
    n_val = min(n_val, max(m - 1, 0))
    members: dict[object, list[str]] = {}
    for name in unique:
        key = ("group", groups[name]) if groups and name in groups else ("alone", name)
        members.setdefault(key, []).append(name)
    units = sorted(members.values(), key=lambda u: u[0])
    order = np.random.default_rng(seed).permutation(len(units))
    out: dict[str, list[str]] = {"train": [], "val": [], "test": []}
    for i in order:  # a group goes where it fits without passing the target; the rest trains
        unit = units[i]
        if len(out["test"]) + len(unit) <= n_test:
            out["test"].extend(unit)
        elif len(out["val"]) + len(unit) <= n_val:
            out["val"].extend(unit)
        else:
            out["train"].extend(unit)
    # groups too large for a target can leave a split empty: it then takes the smallest group of
    # training, or of the other held-out split, whose donor keeps at least one image
    dealt = [units[i] for i in order]
    for split, wanted in (("test", n_test), ("val", n_val)):
        if not wanted or out[split]:
            continue
        other = "val" if split == "test" else "test"
        for donor in ("train", other):
            owned = sorted((u for u in dealt if u[0] in out[donor]), key=len)
            moved = next((u for u in owned if len(out[donor]) - len(u) >= 1), None)
            if moved is not None:
                out[split].extend(moved)
                out[donor] = [n for n in out[donor] if n not in moved]
                break
    return {k: sorted(v) for k, v in out.items()}


def sample_groups(root: Path, names: Iterable[str], images: Mapping[str, Path] | None = None) -> dict[str, int]:
    """Which of a dataset's samples overlap on the ground: name -> group id (every name listed).

    From ``manifest.json``'s ``bounds_3857`` (``osmseg build`` output), else from the extents of
    georeferenced ``images`` (name -> file; GeoTIFFs in any CRS, compared in EPSG:3857); samples
    whose footprint is unknown are alone.
    """
    names = sorted(set(names))
    boxes: dict[str, tuple[float, ...]] = {}
    if manifest_path(Path(root)).is_file():
        try:
            for s in read_manifest(Path(root))["samples"]:
                b = s.get("bounds_3857")
                if isinstance(b, list) and len(b) == 4 and all(isinstance(v, (int, float)) for v in b):
                    boxes[str(s["name"])] = tuple(float(v) for v in b)
        except DatasetError:
            boxes = {}  # footprints from the images below; validation reports the manifest
    for name in names:
        path = (images or {}).get(name)
        if name in boxes or path is None or Path(path).suffix.lower() not in (".tif", ".tiff"):
            continue
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # NotGeoreferencedWarning
                with rasterio.open(path) as ds:
                    if ds.crs is not None:
                        boxes[name] = tuple(transform_bounds(ds.crs, "EPSG:3857", *ds.bounds))
        except (rasterio.errors.RasterioError, ValueError):
            continue  # unreadable here: validation names the file; unknown footprint meanwhile
    known = [n for n in names if n in boxes]
    ids = overlap_groups([boxes[n] for n in known])
    groups = dict(zip(known, ids))
    base = len(set(ids))
    for i, name in enumerate(n for n in names if n not in groups):
        groups[name] = base + i
    return groups


def write_splits(path: Path, splits: dict[str, list[str]], seed: int, split_by: str = "image",
                 groups: Mapping[str, int] | None = None) -> Path:
    """Write the splits to ``path`` as JSON (atomically), with the seed and the rule that drew
    them and, for a split by overlap groups, the groups of more than one sample."""
    doc: dict[str, Any] = {"format": "osmseg-splits", "format_version": 1, "seed": seed, "split_by": split_by,
                           "counts": {k: len(v) for k, v in splits.items()}, "splits": splits}
    if groups:
        together: dict[int, list[str]] = {}
        for name, group in groups.items():
            together.setdefault(group, []).append(name)
        doc["overlap_groups"] = sorted(sorted(g) for g in together.values() if len(g) > 1)
    return atomic_write_bytes(Path(path), (json.dumps(doc, indent=2, sort_keys=True) + "\n").encode())


def read_splits(path: Path) -> dict[str, list[str]]:
    """The splits written by :func:`write_splits`; DatasetError if missing, corrupt or overlapping."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        splits = doc["splits"]
        result = {str(k): [str(n) for n in v] for k, v in splits.items() if isinstance(v, list)}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        raise DatasetError(f"{path}: not a readable splits file; delete it to draw the splits again") from None
    if len(result) != len(splits):
        raise DatasetError(f"{path}: every split must be a list of sample names")
    seen: dict[str, str] = {}
    for split, names in result.items():
        for name in names:
            if name in seen:
                raise DatasetError(f"{path}: {name!r} is in both {seen[name]} and {split}; splits must not overlap")
            seen[name] = split
    return result
