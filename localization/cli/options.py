"""Parsers of ``osmseg localize`` and ``localize-bench`` options that click's types do not cover.

Each turns the text of an option into a value or raises a one-line
:class:`~osmseg.errors.ConfigError` that says what to give. Below them, the options that more
than one ``localize`` command takes, declared once (:mod:`osmseg.cli.options`). Imports: osmseg
core and localization.profile.search.
"""

from __future__ import annotations

import math
from pathlib import Path

import click

from localization.profile.search import UNKNOWN_HEIGHTS
from osmseg.cli.common import typed_options
from osmseg.cli.options import declare
from osmseg.errors import ConfigError

__all__ = ["given", "misplaced", "osm_files", "typed_flags", "parse_pair", "parse_point", "parse_window", "parse_windows", "parse_camera_height", "parse_heading", "parse_heights"]


def osm_files(values: tuple[str, ...]) -> tuple[Path, ...]:
    """``--osm`` as the files a localize command reads: each an existing file (not ``api`` or
    ``overpass``, which only ``osmseg build`` fetches from)."""
    files = tuple(Path(v) for v in values)
    for path in files:
        if not path.is_file():
            raise click.BadParameter(f"{path} is not a file: osmseg localize reads OpenStreetMap files (.osm, "
                                     ".osm.pbf)", param_hint="'--osm'")
    return files


def parse_point(value: str | None) -> tuple[float, float] | None:
    """``"375,380"`` -> (375.0, 380.0).

    >>> parse_point("375,380.5")
    (375.0, 380.5)
    """
    if value is None:
        return None
    return parse_pair(value, f"--truth must be X,Y in aerial pixels, e.g. 375,380; got {value!r}",
                      f"--truth must be finite numbers, got {value!r}")


def parse_pair(value: str, usage: str, not_finite: str) -> tuple[float, float]:
    """Two comma-separated finite numbers; ConfigError ``usage`` when they are not two numbers,
    ``not_finite`` when one is infinite or NaN.

    >>> parse_pair("26.9,60.5", "give LON,LAT", "finite, please")
    (26.9, 60.5)
    """
    try:
        a, b = (float(v) for v in value.split(","))
    except ValueError:
        raise ConfigError(usage) from None
    if not (math.isfinite(a) and math.isfinite(b)):
        raise ConfigError(not_finite)
    return a, b


def parse_window(value: str) -> int | None:
    """``--window``: pixels, or None for "auto".

    >>> parse_window("auto"), parse_window("120")
    (None, 120)
    """
    if value.strip().lower() == "auto":
        return None
    try:
        w = int(value)
    except ValueError:
        raise ConfigError(f"--window must be a number of pixels or 'auto', got {value!r}") from None
    if w < 1:
        raise ConfigError(f"--window must be at least 1 pixel, got {w}")
    return w


def parse_windows(value: str) -> tuple[int, ...]:
    """``--windows``: pixel sizes, coarse to fine.

    >>> parse_windows("400,200,100")
    (400, 200, 100)
    """
    try:
        sizes = tuple(int(v) for v in value.split(","))
    except ValueError:
        raise ConfigError(f"--windows must be pixel sizes, coarse to fine, e.g. 400,200,100; got {value!r}") from None
    if not sizes or min(sizes) < 1:
        raise ConfigError(f"--windows must be positive pixel sizes, got {value!r}")
    return sizes


def parse_camera_height(value: str) -> tuple[float, tuple[float, ...]]:
    """``--camera-height``: (metres, heights to try: none when known).

    >>> parse_camera_height("1.7"), parse_camera_height("unknown")
    ((1.7, ()), (2.0, (1.5, 1.75, 2.0, 2.25, 2.5)))
    """
    if value.strip().lower() == "unknown":
        return 2.0, UNKNOWN_HEIGHTS
    try:
        height = float(value)
    except ValueError:
        raise ConfigError(f"--camera-height must be metres above the ground or 'unknown', got {value!r}") from None
    if not (math.isfinite(height) and height > 0):
        raise ConfigError(f"--camera-height must be a positive number of metres, got {value!r}")
    return height, ()


def parse_heading(value: str) -> float | None:
    """``--heading``: degrees, or None for "unknown".

    >>> parse_heading("unknown"), parse_heading("90")
    (None, 90.0)
    """
    if value.strip().lower() == "unknown":
        return None
    try:
        heading = float(value)
    except ValueError:
        raise ConfigError(f"--heading must be degrees clockwise from north or 'unknown', got {value!r}") from None
    if not math.isfinite(heading):
        raise ConfigError(f"--heading must be a finite number of degrees, got {value!r}")
    return heading % 360.0


def parse_heights(values: tuple[str, ...]) -> dict[str, float]:
    """``("building=12", "tree=5")`` -> the default heights updated with these."""
    from localization.bench.render import DEFAULT_HEIGHTS

    heights = dict(DEFAULT_HEIGHTS)
    for item in values:
        name, eq, metres = item.partition("=")
        try:
            heights[name.strip()] = float(metres)
        except ValueError:
            raise ConfigError(f"--class-height {item!r}: write CLASS=METRES, e.g. building=12") from None
        if not eq or not name.strip():
            raise ConfigError(f"--class-height {item!r}: write CLASS=METRES, e.g. building=12")
    return heights


def misplaced(stray: list[str], owner: str, fix: str) -> ConfigError:
    """The one-line error for options that belong to another method than the one run.

    >>> str(misplaced(["--window"], "the paper method", "paper to --method"))
    '--window applies to the paper method: add paper to --method, or leave it out'
    """
    verb, them = ("applies", "it") if len(stray) == 1 else ("apply", "them")
    return ConfigError(f"{', '.join(stray)} {verb} to {owner}: add {fix}, or leave {them} out")


def typed_flags(ctx: click.Context) -> dict[str, str]:
    """The options typed on the command line: parameter name -> the flag the user knows it by."""
    typed = typed_options(ctx)
    return {str(p.name): max(p.opts, key=len) for p in ctx.command.params if p.name in typed and p.opts}


def given(ctx: click.Context, names: tuple[str, ...]) -> list[str]:
    """The options among ``names`` that were typed on the command line, as ``--option-names``."""
    flags = typed_flags(ctx)
    return [flags[n] for n in names if n in flags]


# ------------------------------------------------------------------ options of more than one localize command
# (each declared once: osmseg.cli.options; a flag's second declaration is an error at import)

P = declare("--p", type=click.FloatRange(0, 1, min_open=True),
            help="Paper method: candidates grow by the cliques sharing at least this fraction of a relevant clique's "
                 "landmarks (covisibility).")
TOP_K = declare("--top-k", type=click.IntRange(min=1), help="Locations reported, best first.")
WINDOW = declare("--window", dest="window_text", metavar="PIXELS|auto",
                 help="Paper method: the aerial covisibility window in pixels, or auto: mean + 5 sd of "
                      "nearest-neighbour distances between landmarks.")
LANDMARK_MODE = declare("--landmark-mode", type=click.Choice(["centroid", "grid", "component"]),
                        help="Landmarks of a mask: component centroids, grid points (every --grid-stride pixels), or "
                             "whole components.")
MIN_SIZE = declare("--min-size", type=click.IntRange(min=0),
                   help="Mask components smaller than this (pixels) are no landmarks.")
GRID_STRIDE = declare("--grid-stride", type=click.IntRange(min=1), help="Spacing of --landmark-mode grid (pixels).")
FOV = declare("--fov", dest="fov_deg", type=click.FloatRange(10, 360),
              help="Horizontal field of view of the ground view in degrees: 360 for a panorama, 60-120 for a photo.")
CAMERA_HEIGHT = declare("--camera-height", dest="camera_height_text", metavar="METRES|unknown",
                        help="Metres of the ground camera above the ground, or 'unknown' to try 1.5 to 2.5 m in 0.25 m "
                             "steps (a hand-held camera to a car's), each place with the height that fits it.")
AERIAL_RESOLUTION = declare("--aerial-resolution", metavar="METRES", type=click.FloatRange(min=0, min_open=True),
                            help="Ground resolution of the aerial side in metres per pixel, for errors in metres")
AERIAL_SIZE = declare("--aerial-size", metavar="WIDTHxHEIGHT",
                      help="Size of the aerial image of a landmark file, when no image lies beside it, e.g. 750x750.")
GROUND_SIZE = declare("--ground-size", metavar="WIDTHxHEIGHT",
                      help="Size of the ground image of a landmark file, when no image lies beside it, e.g. 1232x224.")
CONVENTIONS = declare("--conventions", type=click.Choice(["osmseg", "authors"]),
                      help="Paper method: osmseg's (windows from pixel 0, each candidate at the mean of its windows, "
                           "ties by the clique's own likelihood) or the authors' MATLAB demo's (windows from pixel 1, "
                           "the first window, ties to the first clique in lexicographic order), to reproduce their "
                           "figures.")
METHOD = declare("--method", type=click.Choice(["profile", "paper"]),
                 help="profile: angular profiles on a dense grid (docs/localization.md), which also gives the heading "
                      "and a confidence, and needs the aerial resolution; paper: landmark-graph matching (Verde et "
                      "al. 2020).")
HEADING = declare("--heading", dest="heading_text", metavar="DEGREES|unknown",
                  help="Profile method: compass azimuth (degrees) of the ground image's centre column, or 'unknown' "
                       "to search it. CVUSA-style panoramas are north-aligned: 0.")
LANDMARKS = declare("--landmarks", dest="landmark_dict", metavar="NAME",
                    help="Landmark class dictionary (data_manifests/landmarks-NAME.toml).")
AERIAL_LANDMARKS = declare("--aerial-landmarks", dest="aerial_classes", metavar="NAME",
                           help="Landmark class dictionary of the aerial side (data_manifests/landmarks-NAME.toml).")
GROUND_LANDMARKS = declare("--ground-landmarks", dest="ground_classes", metavar="NAME",
                           help="Landmark class dictionary of the ground side (data_manifests/landmarks-NAME.toml).")
