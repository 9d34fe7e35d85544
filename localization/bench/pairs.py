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
(:mod:`localization.bench.rendered`): errors in metres given the aerial resolution, else in pixels.
With the truth at the centre, "guess the image centre" scores 0: the baseline to beat is the
random guess. ``methods`` adds the profile method side by side (it needs ``resolution_m``;
heading known, or searched with ``heading="unknown"``), and ``conventions="authors"`` runs the
paper method as the authors' MATLAB demo does (truth then ``(W/2, H/2)``, their ``[375 375]``).
"""

from __future__ import annotations

import csv
import logging
import math
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, cast

from localization.bench.compare import (
    RIGHT_WRONG,
    aerial_graphs,
    confidence_of,
    localize_subsets,
    method_summary,
    subsets_of,
)
from localization.bench.plots import write_results
from localization.bench.scores import (
    RECALL_RADII_M,
    BenchResults,
    baselines,
    by_num_classes,
    chance_errors,
    error_fields,
    heading_error,
    summarize,
)
from localization.common.landmark_files import read_landmarks
from localization.common.landmarks import LandmarkClasses, Landmarks, load_landmark_classes
from localization.common.result import DEFAULT_P
from localization.common.views import Camera, check_view_shape
from localization.paper.config import PaperConfig
from localization.paper.match import aerial_graph
from localization.pipeline import METHODS, LocalizeConfig, run
from localization.profile.method import profile_index, run_profile
from localization.profile.search import ProfileConfig
from osmseg import __version__
from osmseg.errors import ConfigError, DatasetError
from osmseg.runtime.progress import Progress, track
from osmseg.units import plural

logger = logging.getLogger(__name__)

__all__ = ["Pair", "PairsConfig", "is_pairs_folder", "load_pairs", "run_pairs", "RECALL_RADII_PX"]

#: Recall radii when errors are in pixels (a CVUSA aerial image is 750 px wide).
RECALL_RADII_PX = (25, 50, 100)
LANDMARK_SUFFIXES = (".txt", ".csv", ".npy")
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")


@dataclass(frozen=True)
class Pair:
    """One panorama's landmarks, its aerial image's landmarks and the true viewpoint (aerial pixels):
    ``truth_given`` False when it is the aerial image's centre by default (no line in truth.csv)."""

    name: str
    aerial: Landmarks
    ground: Landmarks
    truth: tuple[float, float]
    truth_given: bool = True


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
    methods: tuple[str, ...] = ("paper",)   # side by side; the first fills the summary
    heading: str = "known"           # "known": north-aligned (CVUSA); "unknown": the profile method searches it
    profile: ProfileConfig = ProfileConfig(min_confidence=-1.0, min_kappa=-1.0)  # always answer: the error is what is measured
    camera_height_m: float = 2.0
    conventions: str = "osmseg"      # the paper method's: osmseg, or the authors' MATLAB demo (truth (W/2, H/2))

    def __post_init__(self) -> None:
        if not self.methods or any(m not in METHODS for m in self.methods) or len(set(self.methods)) != len(self.methods):
            raise ConfigError(f"methods must be distinct names among {', '.join(METHODS)}, got {list(self.methods)}")
        if self.heading not in ("known", "unknown"):
            raise ConfigError(f"heading must be 'known' or 'unknown', got {self.heading!r}")
        if "profile" in self.methods and self.resolution_m is None:
            raise ConfigError("the profile method measures ground distances in metres: give the aerial resolution "
                              "with --aerial-resolution (CVUSA's 750 px aerial images are about 0.2-0.3 m/px), or "
                              "--methods paper")
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
            return cast("tuple[int, int]", im.size)
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
        logger.warning("%s no partner on the other side and %s skipped: %s",
                       plural(len(lonely), "landmark file") + (" has" if len(lonely) == 1 else " have"),
                       "is" if len(lonely) == 1 else "are", ", ".join(lonely[:5]))
    if not names:
        raise DatasetError(f"{folder}: no NAME has a landmark file (.txt/.csv/.npy) in both aerial/ and ground/")
    truths = _truths(folder)
    unknown = sorted(set(truths) - set(names))
    if unknown:
        logger.warning("truth.csv names %s that %s not exist (%s); check its name column",
                       plural(len(unknown), "pair"), "does" if len(unknown) == 1 else "do", ", ".join(unknown[:5]))
    if truths and len(unknown) < len(truths) and set(names) - set(truths):
        untold = len(set(names) - set(truths))
        logger.warning("%s no line in truth.csv: %s the aerial image's centre", plural(untold, "pair") +
                       (" has" if untold == 1 else " have"), "its truth is" if untold == 1 else "their truth is")
    pairs = []
    for name in names:
        aw, ah = _size(aerial_images.get(name), config.aerial_size, aerial_files[name], "aerial")
        gw, gh = _size(ground_images.get(name), config.ground_size, ground_files[name], "ground")
        check_view_shape(gw, gh, 360.0, f"the panorama of {ground_files[name]}",
                         "give the panoramas' size (--ground-size WIDTHxHEIGHT, CVUSA's is 1232x224)"
                         if config.ground_size else "put the panorama's own image beside it, or give --ground-size")
        aerial = read_landmarks(aerial_files[name], classes, aw, ah)
        ground = read_landmarks(ground_files[name], classes, gw, gh, panorama=True)
        centre = (aw / 2, ah / 2) if config.conventions == "authors" else ((aw - 1) / 2, (ah - 1) / 2)
        truth = truths.get(name, centre)  # the authors' demo: [375 375] of 750, in the files' own numbers
        if not (0 <= truth[0] < aw and 0 <= truth[1] < ah):
            raise DatasetError(f"{folder / 'truth.csv'}: the truth of {name} ({truth[0]:g}, {truth[1]:g}) is outside "
                               f"its {aw}x{ah} aerial image")
        pairs.append(Pair(name, aerial, ground, truth, truth_given=name in truths))
    return pairs


def _mean_time(records: Sequence[dict[str, Any]]) -> float:
    """Mean time of the full-class localization (graph building and matching) per pair, as in the bench."""
    return float(round(sum(r["localize_s"] for r in records) / max(len(records), 1), 4))


def run_pairs(pairs: Sequence[Pair], config: PairsConfig, out_dir: Path, *, progress: Progress | None = None,
              plots: bool = True, source: str = "") -> BenchResults:
    """Localize every pair's panorama with every class subset; write results.json (+ plots)."""
    if not pairs:
        raise DatasetError("no annotated pairs to evaluate")
    classes: LandmarkClasses = load_landmark_classes(config.landmarks)
    paper_first = config.methods[0] == "paper"
    subsets = subsets_of(classes, config.subsets and paper_first)  # class subsets are the paper method's
    scale = config.resolution_m or 1.0
    radii = RECALL_RADII_M if config.resolution_m else RECALL_RADII_PX
    records: list[dict[str, Any]] = []
    t_start = time.perf_counter()
    for index, pair in enumerate(track(pairs, progress, "pairs", unit="pair")):
        graphs = aerial_graphs(pair.aerial, subsets, PaperConfig(window=config.window, conventions=config.conventions))
        scored: dict[str, Any] = {}
        seconds = 0.0
        if "paper" in config.methods:
            scored, seconds = localize_subsets(graphs, pair.ground, pair.truth, scale, PaperConfig(
                p=config.p, top_k=config.top_k, conventions=config.conventions))
        methods: dict[str, dict[str, Any]] = {}
        if "paper" in config.methods:
            paper = LocalizeConfig(method="paper", paper=PaperConfig(p=config.p, top_k=config.top_k,
                                                                    conventions=config.conventions))
            other = pairs[(index + 1) % len(pairs)] if len(pairs) > 1 else None
            negative = (run(paper, aerial_graph(other.aerial.of_classes(subsets[0]),
                                                PaperConfig(window=config.window, conventions=config.conventions)),
                            pair.ground.of_classes(subsets[0])) if other is not None else None)
            methods["paper"] = {**{k: v for k, v in scored.items() if k != "by_subset"}, "localize_s": round(seconds, 4),
                                "heading_error_deg": None,
                                "confidence": confidence_of(run(paper, graphs[subsets[0]], pair.ground.of_classes(subsets[0]))),
                                "negative_confidence": None if negative is None else confidence_of(negative)}
        if "profile" in config.methods:
            methods["profile"] = _profile_pair(pair, pairs[(index + 1) % len(pairs)] if len(pairs) > 1 else None,
                                               config, scale)
        if not paper_first:  # the summary is the profile method's alone (no candidates, no class subsets)
            scored = {**methods["profile"], "candidate_guess": None, "candidates": 0}
            seconds = methods["profile"]["localize_s"]
        centre, uniform = chance_errors((pair.aerial.height, pair.aerial.width), pair.truth, scale)
        ground = pair.ground
        records.append({
            "index": index, "name": pair.name, "truth": list(pair.truth), "truth_given": pair.truth_given,
            "aerial_landmarks": len(pair.aerial), "query_landmarks": len(ground), "window_px": graphs[subsets[0]].window,
            "classes_seen": sorted({ground.classes[c] for c in set(ground.cls.tolist())}),
            "centre_guess": round(centre, 4), "random_guess": round(uniform, 4), "localize_s": round(seconds, 4),
            **scored, "methods": methods,
        })
    total = time.perf_counter() - t_start
    settings = asdict(config)
    settings["methods"] = list(config.methods)
    results: BenchResults = {
        "format": "osmseg-localize-bench", "format_version": 3, "tool": f"osmseg {__version__}",
        "kind": "annotated pairs", "queries": "annotated pairs", "unit": "m" if config.resolution_m else "px",
        "settings": settings, "source": source,
        "landmark_classes": {"name": classes.name, "names": list(classes.names), "mapping": dict(classes.mapping)},
        "classes": list(subsets[0]),
        "summary": summarize(records, radii),
        "baselines": _baselines(records),
        "by_num_classes": by_num_classes(subsets, records, radii),
        "methods": {m: method_summary(records, m, lambda rows: summarize(rows, radii),
                                      right_wrong=RIGHT_WRONG if config.resolution_m else None)
                    for m in config.methods},
        "timing": {"total_s": round(total, 3), "localize_mean_s": _mean_time(records)},
        "viewpoints": records,
    }
    write_results(results, Path(out_dir), plots)
    return results


def _baselines(records: list[dict[str, Any]]) -> dict[str, float | None]:
    """The blind guesses' errors (:func:`~localization.bench.scores.baselines`), without the image
    centre's when no pair has a truth of its own: the truth is then the centre, and guessing it
    would score a made-up 0."""
    out = baselines(records)
    if not any(r["truth_given"] for r in records):
        out["centre_guess_mean"] = None
    return out


def _profile_pair(pair: Pair, other: Pair | None, config: PairsConfig, scale: float) -> dict[str, Any]:
    """The profile method on one pair's landmark files; also on the next pair's aerial image (a non-match)."""
    t0 = time.perf_counter()
    cfg = replace(config.profile, heading_deg=0.0 if config.heading == "known" else None, top_k=config.top_k)
    camera = Camera(pair.ground.width, pair.ground.height, camera_height_m=config.camera_height_m)
    loc = run_profile(cfg, profile_index(pair.aerial, config.resolution_m, cfg), pair.ground, camera)
    seconds = time.perf_counter() - t0
    negative = (run_profile(cfg, profile_index(other.aerial, config.resolution_m, cfg), pair.ground, camera)
                if other is not None else None)
    # CVUSA panoramas face north: the true heading is 0
    heading = None if config.heading == "known" or loc.heading_deg is None else heading_error(loc.heading_deg, 0.0)
    return {**error_fields(loc, pair.truth, scale), "localize_s": round(seconds, 4), "heading_error_deg": heading,
            "confidence": loc.confidence, "kappa": loc.kappa, "margin": loc.margin,
            "negative_confidence": None if negative is None else negative.confidence,
            "negative_kappa": None if negative is None else negative.kappa}
