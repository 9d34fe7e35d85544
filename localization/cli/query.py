"""What both localize commands take: the ground view (the query), its landmarks, and how it was taken.

``osmseg localize`` searches an aerial image and ``osmseg localize-region`` a region drawn from
OpenStreetMap; the query is the same in both. Its options are declared here once, and their
values travel as the request parts :class:`GroundQuery`, :class:`LandmarkOptions` and
:class:`ViewOptions` (built by :func:`osmseg.cli.requests.make_request`).

Imports: osmseg core and localization (common, profile; never another localization.cli command).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import click

from localization.cli.options import parse_camera_height, parse_heading
from localization.common.inputs import SideOptions
from localization.profile.search import ProfileConfig
from osmseg.cli.common import parse_size
from osmseg.cli.options import declare

__all__ = ["GroundQuery", "LandmarkOptions", "ViewOptions", "GROUND", "GROUND_TABLE", "AERIAL_TABLE",
           "GROUND_CHECKPOINT", "TRUTH", "JSON", "TILT"]

GROUND = declare("--ground", dest="ground_path", type=click.Path(exists=True, dir_okay=False, path_type=Path),
                 help="Ground view: label mask (PNG/TIFF of class ids), landmark file (x y Class, .csv, .npy), or RGB "
                      "image with --ground-checkpoint.")
GROUND_TABLE = declare("--ground-table", help="Class table of the ground mask.")
AERIAL_TABLE = declare("--aerial-table", help="Class table of the aerial side, e.g. classes13.toml.")
GROUND_CHECKPOINT = declare("--ground-checkpoint", type=click.Path(exists=True, path_type=Path),
                            help="Segment the ground RGB image with this checkpoint first (needs PyTorch).")
TRUTH = declare("--truth", dest="truth_text", metavar="POINT",
               help="Where the ground view was really taken, to report the answer's error")
JSON = declare("--json", dest="as_json", is_flag=True, help="Print the result as JSON instead of a table.")
TILT = declare("--tilt", dest="tilt_deg", type=click.FloatRange(0, 10),
               help="Profile method: the camera may be tilted up to this many degrees in pitch and roll; the tilt is "
                    "read from the ground mask's horizon, where its sky ends and its ground begins (give the sky as "
                    "a class: the ground table's 'sky', id 14 for classes13).")


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

    def side(self, landmarks: LandmarkOptions, panorama: bool) -> SideOptions:
        """How :func:`localization.common.inputs.load_side` reads the ground view."""
        return SideOptions("ground", self.ground_classes, self.ground_table,
                           parse_size(self.ground_size, "--ground-size"), self.ground_checkpoint, panorama,
                           mode=landmarks.mode, min_size=landmarks.min_size, grid_stride=landmarks.grid_stride)


@dataclass(frozen=True)
class ViewOptions:
    """How the ground view was taken, as the profile method reads it: ``--heading``, ``--fov``,
    ``--camera-height`` and ``--tilt``."""

    heading_text: str
    fov_deg: float
    camera_height_text: str
    tilt_deg: float

    @property
    def camera_height(self) -> float:
        """The camera's height in metres (2 when unknown: the heights tried are :meth:`profile`'s)."""
        return parse_camera_height(self.camera_height_text)[0]

    def profile(self, top_k: int = 5, min_confidence: float | None = None,
                min_kappa: float | None = None) -> ProfileConfig:
        """The profile method's configuration: heading, heights to try and tilt, and what is reported."""
        heights = parse_camera_height(self.camera_height_text)[1]
        return ProfileConfig(heading_deg=parse_heading(self.heading_text), camera_heights=heights,
                             tilt_deg=self.tilt_deg, top_k=top_k, min_confidence=min_confidence, min_kappa=min_kappa)
