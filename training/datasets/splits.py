"""Train/val/test splits by area: samples that overlap on the ground stay in one split.

:func:`make_splits` draws the splits from a seed, keeping the groups of overlapping samples
that :func:`sample_groups` finds (from a dataset's manifest, or its georeferenced images)
together, so that no pixel of a test image was seen in training; :func:`choose_splits` draws
a few seeded candidates and keeps the one whose validation class mix is closest to training's
(:func:`check_split` says how close, and :func:`split_warning` when it is not close enough);
:func:`write_splits` and :func:`read_splits` keep them in a run's ``splits.json``. Imports:
osmseg core only.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
import rasterio.errors
from rasterio.warp import transform_bounds

from osmseg.errors import DatasetError
from osmseg.output.atomic import atomic_write_bytes
from osmseg.output.manifest import manifest_path, read_manifest
from osmseg.overlap import overlap_groups


def make_splits(names: Sequence[str], seed: int, test_fraction: float = 1 / 3,
                val_fraction: float = 0.15, groups: Mapping[str, int] | None = None) -> dict[str, list[str]]:
    """Split sample names into ``train``, ``val`` and ``test`` (each sorted), keeping groups together.

    ``groups`` (name -> group id; names not in it are alone) are samples that overlap on the
    ground (:func:`osmseg.overlap.overlap_groups`): a group always lands in one split, so no
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


#: Candidate draws :func:`choose_splits` compares (draw 0 is :func:`make_splits` with the seed itself).
CANDIDATES = 16
#: A class holding at least this share of training's scored pixels should be in validation.
MEANINGFUL_SHARE = 0.02
#: Total-variation distance between validation's and training's class mix reported as "far".
FAR_DISTANCE = 0.25


def class_pixels(histograms: np.ndarray, names: Sequence[str], num_classes: int,
                 label_lut: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Pixels per model class of each sample: name -> ``(num_classes,)`` int64.

    ``histograms`` are the per-sample counts of the dataset's label ids (one row per name, as
    :func:`training.datasets.patches.validate` returns them); ``label_lut`` maps those ids to the model's
    (AirSegNet6 on a 13-class dataset) before counting.

    >>> class_pixels(np.array([[5, 1, 2]]), ["a"], 2, label_lut=np.array([0, 1, 1]))
    {'a': array([5, 3])}
    """
    hist = np.asarray(histograms, dtype=np.int64).reshape(len(names), -1)
    if label_lut is not None:
        mapped = np.zeros((hist.shape[0], num_classes), dtype=np.int64)
        np.add.at(mapped.T, np.asarray(label_lut)[:hist.shape[1]], hist.T)
        hist = mapped
    return {name: hist[i, :num_classes].copy() for i, name in enumerate(names)}


def class_shares(pixels: Mapping[str, np.ndarray], names: Iterable[str], ignore_index: int | None) -> np.ndarray:
    """Each class's share of the scored pixels of samples ``names`` (``ignore_index``'s pixels
    count nowhere); all zeros when they have none.

    >>> px = {"a": np.array([6, 1, 3]), "b": np.array([0, 0, 4])}
    >>> class_shares(px, ["a", "b"], ignore_index=0).tolist()
    [0.0, 0.125, 0.875]
    """
    total = np.zeros(len(next(iter(pixels.values()))) if pixels else 0, dtype=np.float64)
    for name in names:
        total += pixels[name]
    if ignore_index is not None and total.size:
        total[ignore_index] = 0
    return total / total.sum() if total.sum() else total


def total_variation(p: np.ndarray, q: np.ndarray) -> float:
    """Half the L1 distance of two class mixes: the share of pixels that would have to change
    class for one mix to become the other (0 = the same mix, 1 = no class in common).

    >>> total_variation(np.array([0.5, 0.5, 0.0]), np.array([0.2, 0.4, 0.4]))
    0.4
    """
    return round(float(np.abs(np.asarray(p) - np.asarray(q)).sum() / 2), 12)


@dataclass(frozen=True)
class SplitCheck:
    """How well a split's validation images represent the training classes.

    ``shares``: split -> class -> share of its scored pixels. ``distance``: total variation
    between validation's mix and training's. ``missing``: classes holding at least
    :data:`MEANINGFUL_SHARE` of training's pixels that validation lacks (they cannot be scored,
    so the choice of ``best.pt`` ignores them). ``over``: the class whose validation share
    exceeds its training share the most, with both shares (None when none does).
    """

    shares: dict[str, dict[str, float]]
    distance: float
    missing: tuple[str, ...]
    over: tuple[str, float, float] | None
    test_distance: float = 0.0  # the same distance for the test images (0 without any)

    @property
    def representative(self) -> bool:
        return not self.missing and self.distance < FAR_DISTANCE

    def key(self) -> tuple[int, float]:
        """Order of preference: fewer missing classes, then a closer mix of the farther of the
        two held-out sets (validation picks ``best.pt``, test reports the result: a test set
        unlike training measures the gap between the two, not the model)."""
        return len(self.missing), max(self.distance, self.test_distance)


def check_split(splits: Mapping[str, Sequence[str]], pixels: Mapping[str, np.ndarray], class_names: Sequence[str],
                ignore_index: int | None) -> SplitCheck:
    """Compare validation's class mix with training's (:class:`SplitCheck`).

    Why total variation: the mIoU that picks ``best.pt`` averages over the classes validation
    holds, each weighted by its pixels there; a validation set is fair when its class mix is
    training's. Total variation is the largest difference in share that any set of classes can
    have between the two mixes, in pixels' own units, bounded by 1 and defined when a class is
    absent from either side (unlike a KL divergence). :data:`FAR_DISTANCE` = 0.25 flags a
    quarter of validation's pixels in the "wrong" classes, e.g. a class 30 % of validation but
    under 5 % of training; a few images always differ by some tenths of that. A class that
    holds :data:`MEANINGFUL_SHARE` (2 %) of training but no validation pixel is flagged apart,
    as its absence moves the distance little but removes it from validation's mIoU.
    """
    shares = {split: class_shares(pixels, names, ignore_index) for split, names in splits.items()}
    train, val = shares.get("train"), shares.get("val")
    scored = [i for i in range(len(class_names)) if i != ignore_index]
    named = {split: {class_names[i]: round(float(v[i]), 6) for i in scored} for split, v in shares.items()}
    if train is None or val is None or not train.sum() or not val.sum():
        missing = tuple(class_names[i] for i in scored if train is not None and train[i] >= MEANINGFUL_SHARE)
        return SplitCheck(named, 1.0 if train is not None and train.sum() else 0.0, missing, None)
    missing = tuple(class_names[i] for i in scored if train[i] >= MEANINGFUL_SHARE and val[i] == 0)
    excess = val - train
    top = int(np.argmax(excess))
    over = (class_names[top], float(val[top]), float(train[top])) if excess[top] > 0 else None
    test = shares.get("test")
    test_distance = total_variation(test, train) if test is not None and test.sum() else 0.0
    return SplitCheck(named, total_variation(val, train), missing, over, test_distance)


def draw_seed(seed: int, draw: int) -> int:
    """The seed of candidate ``draw`` (0: ``seed`` itself; others from numpy's SeedSequence).

    >>> draw_seed(7, 0), draw_seed(7, 1) == draw_seed(7, 1), draw_seed(7, 1) != draw_seed(8, 1)
    (7, True, True)
    """
    return seed if draw == 0 else int(np.random.SeedSequence([seed, draw]).generate_state(1)[0])


def choose_splits(names: Sequence[str], seed: int, test_fraction: float = 1 / 3, val_fraction: float = 0.15,
                  groups: Mapping[str, int] | None = None, pixels: Mapping[str, np.ndarray] | None = None,
                  class_names: Sequence[str] = (), ignore_index: int | None = None,
                  candidates: int = CANDIDATES) -> tuple[dict[str, list[str]], dict[str, Any]]:
    """The splits of :func:`make_splits` for ``seed``, or a better one when its validation
    cannot represent training; and a record of the choice.

    The seed's own draw (draw 0) is kept when its validation represents training
    (:attr:`SplitCheck.representative`), so a seed gives the split it always gave. Otherwise
    ``candidates`` draws (draw ``k`` seeded by :func:`draw_seed`, so the same seed always makes
    the same choice; groups stay intact in each) are compared by :meth:`SplitCheck.key`: fewest
    meaningful training classes missing from validation, then the smallest total-variation
    distance between the class mixes of training and the farther of validation and test; ties
    keep the earlier draw. Draws leaving training or
    validation empty are passed over (all of them: draw 0 is returned, for the caller to
    refuse). Without ``pixels`` this is draw 0. The second value records the choice for
    ``splits.json``: ``candidates`` (draws compared; 1 when the first was kept), ``draw``,
    ``draw_seed``, ``val_train_distance``, ``first_draw_distance``, ``missing_in_val``,
    ``class_shares``.
    """
    first = make_splits(names, seed, test_fraction, val_fraction, groups=groups)
    if not pixels:
        return first, {}
    best: tuple[tuple[int, float], int, dict[str, list[str]], SplitCheck] | None = None
    first_check = check_split(first, pixels, class_names, ignore_index)
    if first["train"] and first["val"] and first_check.representative:
        candidates = 1  # nothing to improve on
    for k in range(max(1, candidates)):
        splits = first if k == 0 else make_splits(names, draw_seed(seed, k), test_fraction, val_fraction, groups)
        if not splits["train"] or not splits["val"]:
            continue
        check = first_check if k == 0 else check_split(splits, pixels, class_names, ignore_index)
        if best is None or check.key() < best[0]:
            best = (check.key(), k, splits, check)
    if best is None:
        return first, {}
    _, k, splits, check = best
    info = {"candidates": max(1, candidates), "draw": k, "draw_seed": draw_seed(seed, k),
            "val_train_distance": check.distance, "test_train_distance": check.test_distance,
            "first_draw_distance": first_check.distance,
            "missing_in_val": list(check.missing), "class_shares": check.shares,
            "rule": "the seed's own draw when its validation represents training, else of the seeded draws the "
                    "one whose held-out class mixes are closest to training's (fewest training classes missing "
                    "from validation, then the larger total variation of validation's and test's)"}
    return splits, info


def split_warning(splits: Mapping[str, Sequence[str]], info: Mapping[str, Any], ignore_index: int | None,
                  class_names: Sequence[str], pixels: Mapping[str, np.ndarray]) -> str | None:
    """One line saying why validation cannot represent the training classes, None when it can."""
    check = check_split(splits, pixels, class_names, ignore_index)
    if check.representative:
        return None
    parts = []
    if check.missing:
        shares = check.shares["train"]
        parts.append("it lacks " + ", ".join(f"{c!r} ({shares[c]:.0%} of training)" for c in check.missing))
    if check.distance >= FAR_DISTANCE:
        detail = (f"; {check.over[0]!r} is {check.over[1]:.0%} of validation, {check.over[2]:.0%} of training"
                  if check.over else "")
        parts.append(f"its class mix is {check.distance:.2f} from training's (total variation{detail})")
    tried = info.get("candidates", 1)
    return (f"validation ({len(splits['val'])} image{'s' if len(splits['val']) != 1 else ''}) does not represent "
            f"the training classes: {'; '.join(parts)} — the closest of {tried} seeded draw{'s' if tried != 1 else ''}; "
            "val mIoU and best.pt rest on it: add samples, or raise val_fraction in a --config file")


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
            for s in read_manifest(Path(root)).samples:
                if (box := s.bounds()) is not None:
                    boxes[s.name] = tuple(float(v) for v in box)
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
                 groups: Mapping[str, int] | None = None, selection: Mapping[str, Any] | None = None) -> Path:
    """Write the splits to ``path`` as JSON (atomically), with the seed and the rule that drew
    them, for a split by overlap groups the groups of more than one sample, and the
    ``selection`` of :func:`choose_splits` (which draw, and each split's class shares)."""
    doc: dict[str, Any] = {"format": "osmseg-splits", "format_version": 1, "seed": seed, "split_by": split_by,
                           "counts": {k: len(v) for k, v in splits.items()}, "splits": splits}
    if selection:
        doc["selection"] = {k: v for k, v in selection.items() if k != "class_shares"}
        doc["class_shares"] = selection.get("class_shares", {})
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
