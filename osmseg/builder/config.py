"""What decides a build, as frozen values: :class:`BuildConfig`, :class:`Shard` and the sampling box.

Kept apart from :mod:`osmseg.builder.run` so that the code run for one slot (:mod:`osmseg.builder.slots`),
the worker processes (:mod:`osmseg.builder.workers`) and the build itself share one definition
without importing each other. Imports: osmseg core below it (places, grid, filters, redact,
sampling, processes, errors).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, cast

from osmseg.builder.filters import FilterConfig
from osmseg.grid import TILE_SIZE, LngLatBBox, ground_resolution, pad_bbox
from osmseg.places import Area, normalise_name
from osmseg.redact import redact
from osmseg.runtime.processes import available_cores
from osmseg.runtime.shard import Shard

__all__ = ["DEFAULT_ZOOM", "SAMPLE_TILES", "BuildConfig", "Shard", "available_cores", "sampling_box"]

#: Zoom 18: ~0.6 m/px at the equator, ~0.37 m/px in Berlin; a 5x5 sample spans ~470 m there.
#: Fine enough that footways, single trees and small buildings are several pixels wide, coarse
#: enough that Bing/Esri cover every preset area at this level.
DEFAULT_ZOOM = 18
#: Sample sizes in tiles per side (``--sample-tiles``): odd, so that the centre tile is the middle one
#: (:func:`osmseg.grid.sample_grid`); 5 (1280 px) is the dissertation's.
SAMPLE_TILES = (1, 3, 5, 7, 9)


@dataclass(frozen=True)
class BuildConfig:
    """Everything that decides a build. Passed explicitly; no global settings.

    ``workers`` (how many processes build samples; 0 = every available core) and the other
    options outside :meth:`identity` change how fast a dataset is made, never its bytes.
    """

    out_dir: Path
    area: Area
    imagery: str
    osm: str = "api"
    samples: int = 30
    seed: int = 0
    zoom: int = DEFAULT_ZOOM
    grid_size: int = 5
    classes: str = "classes13.toml"
    image_format: str = "png"
    filters: FilterConfig = field(default_factory=FilterConfig)
    max_tries: int = 10
    osm_padding_m: float = 60.0
    cache_dir: Path | None = None
    offline: bool = False
    shard: Shard | None = None
    zip: bool = False
    name_prefix: str | None = None
    http_timeout: float = 30.0  # seconds to connect, and between bytes read
    http_retries: int = 5  # --retries: further attempts of a request that failed in a way worth retrying
    http_retry_delay: float = 0.5  # --retry-delay: seconds before the first retry; doubles with each
    cassette: Path | None = None  # --record/--replay FILE
    cassette_mode: str = "replay"
    no_overlap: bool = False  # --no-overlap: every attempt gets its own tile block (osmseg.builder.sampling)
    workers: int = 0  # --workers N: processes building samples; 0 = every available core
    tile_size: int | None = None  # --tile-size: px of a tile server's tiles (None: as the provider says)

    def identity(self) -> dict[str, Any]:
        """What decides the dataset's content; recorded in the state and the manifest.

        Returned in its JSON form (tuples as lists), so the identity a rerun computes equals,
        value for value, the one read back from ``.osmseg-build/config.json``.
        """
        return cast("dict[str, Any]", json.loads(json.dumps(self._identity(), allow_nan=False)))

    def _identity(self) -> dict[str, Any]:
        return {
            "area": {k: v for k, v in asdict(self.area).items() if v is not None},
            "imagery": redact(self.imagery),  # a literal key in a template never reaches disk
            "osm": redact(self.osm),
            "samples": self.samples,
            "seed": self.seed,
            "zoom": self.zoom,
            "grid_size": self.grid_size,
            "classes": self.classes,
            "image_format": self.image_format,
            "filters": self.filters.to_dict(),
            "max_tries": self.max_tries,
            "osm_padding_m": self.osm_padding_m,
            # only when asked, so that a folder built before the option existed still resumes
            **({"sampling": "blocks (--no-overlap)"} if self.no_overlap else {}),
            **({"tile_size": self.tile_size} if self.tile_size is not None else {}),
        }

    def my_slots(self) -> list[int]:
        """The slots this process builds: all of them, or this shard's share."""
        return [s for s in range(self.samples) if self.shard is None or self.shard.owns(s)]

    @property
    def prefix(self) -> str:
        return self.name_prefix or normalise_name(self.area.name).replace(" ", "-") or "sample"

    def worker_count(self, todo: int) -> int:
        """Processes to run for ``todo`` unfinished slots: ``workers`` (every available core when
        0), never more than there are slots, and one when a cassette is recorded (it is one file
        that sees every request, written by one process).

        >>> from osmseg.places import Area
        >>> c = BuildConfig(Path("x"), Area("a", 0, 0, 1.0), "xyz:file:///t/{z}/{x}/{y}.png", workers=8)
        >>> c.worker_count(3), c.worker_count(100), c.worker_count(0)
        (3, 8, 1)
        """
        if self.cassette is not None and self.cassette_mode == "record":
            return 1
        wanted = self.workers or available_cores()
        return max(1, min(wanted, todo))


def sampling_box(config: BuildConfig) -> LngLatBBox:
    """A box holding every grid (plus OSM padding) that any attempt of the build can draw."""
    a = config.area
    box = a.bbox or pad_bbox(LngLatBBox(a.lon, a.lat, a.lon, a.lat), (a.radius_km or 0.0) * 1000.0)
    tile_m = TILE_SIZE * ground_resolution(a.lat, config.zoom)
    return pad_bbox(box, (config.grid_size / 2 + 1) * tile_m + config.osm_padding_m)
