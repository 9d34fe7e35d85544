"""``osmseg localize``: where in the aerial image was the ground view taken.

(A region drawn from OpenStreetMap is :mod:`localization.cli.region`'s ``localize-region``; the
benchmarks are :mod:`localization.cli.bench`'s.) The command builds one :class:`ImageQuery` from
its options and calls its :meth:`~ImageQuery.run`.

Registered on the ``osmseg`` group as plugins (entry points ``osmseg.commands``), so the core
package never imports this one. Imports: osmseg core, training (through
:mod:`localization.common.inputs`, for segmenting RGB inputs) and localization.

Each side (``--aerial``, ``--ground``) is a label mask (PNG/TIFF of class ids), a landmark file
(``x y Class`` lines, ``.csv`` or ``.npy``), or an RGB image with ``--*-checkpoint`` to segment
it first. A mask's class table is ``--*-table``, else the ``manifest.json`` of the osmseg
dataset it belongs to (``DATASET/labels/NAME.png``), else the one the landmark dictionary names
(``mask_table``/``mask_classes`` in ``data_manifests/landmarks-*.toml``). A landmark file's
image size is ``--*-size``, else that of an image beside it with the same name (also drawn
under the pictures), else the extent of its landmarks (with a warning).

``--feature-threshold T`` removes the graph edges between landmarks whose encoder features
are closer than T (§5.3.2, :mod:`localization.paper.features`) on each side that is an RGB image or
has its photo as ``--*-image``; result.json's ``feature_edges`` says how many went per side.

The top-k locations go to stdout (a table, or JSON with ``--json``); "unanswered" (no place
in the aerial image shows every class the ground sees) is a normal outcome: exit 0. Bad input
(an unreadable file, no landmarks, a window larger than the image, landmarks of a single
class on both sides) is a one-line error, exit 1 (2 for options).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from localization.cli.options import (
    AERIAL_LANDMARKS,
    AERIAL_RESOLUTION,
    AERIAL_SIZE,
    CAMERA_HEIGHT,
    CONVENTIONS,
    FOV,
    GRID_STRIDE,
    GROUND_LANDMARKS,
    GROUND_SIZE,
    HEADING,
    LANDMARK_MODE,
    METHOD,
    MIN_SIZE,
    TOP_K,
    WINDOW,
    P,
    misplaced,
    parse_point,
    parse_window,
    parse_windows,
    typed_flags,
)
from localization.cli.query import (
    AERIAL_TABLE,
    GROUND,
    GROUND_CHECKPOINT,
    GROUND_MODEL,
    GROUND_MODEL_CLASSES,
    GROUND_TABLE,
    HEADING_WITHIN,
    JSON,
    PHOTO,
    TILT,
    TRUTH,
    VISTA,
    GroundQuery,
    LandmarkOptions,
    ViewOptions,
    apply_photo,
    say_photo,
)
from localization.common.inputs import SideOptions
from osmseg.cli.common import output_options, parse_size, report_errors
from osmseg.cli.options import OUT, declare, moved, moved_each
from osmseg.cli.requests import make_request, part_options
from osmseg.errors import ConfigError
from osmseg.texttable import text_table
from osmseg.units import degrees, metres, number, pixels, plural, ratio

if TYPE_CHECKING:  # the command imports the pipeline only when it runs
    from localization.pipeline import LocalizeConfig, LocalizeReport


logger = logging.getLogger(__name__)

# --------------------------------------------------------------------------- checks and output


def _table(result: Any) -> str:
    """The top-k as a fixed-width table."""
    return text_table(["rank", "x", "y", "posterior", "likelihood"],
                      [[str(rank), number(x, "px"), number(y, "px"), ratio(post), ratio(float(result.likelihoods[i]))]
                       for rank, ((x, y, post), i) in enumerate(zip(result.top_k, result.order), start=1)], left=0)


AERIAL = declare("--aerial", dest="aerial_path", type=click.Path(exists=True, dir_okay=False, path_type=Path),
                 help="Aerial label mask (PNG/TIFF of class ids), landmark file (x y Class, .csv, .npy) or RGB image "
                      "with --aerial-checkpoint.")
AERIAL_CHECKPOINT = declare("--aerial-checkpoint", type=click.Path(exists=True, path_type=Path),
                            help="Segment the aerial RGB image with this checkpoint first (needs PyTorch).")
NO_PANORAMA = declare("--panorama/--no-panorama",
                      help="The ground image is a 360-degree panorama (x wraps around); --no-panorama for an aerial "
                           "crop.")
GROUND_WINDOW = declare("--ground-window", type=click.IntRange(min=1), help="Ground window in pixels.")
STRIDE = declare("--stride", type=click.IntRange(min=1), help="Window stride in pixels.")
HIERARCHICAL = declare("--hierarchical", is_flag=True,
                       help="Refine over --windows, multiplying probabilities (eq. 3.8).")
WINDOWS = declare("--windows", dest="windows_text", help="Hierarchical windows, coarse to fine.")
REFERENCE = declare("--reference", is_flag=True,
                    help="Build graphs with the paper's plain sliding window (slow; a check).")
AERIAL_IMAGE = declare("--aerial-image", type=click.Path(exists=True, dir_okay=False, path_type=Path),
                       help="RGB photo of the aerial mask or landmark file: for --feature-threshold, and drawn under "
                            "the graph.")
GROUND_IMAGE = declare("--ground-image", type=click.Path(exists=True, dir_okay=False, path_type=Path),
                       help="RGB photo of the ground mask or landmark file.")
FEATURE_THRESHOLD = declare("--feature-threshold", type=click.FloatRange(min=0, min_open=True),
                            help="Remove edges between landmarks whose encoder features are closer than this "
                                 "(§5.3.2).")
FEATURE_METRIC = declare("--feature-metric", type=click.Choice(["euclidean", "cosine"]),
                         help="Distance between two landmarks' encoder features.")
FEATURE_REDUCE = declare("--feature-reduce", type=click.Choice(["none", "pca", "umap"]),
                         help="Reduce the features first (umap needs umap-learn). PCA centres them: with 2 landmarks "
                              "their cosine distance is 2, so nothing is dropped.")
FEATURE_COMPONENTS = declare("--feature-components", type=click.IntRange(min=1),
                             help="Dimensions --feature-reduce keeps.")
FEATURE_CHECKPOINT = declare("--feature-checkpoint", type=click.Path(exists=True, path_type=Path),
                             help="Checkpoint whose encoder gives the features.")
MIN_CONFIDENCE = declare("--min-confidence", type=click.FloatRange(-1, 1),
                         help="Profile method: below this confidence (how far the answer stands out from the best "
                              "place 50 m or more away) the answer is 'not sure'.")
MIN_KAPPA = declare("--min-kappa", type=click.FloatRange(-1, 1),
                    help="Profile method: below this kappa (the best match against chance) the answer is 'not in "
                         "this image'; lower it for segmented RGB queries.")

#: what ``osmseg localize`` says to an option of a region search
_REGION = ("{flag} is a region search's: osmseg localize-region --ground FILE --osm FILE --bbox W,S,E,N searches "
           "OpenStreetMap; osmseg localize searches the --aerial image")


#: The region search's options, refused by ``osmseg localize`` in one line naming localize-region.
region_moved = moved_each(("--osm", "--bbox", "--lat", "--lon", "--radius-km", "--zoom", "--shard", "--cache-dir"), _REGION)


@click.command("localize")
@output_options
@AERIAL(required=True)
@GROUND()
@PHOTO()
@AERIAL_LANDMARKS(default="aerial13", show_default=True)
@GROUND_LANDMARKS(default="camvid", show_default=True)
@AERIAL_TABLE(show_default="its dataset's manifest")
@GROUND_TABLE(show_default="the dictionary's own")
@AERIAL_SIZE(show_default="an image beside it")
@GROUND_SIZE()
@AERIAL_CHECKPOINT()
@GROUND_CHECKPOINT()
@GROUND_MODEL()
@GROUND_MODEL_CLASSES()
@NO_PANORAMA(default=True, show_default=True)
@WINDOW(default="auto", show_default=True)
@GROUND_WINDOW(show_default="a panorama's height; otherwise the aerial window")
@P(default=0.5, show_default=True)
@TOP_K(default=5, show_default=True)
@STRIDE(default=1, show_default=True)
@HIERARCHICAL()
@WINDOWS(default="400,200,100", show_default=True)
@LANDMARK_MODE(dest="mode", default="centroid", show_default=True)
@MIN_SIZE(default=50, show_default=True)
@GRID_STRIDE(default=50, show_default=True)
@REFERENCE()
@TRUTH(detail=", as X,Y in aerial pixels.")
@AERIAL_RESOLUTION(dest="resolution", show_default="a GeoTIFF's, or the dataset manifest's")
@JSON()
@OUT(detail=" of localization.png, aerial_graph.png, ground_graph.png and result.json.")
@AERIAL_IMAGE()
@GROUND_IMAGE()
@FEATURE_THRESHOLD(show_default="off")
@FEATURE_METRIC(default="cosine", show_default=True)
@FEATURE_REDUCE(default="pca", show_default=True)
@FEATURE_COMPONENTS(default=8, show_default=True)
@FEATURE_CHECKPOINT(show_default="the side's --aerial-checkpoint/--ground-checkpoint")
@CONVENTIONS(default="osmseg", show_default=True)
@METHOD(default="profile", show_default=True)
@HEADING(default="0", show_default=True)
@HEADING_WITHIN()
@FOV(default=360.0, show_default=True)
@CAMERA_HEIGHT(default="2", show_default=True)
@TILT(default=0.0, show_default="level")
@VISTA(default=0.0, show_default="0, none")
@MIN_CONFIDENCE(show_default="0.04 for an aerial mask, none for aerial landmark points")
@MIN_KAPPA(show_default="0.6 for an aerial mask, 0.3 for aerial landmark points")
@region_moved
@moved("--mode", "--mode is predict's (split-join or rescale): osmseg localize's landmarks are --landmark-mode "
                 "centroid|grid|component")
@moved("--resolution", "--resolution is predict's (resample the input): osmseg localize takes the aerial "
                       "image's metres per pixel as --aerial-resolution")
@moved("--aerial-classes", "--aerial-classes is now --aerial-landmarks (a landmark dictionary; --aerial-table is "
                           "the class table)")
@moved("--ground-classes", "--ground-classes is now --ground-landmarks (a landmark dictionary; --ground-table is "
                           "the class table)")
@click.pass_context
@report_errors
def localize_command(ctx: click.Context, /, **params: Any) -> None:
    """Find where the GROUND view was taken in the AERIAL image: angular profiles (the default) or
    landmark graphs (--method paper). A region drawn from OpenStreetMap is osmseg localize-region's."""
    typed = typed_flags(ctx)
    facts = apply_photo(params, typed)
    if facts is not None:
        say_photo(facts, params, quiet=(ctx.obj or {}).get("verbosity", 0) < 0)
    request = make_request(ImageQuery, params, typed=typed)
    report = request.run()
    _say(report, as_json=request.as_json, quiet=(ctx.obj or {}).get("verbosity", 0) < 0,
         hierarchical=request.paper.hierarchical, auto_window=request.paper.window is None, out_dir=request.out_dir)


@dataclass(frozen=True)
class AerialImage:
    """The aerial side: its file, how to read it, its photo and metres per pixel (``--aerial*``)."""

    aerial_path: Path
    aerial_classes: str
    aerial_table: str | None
    aerial_size: str | None
    aerial_checkpoint: Path | None
    aerial_image: Path | None
    resolution: float | None

    def side(self, landmarks: LandmarkOptions) -> SideOptions:
        """How :func:`localization.common.inputs.load_side` reads the aerial image."""
        return SideOptions("aerial", self.aerial_classes, self.aerial_table,
                           parse_size(self.aerial_size, "--aerial-size"), self.aerial_checkpoint, False,
                           mode=landmarks.mode, min_size=landmarks.min_size, grid_stride=landmarks.grid_stride)


@dataclass(frozen=True)
class FeatureOptions:
    """How ``--feature-threshold`` removes graph edges (§5.3.2); the others set how, so they go with it."""

    feature_threshold: float | None
    feature_checkpoint: Path | None
    feature_metric: str
    feature_reduce: str
    feature_components: int


@dataclass(frozen=True)
class PaperOptions:
    """The paper method's options (Verde et al. 2020): its windows, covisibility and feature edges."""

    window_text: str
    ground_window: int | None
    p: float
    stride: int
    hierarchical: bool
    windows_text: str
    reference: bool
    features: FeatureOptions
    conventions: str

    @property
    def window(self) -> int | None:
        """``--window`` in pixels; None for auto."""
        return parse_window(self.window_text)


@dataclass(frozen=True)
class ProfileOptions:
    """The profile method's options: how the view was taken, and when an answer is accepted."""

    view: ViewOptions
    min_confidence: float | None
    min_kappa: float | None


@dataclass(frozen=True)
class ImageQuery:
    """What ``osmseg localize`` was asked, typed and frozen; ``typed`` (parameter -> flag) the
    options given on the command line. The options of the method not run, and feature options
    without ``--feature-threshold``, are refused from the parts' own fields."""

    aerial: AerialImage
    ground: GroundQuery
    ground_image: Path | None
    panorama: bool
    landmarks: LandmarkOptions
    method: str
    paper: PaperOptions
    profile: ProfileOptions
    top_k: int
    truth_text: str | None
    as_json: bool
    out_dir: Path | None
    typed: Mapping[str, str] = field(default_factory=dict)

    def _refuse_misplaced(self) -> None:
        """One line for options that do nothing in this run."""
        features = self.paper.features
        how = tuple(n for n in part_options(FeatureOptions) if n != "feature_threshold")
        if features.feature_threshold is None and (stray := self._given(how)):
            raise ConfigError(f"{', '.join(stray)} set how --feature-threshold removes edges: add "
                              "--feature-threshold T, or leave them out")
        for name, part in (("profile", ProfileOptions), ("paper", PaperOptions)):
            if self.method != name and (stray := self._given(part_options(part))):
                raise misplaced(stray, f"--method {name}", f"--method {name}")

    def _given(self, names: tuple[str, ...]) -> list[str]:
        return [self.typed[n] for n in names if n in self.typed]

    def config(self) -> LocalizeConfig:
        """The pipeline's :class:`~localization.pipeline.LocalizeConfig`."""
        from localization.paper.config import PaperConfig
        from localization.paper.features import FeatureEdges
        from localization.pipeline import LocalizeConfig

        self._refuse_misplaced()
        paper, f, view = self.paper, self.paper.features, self.profile.view
        features = (None if f.feature_threshold is None else
                    FeatureEdges(f.feature_threshold, f.feature_metric, f.feature_reduce, f.feature_components))
        return LocalizeConfig(
            method=self.method, features=features, fov_deg=view.fov_deg, camera_height_m=view.camera_height,
            paper=PaperConfig(window=paper.window, query_window=paper.ground_window, p=paper.p, stride=paper.stride,
                              top_k=self.top_k, fast=not paper.reference, hierarchical=paper.hierarchical,
                              windows=parse_windows(paper.windows_text), conventions=paper.conventions),
            profile=view.profile(top_k=self.top_k, min_confidence=self.profile.min_confidence,
                                 min_kappa=self.profile.min_kappa))

    def run(self) -> LocalizeReport:
        """Localize the ground view in the aerial image; with ``out_dir``, write result.json and the pictures."""
        from localization.pipeline import LocalizeFiles, localize_files

        config = self.config()
        files = LocalizeFiles(
            aerial=self.aerial.aerial_path, ground=self.ground.ground_path,
            aerial_options=self.aerial.side(self.landmarks),
            ground_options=self.ground.side(self.landmarks, self.panorama),
            aerial_image=self.aerial.aerial_image, ground_image=self.ground_image,
            feature_checkpoint=self.paper.features.feature_checkpoint, truth=parse_point(self.truth_text),
            resolution_m=self.aerial.resolution)
        return localize_files(files, config, self.out_dir)


def _say(report: LocalizeReport, *, as_json: bool, quiet: bool, hierarchical: bool, auto_window: bool,
         out_dir: Path | None) -> None:
    """What ``osmseg localize`` prints: the answer on stdout (a table, or JSON), how it was found on stderr."""
    result = report.result
    if as_json:
        click.echo(json.dumps({**report.summary.to_json(), **result.to_dict(all_candidates=False),
                               "files": [str(f) for f in report.written]}, indent=2, sort_keys=True))
    elif result.unanswered:
        click.echo(f"unanswered: {result.reason}")
    else:
        click.echo(_table(result))
    if not quiet and not as_json:
        if result.method == "profile" and result.confidence is not None:
            alt = (f"; best place 50 m or more away scores {ratio(result.margin)} less" if result.margin is not None
                   else "")
            pose = ""
            if result.camera_pose is not None:
                h, pitch, roll = result.camera_pose
                pose = f", camera {metres(h)} up, pitch {degrees(pitch)}, roll {degrees(roll)}"
            click.echo(f"profile method: heading {degrees(result.heading_deg)}{pose}, confidence "
                       f"{ratio(result.confidence)} (kappa {ratio(result.kappa)} against chance "
                       f"{ratio(result.chance)}{alt}), {plural(len(result.candidates), 'position')} at the finest level", err=True)
        elif not result.unanswered:
            ties = f", {result.ties} tied at the top (broken as documented)" if result.ties > 1 else ""
            used = (f"windows {', '.join(str(lv.window) for lv in result.levels)} px (hierarchical)" if hierarchical
                    else f"window {result.window} px{' (auto)' if auto_window else ''}")
            click.echo(f"{used}, ground window {result.query_window} px, {plural(result.n_cliques, 'clique')}, "
                       f"{plural(len(result.candidates), 'candidate')}{ties}", err=True)
        if (where := report.summary.map_lonlat) is not None:
            click.echo(f"the answer in degrees (the aerial image's georeference): {where[0]:.7f}, "
                       f"{where[1]:.7f}", err=True)
        if report.error_px is not None:
            click.echo(f"error of the best location: {pixels(report.error_px)}"
                       + (f" ({metres(report.error_m)})" if report.error_m is not None else ""), err=True)
        if report.written:
            click.echo(f"written: {', '.join(f.name for f in report.written)} in {out_dir}/", err=True)
