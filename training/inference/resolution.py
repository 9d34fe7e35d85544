"""The ground resolution of the images ``osmseg predict`` and ``osmseg eval`` read, against the model's.

A checkpoint records the ground pixel size of its training data (``spec.resolution_m``). An
input's is its GeoTIFF's (:func:`input_resolution`, any CRS), or, for a PNG or JPEG of an
``osmseg build`` dataset, its sample's in the manifest (:class:`GroundPlace`: ``ground_resolution_m``
and ``bounds_3857``), which places the image as a GeoTIFF of that place would be.
``--resolution`` (:func:`target_resolution`) resamples inputs by :func:`resolution_factor`;
:func:`warn_resolutions` says once, for all the inputs of a command, which are far from the
training data's resolution with nothing resampling them, or cannot be resampled. Imports:
osmseg core.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import rasterio
from affine import Affine
from rasterio.crs import CRS
from rasterio.errors import NotGeoreferencedWarning, RasterioError
from rasterio.transform import from_bounds

from osmseg.errors import ConfigError
from osmseg.grid import ground_pixel_size, resolution_mismatch
from osmseg.output.manifest import manifest_path, read_manifest

if TYPE_CHECKING:
    from training.models.spec import ModelSpec

logger = logging.getLogger(__name__)

WEB_MERCATOR = CRS.from_epsg(3857)  # the CRS of a dataset's samples (manifest.json bounds_3857)
#: image files without georeferencing (read by PIL)
PLAIN_SUFFIXES = (".png", ".jpg", ".jpeg")


def input_resolution(src: str | Path) -> float | None:
    """Ground metres per pixel of an image file (geodesic, any CRS); None without georeferencing."""
    path = Path(src)
    if path.suffix.lower() in PLAIN_SUFFIXES:
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(path) as ds:
                return ground_pixel_size(ds.crs, ds.transform, ds.width, ds.height) if ds.crs else None
    except RasterioError:
        return None


def resolution_factor(pixel_m: float | None, target_m: float | None) -> float:
    """How much to enlarge an image with ``pixel_m`` pixels so they become ``target_m`` (1.0: leave it).

    >>> resolution_factor(0.6, 0.3), resolution_factor(None, 0.3), resolution_factor(0.3, 0.31)
    (2.0, 1.0, 1.0)
    """
    if pixel_m is None or target_m is None:
        return 1.0
    factor = pixel_m / target_m
    return 1.0 if abs(factor - 1.0) < 0.05 else factor


def target_resolution(asked: float | str | None, spec: ModelSpec) -> float | None:
    """``--resolution``'s metres: a number, ``"model"`` (the training data's, from the checkpoint) or None."""
    if asked is None or isinstance(asked, (int, float)):
        return None if asked is None else float(asked)
    if str(asked).strip().lower() == "model":
        if spec.resolution_m is None:
            raise ConfigError("--resolution model: this checkpoint does not record the ground resolution of its "
                              "training data; give it in metres, e.g. --resolution 0.3")
        return spec.resolution_m
    try:
        value = float(asked)
    except ValueError:
        raise ConfigError(f"--resolution {asked!r}: give metres per pixel (e.g. 0.3) or 'model'") from None
    if not value > 0:
        raise ConfigError(f"--resolution {asked!r}: must be > 0 metres per pixel")
    return value


@dataclass(frozen=True)
class GroundPlace:
    """Where an image lies when its file does not say (a PNG or JPEG of a dataset): its ground pixel
    size in metres and, when known, its Web Mercator bounds (``osmseg build``'s manifest records both
    per sample: ``ground_resolution_m``, ``bounds_3857``)."""

    pixel_m: float
    bounds_3857: tuple[float, float, float, float] | None = None

    def georef(self, width: int, height: int) -> dict[str, Any]:
        """The image's georeferencing: its bounds on its pixel grid; without bounds, squares of
        ``pixel_m`` on the equator, where Web Mercator metres are ground metres (only the scale
        matters for resampling).

        >>> GroundPlace(0.5).georef(4, 2)["transform"].a, GroundPlace(0.5, (0.0, 0.0, 8.0, 2.0)).georef(4, 2)["transform"].a
        (0.5, 2.0)
        """
        if self.bounds_3857 is not None:
            return {"crs": WEB_MERCATOR, "transform": from_bounds(*self.bounds_3857, width, height)}
        return {"crs": WEB_MERCATOR, "transform": Affine(self.pixel_m, 0.0, 0.0, 0.0, -self.pixel_m, 0.0)}


def dataset_places(dataset: Path | None) -> dict[str, GroundPlace]:
    """Where each sample of an ``osmseg build`` dataset lies, by name, from its manifest
    (``ground_resolution_m``, and ``bounds_3857`` when recorded); empty for a folder without one."""
    if dataset is None or not manifest_path(dataset).is_file():
        return {}
    places = {}
    for sample in read_manifest(dataset).samples:
        if sample.ground_resolution_m is None:
            continue  # a sample without its place is predicted at its own pixel size, and said so
        places[sample.name] = GroundPlace(float(sample.ground_resolution_m), sample.bounds())
    return places


def input_places(inputs: Sequence[Path]) -> dict[Path, GroundPlace]:
    """The places of the inputs that are images of an ``osmseg build`` dataset (``DATASET/images/NAME.*``
    beside ``DATASET/manifest.json``), from its manifest (:func:`dataset_places`)."""
    found: dict[Path, GroundPlace] = {}
    datasets: dict[Path, dict[str, GroundPlace]] = {}
    for src in inputs:
        root = Path(src).parent.parent
        if Path(src).parent.name != "images":
            continue
        if root not in datasets:
            datasets[root] = dataset_places(root)
        if (place := datasets[root].get(Path(src).stem)) is not None:
            found[Path(src)] = place
    return found


def warn_resolutions(inputs: Sequence[tuple[str, float | None]], spec: ModelSpec, asked: float | None) -> None:
    """Say once, for all ``inputs`` (name, ground pixel size or None when unknown), what nothing
    else would: without ``--resolution`` (``asked`` None), the inputs whose pixels are far (more than
    :data:`~osmseg.grid.RESOLUTION_MISMATCH`, 1.5x, the threshold ``osmseg build`` warns at too) from
    the training data's, naming ``--resolution model``; with it, the inputs it cannot resample
    because nothing says their ground pixel size. One line each, however many inputs."""
    trained = spec.resolution_m
    if asked is not None:
        unknown = [name for name, pixel_m in inputs if pixel_m is None]
        if len(unknown) == 1:
            logger.warning("%s is not georeferenced: --resolution cannot apply, predicted at its own pixel size",
                           unknown[0])
        elif unknown:
            which = (f"all {len(unknown)} images" if len(unknown) == len(inputs)
                     else f"{len(unknown)} of the {len(inputs)} images")
            logger.warning("%s (%s) are not georeferenced and no dataset manifest gives their ground resolution: "
                           "--resolution cannot apply, they are predicted at their own pixel size", which,
                           _some(unknown))
        return
    if trained is None:
        return
    far = [(name, pixel_m) for name, pixel_m in inputs if pixel_m is not None and resolution_mismatch(pixel_m, trained)]
    if not far:
        return
    sizes = sorted(pixel_m for _, pixel_m in far)
    median = sizes[len(sizes) // 2]
    looks = ("smaller" if all(p > trained for p in sizes) else "larger" if all(p < trained for p in sizes)
             else "smaller or larger")
    if len(far) == 1:
        logger.warning("%s has %.3g m pixels but the model was trained on %.3g m pixels: objects look %.1fx %s "
                       "than it learnt them; pass --resolution model to resample the input first", far[0][0],
                       median, trained, resolution_mismatch(median, trained), looks)
        return
    span = f"{sizes[0]:.3g}" if f"{sizes[0]:.3g}" == f"{sizes[-1]:.3g}" else f"{sizes[0]:.3g}-{sizes[-1]:.3g}"
    which = (f"all {len(far)} images" if len(far) == len(inputs)
             else f"{len(far)} of the {len(inputs)} images ({_some([name for name, _ in far])})")
    logger.warning("%s have %s m pixels but the model was trained on %.3g m pixels: objects look about %.1fx %s "
                   "than it learnt them; pass --resolution model to resample the inputs first", which, span, trained,
                   resolution_mismatch(median, trained), looks)


def known_resolution(src: Path, place: GroundPlace | None) -> float | None:
    """An input's ground pixel size: its file's (a GeoTIFF's), else its ``place``'s, else None."""
    own = input_resolution(src)
    return own if own is not None or place is None else place.pixel_m


def _some(names: Sequence[str], shown: int = 2) -> str:
    """The first ``shown`` of ``names``, and how many more.

    >>> _some(["a", "b", "c", "d"]), _some(["a"])
    ('a, b and 2 more', 'a')
    """
    more = len(names) - shown
    return ", ".join(names[:shown]) + (f" and {more} more" if more > 0 else "")
