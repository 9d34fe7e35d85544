"""Where in a whole region was a ground view taken? The profile method over OpenStreetMap alone.

An analyst holds a photo and a district, not an aerial image centred on the answer. The
district's OpenStreetMap is drawn by the builder's own reader and rasteriser
(:func:`osmseg.osm.features.read_features`, :func:`osmseg.rasterize.rasterize`) into
overlapping **blocks** of ``size`` x ``size`` Web Mercator tiles at ``zoom`` (no imagery
needed), every block is searched by the profile method (:mod:`localization.search`), and the
candidates are ranked across blocks in degrees:

* Blocks step by ``size - 2`` tiles, so neighbours share a two-tile band. A block keeps only
  the candidates in its **core** (all but its outer ring of tiles), where every position sees
  at least one tile of map around it (about 75 m at zoom 18 at 60° N, more than the profile
  method's 60 m range): each place is answered by exactly one block, with its whole
  surroundings drawn.
* The answers are the candidates best first (the profile score: the share of the query's
  profile the map agrees with, comparable across blocks), each with its confidence (its kappa
  against its block's chance agreement, :mod:`localization.search`). Beside the best answer, the **best distinct
  alternative**: the best candidate at least ``distinct_m`` from it. The margin between their
  scores says how much better the answer fits than any other place (a look-alike has a small
  margin).

Everything is a function of the region, the query and the settings: no random choice.
Imports: osmseg core, localization.profile, .pipeline, .landmarks, .result.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mercantile
import numpy as np

from localization.landmarks import LandmarkClasses
from localization.pipeline import profile_index, profile_query, run_profile
from localization.profile import Camera, SemanticMap, semantic_map
from localization.search import ProfileConfig, class_prior, grid_positions
from osmseg.classes import ClassTable
from osmseg.errors import ConfigError
from osmseg.grid import SampleGrid, ground_resolution
from osmseg.osm.features import read_features
from osmseg.progress import Progress, track
from osmseg.rasterize import rasterize

__all__ = ["RegionConfig", "Answer", "RegionResult", "region_blocks", "search_region", "distance_m", "pixel_lonlat"]


@dataclass(frozen=True)
class RegionConfig:
    """The region (``bbox`` west, south, east, north in degrees) and how it is searched."""

    bbox: tuple[float, float, float, float]
    zoom: int = 18
    size: int = 5                 # tiles per block side (odd, >= 3)
    top_k: int = 5                # answers reported
    distinct_m: float = 50.0      # the best distinct alternative is at least this far from the answer
    per_block: int = 200          # candidates each block passes on (spaced by the profile method's grid)

    def __post_init__(self) -> None:
        w, s, e, n = self.bbox
        if not (-180 <= w < e <= 180 and -85.05 <= s < n <= 85.05):
            raise ConfigError(f"--bbox must be west,south,east,north in degrees with west < east and south < north, "
                              f"got {','.join(f'{v:g}' for v in self.bbox)}")
        if self.size < 3 or self.size % 2 == 0:
            raise ConfigError(f"block size must be an odd number of tiles >= 3, got {self.size}")
        if not 14 <= self.zoom <= 21:
            raise ConfigError(f"zoom must be 14-21 (ground pixels of 10 m to 7 cm), got {self.zoom}")


@dataclass(frozen=True)
class Answer:
    """A place the query may have been taken: degrees, the profile score, the block's confidence."""

    lon: float
    lat: float
    score: float
    confidence: float | None
    heading_deg: float | None

    def to_dict(self) -> dict[str, Any]:
        return {"lon": round(self.lon, 7), "lat": round(self.lat, 7), "score": round(self.score, 5),
                "confidence": None if self.confidence is None else round(self.confidence, 4),
                "heading_deg": None if self.heading_deg is None else round(self.heading_deg, 2)}


@dataclass(frozen=True)
class RegionResult:
    """The answers best first, the best distinct alternative and the margin between them."""

    answers: tuple[Answer, ...]
    alternative: Answer | None
    blocks: int
    config: RegionConfig
    overview: np.ndarray | None = None     # the region's drawn classes, every OVERVIEW_STEP-th pixel of the cores
    overview_bounds: tuple[float, float, float, float] | None = None  # its west, south, east, north in degrees

    @property
    def best(self) -> Answer | None:
        return self.answers[0] if self.answers else None

    @property
    def margin(self) -> float | None:
        """Score of the answer minus that of the best distinct alternative."""
        if self.best is None or self.alternative is None:
            return None
        return self.best.score - self.alternative.score

    def to_geojson(self) -> dict[str, Any]:
        """A FeatureCollection: the answers (rank 1 first), then the alternative."""
        features = [_point(a, {"rank": i + 1, "role": "answer" if i == 0 else "candidate"})
                    for i, a in enumerate(self.answers)]
        if self.alternative is not None:
            features.append(_point(self.alternative, {"role": "best distinct alternative",
                                                      "distance_m": round(distance_m(self.best, self.alternative), 1)
                                                      if self.best else None}))
        margin = self.margin
        return {"type": "FeatureCollection", "features": features,
                "properties": {"bbox": list(self.config.bbox), "zoom": self.config.zoom, "blocks": self.blocks,
                               "distinct_m": self.config.distinct_m,
                               "margin": None if margin is None else round(margin, 5)}}


def _point(a: Answer, extra: dict[str, Any]) -> dict[str, Any]:
    return {"type": "Feature", "geometry": {"type": "Point", "coordinates": [round(a.lon, 7), round(a.lat, 7)]},
            "properties": {**a.to_dict(), **extra}}


def distance_m(a: Answer | tuple[float, float], b: Answer | tuple[float, float]) -> float:
    """Metres between two places (equirectangular: exact enough within a district).

    >>> round(distance_m((0.0, 0.0), (0.001, 0.0)), 1)
    111.3
    """
    lon1, lat1 = (a.lon, a.lat) if isinstance(a, Answer) else a
    lon2, lat2 = (b.lon, b.lat) if isinstance(b, Answer) else b
    k = math.cos(math.radians((lat1 + lat2) / 2))
    return math.hypot((lon2 - lon1) * k, lat2 - lat1) * 111_319.49


def region_blocks(config: RegionConfig) -> list[tuple[SampleGrid, frozenset[tuple[int, int]]]]:
    """The blocks that cover ``config.bbox``, each with the tiles of its core (see the module docstring).

    >>> blocks = region_blocks(RegionConfig((26.94, 60.53, 26.95, 60.535), zoom=18))
    >>> len(blocks), len(blocks[0][0].tiles), len(blocks[0][1])
    (9, 25, 9)
    >>> inside = {(t.x, t.y) for t in mercantile.tiles(26.94, 60.53, 26.95, 60.535, 18)}
    >>> cores = [c for _, core in blocks for c in core]
    >>> inside <= set(cores), len(cores) == len(set(cores))
    (True, True)
    """
    w, s, e, n = config.bbox
    nw, se = mercantile.tile(w, n, config.zoom), mercantile.tile(e, s, config.zoom)
    step, size = config.size - 2, config.size
    out = []
    for y0 in range(nw.y - 1, se.y, step):  # cores tile [nw, se] without a gap
        for x0 in range(nw.x - 1, se.x, step):
            tiles = tuple(mercantile.Tile(x0 + dx, y0 + dy, config.zoom) for dy in range(size) for dx in range(size))
            b = mercantile.bounds(tiles[len(tiles) // 2])
            lon, lat = (b.west + b.east) / 2, (b.south + b.north) / 2
            grid = SampleGrid(lon=lon, lat=lat, zoom=config.zoom, tiles=tiles, size=size)
            core = frozenset((x0 + dx, y0 + dy) for dy in range(1, size - 1) for dx in range(1, size - 1))
            out.append((grid, core))
    return out


def _block_masks(osm: Sequence[Path | str], blocks: Sequence[tuple[SampleGrid, frozenset[tuple[int, int]]]],
                 table: ClassTable) -> Iterator[np.ndarray]:
    for grid, _ in blocks:
        yield rasterize(read_features(list(osm), grid, table), grid, table)


def search_region(query: SemanticMap, camera: Camera, osm: Sequence[Path | str], table: ClassTable,
                  classes: LandmarkClasses, config: RegionConfig, profile: ProfileConfig = ProfileConfig(),
                  progress: Progress | None = None) -> RegionResult:
    """Search every block of the region for ``query`` (its semantic map, seen by ``camera``).

    Two passes. The first scores every block on the profile method's coarse grid alone (no
    refinement), which leaves candidates spread over the whole block, so that places far
    apart all compete: this is where the best distinct alternative comes from. The second
    searches again, coarse to fine, the blocks that hold the best ``top_k`` coarse places, and
    their refined candidates are the answers.
    """
    blocks = region_blocks(config)
    coarse = dataclasses.replace(profile, top_k=config.per_block, min_confidence=0.0, levels=0)
    fine = dataclasses.replace(profile, top_k=config.per_block, min_confidence=0.0)
    q = profile_query(query, camera, fine)
    packed: list[bytes] = []  # each block's mask, deflated: memory stays small whatever the region's size
    priors = []
    overview = _Overview(blocks)
    for (grid, core), mask in track(zip(blocks, _block_masks(osm, blocks, table)), progress, "drawing blocks",
                                    total=len(blocks), unit="block"):
        packed.append(zlib.compress(np.ascontiguousarray(mask, np.uint8).tobytes(), 1))
        overview.paste(grid, mask)
        index = _index(mask, grid, table, classes, coarse)
        priors.append(class_prior(index, q, grid_positions(index.shape, index.grid_m / index.resolution_m)))
    prior = np.mean(priors, axis=0)  # one yardstick for every block: the region's class frequencies

    def index_of(b: int) -> Any:
        grid = blocks[b][0]
        mask = np.frombuffer(zlib.decompress(packed[b]), np.uint8).reshape(grid.height, grid.width)
        return _index(mask, grid, table, classes, coarse)

    found: list[tuple[Answer, int]] = []
    for b, (grid, core) in enumerate(track(blocks, progress, "searching blocks", unit="block")):
        found += [(a, b) for a in _in_core(run_profile(coarse, index_of(b), q, prior=prior), grid, core, config.zoom)]
    found.sort(key=lambda ab: (-ab[0].score, ab[0].lat, ab[0].lon))  # the profile score, as within one block
    refined: list[Answer] = []
    for b in dict.fromkeys(b for _, b in found[:config.top_k]):  # the blocks of the best places, best first
        grid, core = blocks[b]
        refined += _in_core(run_profile(fine, index_of(b), q, prior=prior), grid, core, config.zoom)
    refined.sort(key=lambda a: (-a.score, a.lat, a.lon))
    answers = _spaced(refined, config.top_k, min_m=1.0)
    everything = sorted([*refined, *(a for a, _ in found)], key=lambda a: (-a.score, a.lat, a.lon))
    alternative = next((a for a in everything if answers and distance_m(answers[0], a) >= config.distinct_m), None)
    return RegionResult(tuple(answers), alternative, len(blocks), config, overview.pixels, overview.bounds)


#: the overview keeps every OVERVIEW_STEP-th pixel of each block's core (256 px tiles -> 32 px)
OVERVIEW_STEP = 8


class _Overview:
    """A small mosaic of the blocks' cores (every :data:`OVERVIEW_STEP`-th pixel) for the map picture."""

    def __init__(self, blocks: Sequence[tuple[SampleGrid, frozenset[tuple[int, int]]]]) -> None:
        cores = [t for _, core in blocks for t in core]
        self.x0, self.y0 = min(x for x, _ in cores), min(y for _, y in cores)
        self.x1, self.y1 = max(x for x, _ in cores), max(y for _, y in cores)
        self.zoom = blocks[0][0].zoom
        side = 256 // OVERVIEW_STEP
        self.pixels = np.zeros(((self.y1 - self.y0 + 1) * side, (self.x1 - self.x0 + 1) * side), np.uint8)
        self.side = side
        self.cores = {id(grid): core for grid, core in blocks}

    def paste(self, grid: SampleGrid, mask: np.ndarray) -> None:
        small = mask[OVERVIEW_STEP // 2::OVERVIEW_STEP, OVERVIEW_STEP // 2::OVERVIEW_STEP]
        first = grid.tiles[0]
        for x, y in self.cores[id(grid)]:
            r, c = (y - first.y) * self.side, (x - first.x) * self.side
            R, C = (y - self.y0) * self.side, (x - self.x0) * self.side
            self.pixels[R:R + self.side, C:C + self.side] = small[r:r + self.side, c:c + self.side]

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        nw = mercantile.bounds(self.x0, self.y0, self.zoom)
        se = mercantile.bounds(self.x1, self.y1, self.zoom)
        return nw.west, se.south, se.east, nw.north


def _index(mask: np.ndarray, grid: SampleGrid, table: ClassTable, classes: LandmarkClasses,
           config: ProfileConfig) -> Any:
    """The profile method's aerial side of one block's mask."""
    return profile_index(semantic_map(mask, table, classes), ground_resolution(grid.lat, grid.zoom), config)


def _in_core(loc: Any, grid: SampleGrid, core: frozenset[tuple[int, int]], zoom: int) -> list[Answer]:
    """A block's candidates (``loc``: a profile-method :class:`~localization.result.Localization`)
    that lie in its core, each with its kappa against the block's chance agreement."""
    if loc.unanswered:
        return []
    chance = loc.chance if loc.chance is not None else 0.0
    out = []
    for x, y, score in loc.top_k:
        b = grid.xy_bounds
        lon, lat = pixel_lonlat((b.left, b.bottom, b.right, b.top), (grid.height, grid.width), (x, y))
        tile = mercantile.tile(lon, lat, zoom)
        if (tile.x, tile.y) in core:
            out.append(Answer(lon, lat, score, (score - chance) / (1 - chance) if chance < 1 else 0.0, loc.heading_deg))
    return out


def _spaced(found: Sequence[Answer], k: int, min_m: float) -> list[Answer]:
    """The first ``k`` answers no two of which are within ``min_m`` (two blocks' copies of one place)."""
    out: list[Answer] = []
    for a in found:
        if all(distance_m(a, b) >= min_m for b in out):
            out.append(a)
            if len(out) == k:
                break
    return out


def pixel_lonlat(bounds: tuple[float, float, float, float], shape: tuple[int, int],
                 xy: tuple[float, float]) -> tuple[float, float]:
    """Longitude and latitude of pixel ``(x, y)`` (centres at integers) of a ``shape`` mask whose
    Web Mercator ``bounds`` are (left, bottom, right, top).

    >>> b = (*mercantile.xy(0.0, -0.001), *mercantile.xy(0.002, 0.001))
    >>> [round(v, 6) for v in pixel_lonlat(b, (200, 200), (99.5, 99.5))]
    [0.001, 0.0]
    """
    left, bottom, right, top = bounds
    height, width = shape
    x = left + (xy[0] + 0.5) * (right - left) / width
    y = top - (xy[1] + 0.5) * (top - bottom) / height
    lon, lat = mercantile.lnglat(x, y)
    return lon, lat


# --------------------------------------------------------------------------- files in, files out


@dataclass(frozen=True)
class RegionRequest:
    """``osmseg localize --osm FILE --bbox W,S,E,N``'s inputs: the query file and the region's OSM."""

    ground: Path
    ground_options: Any  # localization.inputs.SideOptions
    osm: tuple[Path, ...]
    table: str = "classes13.toml"        # the classes the OSM is drawn in
    aerial_classes: str = "aerial13"     # their landmark dictionary
    fov_deg: float = 360.0
    camera_height_m: float = 2.0
    truth: tuple[float, float] | None = None  # lon, lat


def localize_region(request: RegionRequest, config: RegionConfig, profile: ProfileConfig = ProfileConfig(),
                    out_dir: Path | None = None, progress: Progress | None = None) -> RegionResult:
    """Read the query, search the region, and (with ``out_dir``) write ``region.geojson``."""
    import json

    from localization.inputs import load_side
    from localization.landmarks import load_landmark_classes
    from localization.profile import check_view_shape
    from osmseg.classes import load_class_table
    from osmseg.output.atomic import atomic_write_text

    for path in request.osm:
        if not Path(path).is_file():
            raise ConfigError(f"--osm {path} is not a file: give the region's OSM extract (.osm, .osm.pbf)")
    ground = load_side(request.ground, request.ground_options)
    if ground.semantic is None:
        raise ConfigError(f"--ground {request.ground.name}: region search needs the query as a label mask "
                          "(or an RGB image with --ground-checkpoint), not a landmark file")
    g = ground.landmarks
    check_view_shape(g.width, g.height, request.fov_deg, f"--ground {request.ground.name}",
                     "give a panorama, or a photo with its field of view (--fov DEGREES)")
    camera = Camera(g.width, g.height, hfov_deg=request.fov_deg, camera_height_m=request.camera_height_m)
    result = search_region(ground.semantic, camera, request.osm, load_class_table(request.table),
                           load_landmark_classes(request.aerial_classes), config, profile, progress)
    if out_dir is not None:
        doc = result.to_geojson()
        if request.truth is not None and result.best is not None:
            doc["properties"]["truth"] = {"lon": request.truth[0], "lat": request.truth[1],
                                          "error_m": round(distance_m(result.best, request.truth), 2)}
        atomic_write_text(Path(out_dir) / "region.geojson", json.dumps(doc, indent=2) + "\n")
        if importlib.util.find_spec("matplotlib") is not None:  # the picture is optional, the answers are not
            from localization.figures import region_png

            error = (distance_m(result.best, request.truth) if request.truth is not None and result.best is not None
                     else None)
            region_png(Path(out_dir) / "region.png", result, load_class_table(request.table), request.truth, error)
    return result
