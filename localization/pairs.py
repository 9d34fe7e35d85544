"""Annotated ground/aerial pairs: the paper's own evaluation, on landmark files made by people.

Verde et al. (2020) evaluate on pairs of a 360° ground panorama and an aerial image centred on
where it was taken (CVUSA: 1232x224 panoramas, 750x750 aerial images), each annotated by hand
with ``x y Class`` landmarks (Building, Pavement, Road, Tree). The authors published such
pairs in that layout, which is what :func:`load_pairs` reads::

    DIR/aerial/NAME.txt    aerial landmarks, one ``x y Class`` per line (or .csv / .npy)
    DIR/ground/NAME.txt    the panorama's landmarks
    DIR/aerial/NAME.jpg    optional: the images, read only for their size
    DIR/ground/NAME.jpg       (else give the sizes in :class:`PairsConfig`)
    DIR/truth.csv          optional: ``name,x,y`` viewpoints in aerial pixels; default: the
                           aerial image's centre, as in CVUSA

:func:`run_pairs` localizes every panorama in its aerial image with every subset of classes and
writes the same ``results.json`` and pictures as the rendered-panorama benchmark
(:mod:`localization.bench`): errors in metres given the aerial resolution, else in pixels.
With the truth at the centre, "guess the image centre" scores 0: the baseline to beat is the
random guess.
"""

from __future__ import annotations

import csv
import logging
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from localization.bench import (RECALL_RADII_M, aerial_graphs, baselines, by_num_classes, chance_errors,
                                localize_subsets, subsets_of, summarize, write_results)
from localization.landmark_files import read_landmarks
from localization.landmarks import LandmarkClasses, Landmarks, load_landmark_classes
from localization.result import DEFAULT_P
from osmseg import __version__
from osmseg.errors import ConfigError, DatasetError

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


def _landmark_file(folder: Path, name: str) -> Path | None:
    return next((folder / f"{name}{s}" for s in LANDMARK_SUFFIXES if (folder / f"{name}{s}").is_file()), None)


def _size(folder: Path, name: str, given: tuple[int, int] | None, side: str) -> tuple[int, int]:
    """(width, height) of the image beside a landmark file (header only), else the given size."""
    for suffix in IMAGE_SUFFIXES:
        path = folder / f"{name}{suffix}"
        if path.is_file():
            from PIL import Image

            try:
                with Image.open(path) as im:
                    return im.size
            except OSError as exc:
                raise DatasetError(f"{path}: cannot read the image for its size ({exc}); remove it or "
                                   f"give --{side}-size") from None
    if given is None:
        raise DatasetError(f"{folder / name}: no image beside the landmark file to read its size from; "
                           f"give --{side}-size WIDTHxHEIGHT")
    return given


def _truths(folder: Path) -> dict[str, tuple[float, float]]:
    """``truth.csv`` (``name,x,y``) if present."""
    path = folder / "truth.csv"
    if not path.is_file():
        return {}
    out: dict[str, tuple[float, float]] = {}
    with path.open(newline="", encoding="utf-8") as fh:
        for line, row in enumerate(csv.DictReader(fh), start=2):
            try:
                x, y = float(row["x"]), float(row["y"])
                if not (math.isfinite(x) and math.isfinite(y)):
                    raise ValueError
                out[str(row["name"]).strip()] = (x, y)
            except (KeyError, TypeError, ValueError):
                raise DatasetError(f"{path}:{line}: write name,x,y with numbers (a header line first)") from None
    return out


def load_pairs(folder: Path, config: PairsConfig = PairsConfig()) -> list[Pair]:
    """Every ``NAME`` with a landmark file in both ``aerial/`` and ``ground/`` of ``folder``."""
    folder = Path(folder)
    if not is_pairs_folder(folder):
        raise DatasetError(f"{folder}: annotated pairs need aerial/ and ground/ folders of landmark files")
    classes = load_landmark_classes(config.landmarks)
    aerial_dir, ground_dir = folder / "aerial", folder / "ground"
    names = sorted({p.stem for p in aerial_dir.iterdir() if p.suffix.lower() in LANDMARK_SUFFIXES})
    lonely = [n for n in names if _landmark_file(ground_dir, n) is None]
    if lonely:
        logger.warning("%d aerial landmark files have no ground file and are skipped: %s", len(lonely),
                       ", ".join(lonely[:5]))
    names = [n for n in names if n not in lonely]
    if not names:
        raise DatasetError(f"{folder}: no NAME has a landmark file (.txt/.csv/.npy) in both aerial/ and ground/")
    truths = _truths(folder)
    pairs = []
    for name in names:
        aw, ah = _size(aerial_dir, name, config.aerial_size, "aerial")
        gw, gh = _size(ground_dir, name, config.ground_size, "ground")
        aerial = read_landmarks(_landmark_file(aerial_dir, name), classes, aw, ah)
        ground = read_landmarks(_landmark_file(ground_dir, name), classes, gw, gh, panorama=True)
        truth = truths.get(name, ((aw - 1) / 2, (ah - 1) / 2))
        pairs.append(Pair(name, aerial, ground, truth))
    return pairs


def run_pairs(pairs: Sequence[Pair], config: PairsConfig, out_dir: Path, *, progress: bool = False,
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
    for index, pair in enumerate(tqdm(pairs, desc="pairs", unit="pair", disable=not progress, file=sys.stderr,
                                      dynamic_ncols=True)):
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
        "timing": {"total_s": round(total, 3), "localize_mean_s": round(total / len(pairs), 4)},
        "viewpoints": records,
    }
    write_results(results, Path(out_dir), plots)
    return results
