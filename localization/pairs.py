"""Annotated ground/aerial pairs: the paper's own evaluation, on landmark files made by people.

Verde et al. (2020) evaluate on pairs of a 360° ground panorama and an aerial image centred on
where it was taken (CVUSA: 1232x224 panoramas, 750x750 aerial images), each annotated by hand
with ``x y Class`` landmarks (Building, Pavement, Road, Tree). The authors published such
pairs in that layout, which is what :func:`load_pairs` reads::

    DIR/aerial/NAME.txt    aerial landmarks, one ``x y Class`` or ``x,y,Class`` per line (or .csv / .npy)
    DIR/ground/NAME.txt    the panorama's landmarks
    DIR/aerial/NAME.jpg    optional: the images, read only for their size, unless the sizes
    DIR/ground/NAME.jpg       are given in :class:`PairsConfig` (``--aerial-size``, which wins)
    DIR/truth.csv          optional: ``name,x,y`` viewpoints in aerial pixels; default: the
                           aerial image's centre ``((W - 1) / 2, (H - 1) / 2)``, as in CVUSA
                           (the authors' code uses pixel 375 of 750, 1-based: half a pixel off)

:func:`run_pairs` localizes every panorama in its aerial image with every subset of classes and
writes the same ``results.json`` and pictures as the rendered-panorama benchmark
(:mod:`localization.evaluate`): errors in metres given the aerial resolution, else in pixels.
With the truth at the centre, "guess the image centre" scores 0: the baseline to beat is the
random guess.
"""

from __future__ import annotations

import csv
import logging
import math
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any


from localization.evaluate import (RECALL_RADII_M, aerial_graphs, baselines, by_num_classes, chance_errors,
                                localize_subsets, subsets_of, summarize, write_results)
from localization.landmark_files import read_landmarks
from localization.landmarks import LandmarkClasses, Landmarks, load_landmark_classes
from localization.result import DEFAULT_P
from osmseg import __version__
from osmseg.errors import ConfigError, DatasetError
from osmseg.progress import Progress, track

logger = logging.getLogger(__name__)

__all__ = ["Pair", "PairsConfig", "is_pairs_folder", "load_pairs", "run_pairs", "RECALL_RADII_PX"]

#: Recall radii when errors are in pixels (a CVUSA aerial image is 750 px wide).
RECALL_RADII_PX = (25, 50, 100)
LANDMARK_SUFFIXES = (".txt", ".csv", ".npy")
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")


@dataclass(frozen=True)
class Pair:
    """One panorama's landmarks, its aerial image's landmarks and the true viewpoint (aerial pixels)."""

    name: str
    aerial: Landmarks
    ground: Landmarks
    truth: tuple[float, float]


@dataclass(frozen=True)
class PairsConfig:
    """Settings of an annotated-pairs run (all recorded in results.json)."""

    landmarks: str = "camvid"        # dictionary resolving the files' class names (Building, Pavement...)
    window: int | None = None        # aerial window in pixels; None: mu + 5 sigma per image (the paper's)
    p: float = DEFAULT_P
    top_k: int = 5
    subsets: bool = True             # also every subset of 2.. classes (Figure 5.2)
    resolution_m: float | None = None  # aerial metres per pixel: errors in metres; None: in pixels
    aerial_size: tuple[int, int] | None = None  # (width, height) when no image lies beside the files
    ground_size: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        if not 0 < self.p <= 1:
            raise ConfigError(f"p must be in (0, 1], got {self.p}")
        if self.top_k < 1 or (self.window is not None and self.window < 1):
            raise ConfigError("top_k and window must be at least 1")
        if self.resolution_m is not None and not self.resolution_m > 0:
            raise ConfigError(f"resolution must be a positive number of metres per pixel, got {self.resolution_m}")


def is_pairs_folder(folder: Path) -> bool:
    """Whether ``folder`` has the ``aerial/`` + ``ground/`` layout of annotated pairs."""
    return (Path(folder) / "aerial").is_dir() and (Path(folder) / "ground").is_dir()


def _files(folder: Path, suffixes: tuple[str, ...]) -> dict[str, Path]:
    """``NAME -> path`` of the files in ``folder`` with one of ``suffixes`` (any case; first suffix wins)."""
    found: dict[str, Path] = {}
    for path in sorted(folder.iterdir(), key=lambda q: (suffixes.index(q.suffix.lower())
                                                        if q.suffix.lower() in suffixes else len(suffixes), q.name)):
        if path.is_file() and path.suffix.lower() in suffixes:
            found.setdefault(path.stem, path)
    return found


def _size(image: Path | None, given: tuple[int, int] | None, where: Path, side: str) -> tuple[int, int]:
    """(width, height): the given ``--SIDE-size``, else that of the image beside the file (header only)."""
    if given is not None:
        return given
    if image is None:
        raise DatasetError(f"{where}: no image beside the landmark file to read its size from; "
                           f"give --{side}-size WIDTHxHEIGHT")
    from PIL import Image

    try:
        with Image.open(image) as im:
            return im.size
    except OSError as exc:
        raise DatasetError(f"{image}: cannot read the image for its size ({exc}); remove it or "
                           f"give --{side}-size") from None


def _truths(folder: Path) -> dict[str, tuple[float, float]]:
    """``truth.csv`` (``name,x,y``; a byte-order mark and spaces around the names are fine) if present."""
    path = folder / "truth.csv"
    if not path.is_file():
        return {}
    out: dict[str, tuple[float, float]] = {}
    with path.open(newline="", encoding="utf-8-sig") as fh:
        reader = csv.DictReader(fh)
        reader.fieldnames = [f.strip().lower() for f in reader.fieldnames or []]
        for line, row in enumerate(reader, start=2):
            try:
                x, y = float(row["x"]), float(row["y"])
                if not (math.isfinite(x) and math.isfinite(y)):
                    raise ValueError
                out[str(row["name"]).strip()] = (x, y)
            except (KeyError, TypeError, ValueError, AttributeError):
                raise DatasetError(f"{path}:{line}: write name,x,y with numbers (a header line first)") from None
    return out


def load_pairs(folder: Path, config: PairsConfig = PairsConfig()) -> list[Pair]:
    """Every ``NAME`` with a landmark file in both ``aerial/`` and ``ground/`` of ``folder``."""
    folder = Path(folder)
    if not is_pairs_folder(folder):
        raise DatasetError(f"{folder}: annotated pairs need aerial/ and ground/ folders of landmark files")
    classes = load_landmark_classes(config.landmarks)
    aerial_dir, ground_dir = folder / "aerial", folder / "ground"
    aerial_files, ground_files = _files(aerial_dir, LANDMARK_SUFFIXES), _files(ground_dir, LANDMARK_SUFFIXES)
    aerial_images, ground_images = _files(aerial_dir, IMAGE_SUFFIXES), _files(ground_dir, IMAGE_SUFFIXES)
    names = sorted(set(aerial_files) & set(ground_files))
    lonely = sorted(set(aerial_files) ^ set(ground_files))
    if lonely:
        logger.warning("%d landmark files have no partner on the other side and are skipped: %s", len(lonely),
                       ", ".join(lonely[:5]))
    if not names:
        raise DatasetError(f"{folder}: no NAME has a landmark file (.txt/.csv/.npy) in both aerial/ and ground/")
    truths = _truths(folder)
    unknown = sorted(set(truths) - set(names))
    if unknown:
        logger.warning("truth.csv names %d pairs that do not exist (%s); check its name column", len(unknown),
                       ", ".join(unknown[:5]))
    if truths and len(unknown) < len(truths) and set(names) - set(truths):
        logger.warning("%d pairs have no line in truth.csv: their truth is the aerial image's centre",
                       len(set(names) - set(truths)))
    pairs = []
    for name in names:
        aw, ah = _size(aerial_images.get(name), config.aerial_size, aerial_files[name], "aerial")
        gw, gh = _size(ground_images.get(name), config.ground_size, ground_files[name], "ground")
        aerial = read_landmarks(aerial_files[name], classes, aw, ah)
        ground = read_landmarks(ground_files[name], classes, gw, gh, panorama=True)
        truth = truths.get(name, ((aw - 1) / 2, (ah - 1) / 2))
        if not (0 <= truth[0] < aw and 0 <= truth[1] < ah):
            raise DatasetError(f"{folder / 'truth.csv'}: the truth of {name} ({truth[0]:g}, {truth[1]:g}) is outside "
                               f"its {aw}x{ah} aerial image")
        pairs.append(Pair(name, aerial, ground, truth))
    return pairs


def _mean_time(records: Sequence[dict[str, Any]]) -> float:
    """Mean time of the full-class localization (graph building and matching) per pair, as in the bench."""
    return round(sum(r["localize_s"] for r in records) / max(len(records), 1), 4)


def run_pairs(pairs: Sequence[Pair], config: PairsConfig, out_dir: Path, *, progress: Progress | None = None,
              plots: bool = True, source: str = "") -> dict[str, Any]:
    """Localize every pair's panorama with every class subset; write results.json (+ plots)."""
    if not pairs:
        raise DatasetError("no annotated pairs to evaluate")
    classes: LandmarkClasses = load_landmark_classes(config.landmarks)
    subsets = subsets_of(classes, config.subsets)
    scale = config.resolution_m or 1.0
    radii = RECALL_RADII_M if config.resolution_m else RECALL_RADII_PX
    records: list[dict[str, Any]] = []
    t_start = time.perf_counter()
    for index, pair in enumerate(track(pairs, progress, "pairs", unit="pair")):
        graphs = aerial_graphs(pair.aerial, subsets, config.window)
        scored, seconds = localize_subsets(graphs, pair.ground, pair.truth, scale, config.p, config.top_k)
        centre, uniform = chance_errors((pair.aerial.height, pair.aerial.width), pair.truth, scale)
        ground = pair.ground
        records.append({
            "index": index, "name": pair.name, "truth": list(pair.truth),
            "aerial_landmarks": len(pair.aerial), "query_landmarks": len(ground), "window_px": graphs[subsets[0]].window,
            "classes_seen": sorted({ground.classes[c] for c in set(ground.cls.tolist())}),
            "centre_guess": round(centre, 4), "random_guess": round(uniform, 4), "localize_s": round(seconds, 4),
            **scored,
        })
    total = time.perf_counter() - t_start
    settings = asdict(config)
    results = {
        "format": "osmseg-localize-bench", "format_version": 2, "tool": f"osmseg {__version__}",
        "kind": "annotated pairs", "queries": "annotated pairs", "unit": "m" if config.resolution_m else "px",
        "settings": settings, "source": source,
        "landmark_classes": {"name": classes.name, "names": list(classes.names), "mapping": dict(classes.mapping)},
        "classes": list(subsets[0]),
        "summary": summarize(records, radii),
        "baselines": baselines(records),
        "by_num_classes": by_num_classes(subsets, records, radii),
        "timing": {"total_s": round(total, 3), "localize_mean_s": _mean_time(records)},
        "viewpoints": records,
    }
    write_results(results, Path(out_dir), plots)
    return results
