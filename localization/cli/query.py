"""What both localize commands take: the ground view (the query), its landmarks, and how it was taken.

``osmseg localize`` searches an aerial image and ``osmseg localize-region`` a region drawn from
OpenStreetMap; the query is the same in both. Its options are declared here once, and their
values travel as the request parts :class:`GroundQuery`, :class:`LandmarkOptions` and
:class:`ViewOptions` (built by :func:`osmseg.cli.requests.make_request`).

Imports: osmseg core and localization (common, profile; never another localization.cli command).
"""

from __future__ import annotations

from collections.abc import Mapping, MutableMapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click

from localization.cli.options import parse_camera_height, parse_heading
from localization.common.inputs import SideOptions
from localization.common.photo import COMPASS_WITHIN_DEG, PhotoFacts, photo_facts
from localization.profile.search import ProfileConfig
from osmseg.cli.common import parse_size
from osmseg.cli.options import declare

__all__ = ["GroundQuery", "LandmarkOptions", "ViewOptions", "GROUND", "GROUND_TABLE", "AERIAL_TABLE",
           "GROUND_CHECKPOINT", "GROUND_MODEL", "GROUND_MODEL_CLASSES", "TRUTH", "JSON", "TILT", "VISTA", "PHOTO", "HEADING_WITHIN", "apply_photo", "say_photo"]

GROUND = declare("--ground", dest="ground_path", type=click.Path(exists=True, dir_okay=False, path_type=Path),
                 help="Ground view: label mask (PNG/TIFF of class ids), landmark file (x y Class, .csv, .npy), or RGB "
                      "image with --ground-checkpoint.")
GROUND_TABLE = declare("--ground-table", help="Class table of the ground mask.")
PHOTO = declare("--photo", dest="photo_path", type=click.Path(exists=True, dir_okay=False, path_type=Path),
                help="The photo as it was taken (JPEG or TIFF with EXIF): its field of view (focal length), compass "
                     "heading and GPS fix stand in for --fov, --heading/--heading-within and the region's centre "
                     "where those are not given. The ground view is its class-id mask (--ground), or the photo "
                     "itself segmented with --ground-checkpoint or --ground-model.")
HEADING_WITHIN = declare("--heading-within", dest="heading_within_deg", type=click.FloatRange(0, 180, min_open=True),
                         metavar="DEGREES",
                         help="How far --heading (or a --photo's compass) may be off: headings within this many "
                              f"degrees of it are searched [--heading: exact; a photo's compass: {COMPASS_WITHIN_DEG:g}].")
AERIAL_TABLE = declare("--aerial-table", help="Class table of the aerial side, e.g. classes13.toml.")
GROUND_CHECKPOINT = declare("--ground-checkpoint", type=click.Path(exists=True, path_type=Path),
                            help="Segment the ground RGB image with this checkpoint first (needs PyTorch).")
GROUND_MODEL = declare("--ground-model", type=click.Path(exists=True, dir_okay=False, path_type=Path),
                       help="Segment the ground RGB image with a model trained elsewhere first: TorchScript (.pt, .ts) "
                            "or ONNX (.onnx), read through --ground-model-classes.")
GROUND_MODEL_CLASSES = declare("--ground-model-classes", type=click.Path(exists=True, dir_okay=False, path_type=Path),
                               help="TOML naming the osmseg class of each output channel of --ground-model (and its "
                                    "table, input size and normalisation; docs/localization.md).")
TRUTH = declare("--truth", dest="truth_text", metavar="POINT",
               help="Where the ground view was really taken, to report the answer's error")
JSON = declare("--json", dest="as_json", is_flag=True, help="Print the result as JSON instead of a table.")
TILT = declare("--tilt", dest="tilt_deg", type=click.FloatRange(0, 10),
               help="Profile method: the camera may be tilted up to this many degrees in pitch and roll; the tilt is "
                    "read from the ground mask's horizon, where its sky ends and its ground begins (give the sky as "
                    "a class: the ground table's 'sky', id 14 for classes13).")

VISTA = declare("--vista-weight", type=click.FloatRange(min=0),
                help="Profile method: how much an open horizon counts, in ground distances (4 tells more look-alikes "
                     "apart: docs/localization.md). Where the ground view's sky comes down to the horizon, nothing "
                     "stands within 75 m: a place with a building there fits worse. Needs the sky as a class.")


@dataclass(frozen=True)
class LandmarkOptions:
    """How a mask becomes landmarks: ``--landmark-mode``, ``--min-size``, ``--grid-stride``."""

    mode: str
    min_size: int
    grid_stride: int


@dataclass(frozen=True)
class GroundQuery:
    """The ground view: its file and how to read it (``--ground*``)."""

    ground_path: Path
    ground_classes: str
    ground_table: str | None
    ground_size: str | None
    ground_checkpoint: Path | None
    ground_model: Path | None = None
    ground_model_classes: Path | None = None

    def side(self, landmarks: LandmarkOptions, panorama: bool) -> SideOptions:
        """How :func:`localization.common.inputs.load_side` reads the ground view."""
        if self.ground_checkpoint is not None and self.ground_model is not None:
            raise click.UsageError("give one segmentation of the ground photo: --ground-checkpoint (an osmseg "
                                   "checkpoint) or --ground-model (TorchScript or ONNX)")
        if self.ground_model_classes is not None and self.ground_model is None:
            raise click.UsageError("--ground-model-classes reads the output of --ground-model: give the model too")
        return SideOptions("ground", self.ground_classes, self.ground_table,
                           parse_size(self.ground_size, "--ground-size"), self.ground_checkpoint, panorama,
                           mode=landmarks.mode, min_size=landmarks.min_size, grid_stride=landmarks.grid_stride,
                           model=self.ground_model, model_classes=self.ground_model_classes)


@dataclass(frozen=True)
class ViewOptions:
    """How the ground view was taken, as the profile method reads it: ``--heading`` (``--heading-within``),
    ``--fov``, ``--camera-height``, ``--tilt`` and ``--vista-weight``, and the ``--photo`` whose EXIF gave those
    not typed."""

    heading_text: str
    fov_deg: float
    camera_height_text: str
    tilt_deg: float
    heading_within_deg: float | None = None
    photo_path: Path | None = None  # the photo whose EXIF filled what was not given (apply_photo)
    vista_weight: float = ProfileConfig.vista_weight

    @property
    def camera_height(self) -> float:
        """The camera's height in metres (2 when unknown: the heights tried are :meth:`profile`'s)."""
        return parse_camera_height(self.camera_height_text)[0]

    def profile(self, top_k: int = 5, min_confidence: float | None = None,
                min_kappa: float | None = None) -> ProfileConfig:
        """The profile method's configuration: heading, heights to try and tilt, and what is reported."""
        heights = parse_camera_height(self.camera_height_text)[1]
        heading = parse_heading(self.heading_text)
        near = heading is not None and self.heading_within_deg is not None  # a compass: the heading searched near it
        return ProfileConfig(heading_deg=None if near else heading, heading_prior_deg=heading if near else None,
                             heading_within_deg=self.heading_within_deg if near and self.heading_within_deg else 180.0,
                             camera_heights=heights, tilt_deg=self.tilt_deg, vista_weight=self.vista_weight,
                             top_k=top_k,
                             min_confidence=min_confidence, min_kappa=min_kappa)


def apply_photo(params: MutableMapping[str, Any], typed: Mapping[str, str]) -> PhotoFacts | None:
    """Fill ``params`` (a localize command's) from ``--photo``'s EXIF where the user gave nothing:
    ``--fov`` from its focal length, ``--heading`` and ``--heading-within`` from its compass (none:
    the heading is searched), and the ground view from the photo itself with ``--ground-checkpoint``.
    Returns what the EXIF said (None without ``--photo``); UsageError for a query that is missing
    or does not match the photo."""
    photo = params.get("photo_path")
    facts = photo_facts(photo) if photo is not None else None
    if "heading_within_deg" in typed and "heading_text" not in typed and (facts is None or facts.heading_deg is None):
        raise click.UsageError("--heading-within is how far a heading may be off: give it with --heading DEGREES (or a "
                               "--photo whose EXIF has a compass heading)")
    if "heading_within_deg" in typed and parse_heading(str(params.get("heading_text"))) is None:
        raise click.UsageError("--heading-within needs a heading to search near: --heading DEGREES, not unknown")
    if photo is None or facts is None:
        if params.get("ground_path") is None:
            raise click.UsageError("give the ground view: --ground FILE (or --photo FILE.jpg with --ground-checkpoint "
                                   "or --ground-model)")
        return None
    if params.get("ground_path") is None:
        if params.get("ground_checkpoint") is None and params.get("ground_model") is None:
            raise click.UsageError(f"--photo {photo.name}: give its class-id mask as --ground FILE, or segment the "
                                   "photo itself with --ground-checkpoint FILE or --ground-model FILE")
        params["ground_path"] = photo
    else:
        _check_aspect(Path(params["ground_path"]), facts, photo)
    if "fov_deg" not in typed:
        if facts.hfov_deg is None:
            raise click.UsageError(f"--photo {photo.name}: its EXIF has no focal length; give its field of view as "
                                   "--fov DEGREES")
        if not 10 <= facts.hfov_deg <= 360:
            raise click.UsageError(f"--photo {photo.name}: its EXIF gives a field of view of {facts.hfov_deg:.1f}° "
                                   f"({facts.fov_from}), outside 10-360°; give it as --fov DEGREES")
        params["fov_deg"] = round(facts.hfov_deg, 3)
    if "heading_text" not in typed:
        if facts.heading_deg is None:
            params["heading_text"] = "unknown"  # a photo without a compass: its heading is searched
        else:
            params["heading_text"] = f"{facts.heading_deg:g}"
            if "heading_within_deg" not in typed:
                params["heading_within_deg"] = COMPASS_WITHIN_DEG
    return facts


def _check_aspect(mask: Path, facts: PhotoFacts, photo: Path) -> None:
    """UsageError when ``mask`` cannot be ``photo``'s segmentation: another shape than the photo upright."""
    from PIL import Image

    try:
        with Image.open(mask) as im:
            w, h = im.size
    except OSError:
        return  # a landmark file: read (and refused if need be) as a ground view
    if abs(w / h - facts.width / facts.height) > 0.02 * (facts.width / facts.height):
        raise click.UsageError(f"--ground {mask.name} is {w}x{h}, but --photo {photo.name} is {facts.width}x"
                               f"{facts.height} upright: give the mask of this photo as it is seen (EXIF orientation "
                               "applied)")


def say_photo(facts: PhotoFacts, params: Mapping[str, Any], quiet: bool = False) -> None:
    """Say on stderr what the photo's EXIF gave and how the search takes it (``params``: after :func:`apply_photo`)."""
    if quiet:
        return
    click.echo(f"photo: {facts.describe()}", err=True)
    if facts.hfov_deg is not None and abs(float(params["fov_deg"]) - facts.hfov_deg) > 0.01:
        click.echo(f"field of view: {float(params['fov_deg']):g}° (--fov), not the EXIF's", err=True)
    within = params.get("heading_within_deg")
    if params.get("heading_text") == "unknown":
        click.echo("heading: searched (give --heading DEGREES if it is known)", err=True)
    elif within is not None:
        click.echo(f"heading: searched within ±{within:g}° of {params['heading_text']}° (--heading-within; a phone's "
                   "compass is often 10-30° off)", err=True)
