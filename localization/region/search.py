"""Where in a whole region was a ground view taken? The profile method over OpenStreetMap alone.

An analyst holds a photo and a district, not an aerial image centred on the answer. The
district's OpenStreetMap is drawn by the builder's own reader and rasteriser
(:func:`osmseg.osm.features.read_features`, :func:`osmseg.rasterize.rasterize`) into
overlapping **blocks** of ``size`` x ``size`` Web Mercator tiles at ``zoom`` (no imagery
needed), every block is searched by the profile method (:mod:`localization.profile.search`), and the
candidates are ranked across blocks in degrees:

* Blocks step by ``size - 2`` tiles, so neighbours share a two-tile band. A block keeps only
  the candidates in its **core** (all but its outer ring of tiles), where every position sees
  at least one tile of map around it (about 75 m at zoom 18 at 60° N, more than the profile
  method's 60 m range): each place is answered by exactly one block, with its whole
  surroundings drawn. So only the core (and one coarse cell around it) is searched: its rays read
  the whole block, and the outer ring's positions, a neighbour's core, are that neighbour's. (The open horizon's 75 m, ``--vista-weight``, can reach past a block's
  edge from the rim of its core, farther north; such a ray is credited with chance, as a ray
  leaving an aerial image is.)
* Every block is scored against the same class frequencies, those of up to 16 blocks spread
  over the region (:func:`prior_blocks`), so scores compare across blocks.
* The answers are the candidates best first (the profile score: the share of the query's
  profile the map agrees with), each with its kappa (against chance) and its **confidence**:
  the share of its lead over chance that no place at least ``distinct_m`` away reaches, as
  within one image (:mod:`localization.profile.search`). Beside the best answer, the **best distinct
  alternative** and the score margin between them: a look-alike place has a small margin and
  the answer a confidence near 0.
* **Is it from here at all?** Every block is also searched, on a grid twice as sparse, for two
  scrambled copies of the query (:mod:`localization.profile.null`): the best score they reach is
  the **null**, what the district gives any view with the query's contents. The answer's
  **lift** is how far the query's own best on the coarse grid rises above the null, as a share
  of its lead over chance, and the **verdict** is "not found here" below :data:`NULL_MIN_LIFT`,
  "not sure" below the confidence threshold, else "here" (docs/localization.md: how the
  threshold was chosen, on views of three real towns searched in each).
* A region is split between processes or machines by ``--shard K/N``: shard K searches the
  blocks ``b`` with ``b % N == K - 1`` (:func:`search_part`) and :func:`merge_parts` ranks
  what all shards found. A block's candidates depend on that block alone, so the answer is the
  same for any number of shards.

Everything is a function of the region, the query and the settings: no random choice.
Imports: osmseg core, localization.common (landmarks, views), the profile wing (method, profiles, search) and
localization.region.cache.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mercantile
import numpy as np

from localization.common.landmarks import LandmarkClasses
from localization.common.views import Camera, SemanticMap, semantic_map
from localization.profile.method import profile_index, profile_query, run_profile
from localization.profile.null import null_queries
from localization.profile.profiles import MASK_MIN_CONFIDENCE
from localization.profile.search import ProfileConfig, class_prior, grid_positions
from localization.region.cache import BlockMasks
from osmseg import units
from osmseg.classes import ClassTable
from osmseg.errors import ConfigError
from osmseg.grid import TILE_SIZE, SampleGrid, ground_resolution, pixel_lonlat
from osmseg.runtime.progress import Progress, track
from osmseg.runtime.shard import Shard

__all__ = ["RegionConfig", "Answer", "RegionResult", "RegionPart", "region_blocks", "prior_blocks", "search_part",
           "merge_parts", "search_region", "distance_m", "pixel_lonlat"]


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
    kappa: float | None = None
    chance: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"lon": round(self.lon, 7), "lat": round(self.lat, 7), "score": round(self.score, 5),
                "confidence": None if self.confidence is None else round(self.confidence, 4),
                "kappa": None if self.kappa is None else round(self.kappa, 4),
                "heading_deg": None if self.heading_deg is None else round(self.heading_deg, 2)}


@dataclass(frozen=True)
class RegionResult:
    """The answers best first, the best distinct alternative and the margin between them."""

    answers: tuple[Answer, ...]
    alternative: Answer | None
    blocks: int
    config: RegionConfig
    null_score: float | None = None        # the best score a scrambled copy of the query reaches (the null)
    coarse_score: float | None = None      # the query's own best on the same coarse grid, to compare with it
    overview: np.ndarray | None = None     # the region's drawn classes, every OVERVIEW_STEP-th pixel of the cores
    overview_bounds: tuple[float, float, float, float] | None = None  # its west, south, east, north in degrees

    @property
    def best(self) -> Answer | None:
        return self.answers[0] if self.answers else None

    @property
    def lift(self) -> float | None:
        """How far the query's best place rises above the null, as a share of its lead over
        chance: 1 when no scrambled copy fits anywhere better than chance, 0 or less when one
        fits some place as well as the query fits its best (nothing here is its place)."""
        best = self.best
        if best is None or best.chance is None or self.null_score is None or self.coarse_score is None:
            return None
        lead = self.coarse_score - best.chance
        return (self.coarse_score - self.null_score) / lead if lead > 0 else 0.0

    @property
    def verdict(self) -> str:
        """``here`` (the answer stands out from the district and from the null), ``not sure`` (a
        look-alike place fits nearly as well: confidence below the threshold) or ``not found
        here`` (the query fits the district no better than a scrambled copy of itself, or no
        place was found)."""
        best, lift = self.best, self.lift
        if best is None or (lift is not None and lift < NULL_MIN_LIFT):
            return NOT_HERE
        if best.confidence is not None and best.confidence < MASK_MIN_CONFIDENCE:
            return NOT_SURE
        return HERE

    def headline(self, error_m: float | None = None) -> str:
        """The verdict in one line, as the region's picture and map title it (``error_m``: the
        answer's distance from a known truth)."""
        line = (f"unanswered: no place of the region fits the query ({self.blocks} blocks searched)"
                if not self.answers else
                f"not found here: the view fits no better than scrambled ({self.blocks} blocks searched)"
                if self.verdict == NOT_HERE else f"{self.verdict}: {self.blocks} blocks searched")
        return line if error_m is None else f"{line}; answer {units.metres(error_m)} from the truth"

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
                               "sure": None if self.best is None or self.best.confidence is None
                               else self.best.confidence >= MASK_MIN_CONFIDENCE,
                               "verdict": self.verdict,
                               "null_score": None if self.null_score is None else round(self.null_score, 5),
                               "lift": None if self.lift is None else round(self.lift, 4),
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


#: the verdicts of a region search (:attr:`RegionResult.verdict`)
HERE, NOT_SURE, NOT_HERE = "here", "not sure", "not found here"
#: below this lift over the null (:attr:`RegionResult.lift`) the answer is "not found here"
NULL_MIN_LIFT = 0.12
#: the null's grid is this many times sparser than the coarse pass's
NULL_GRID = 2.0

#: At most this many blocks, spread evenly over the region, give its class frequencies.
PRIOR_BLOCKS = 16


def prior_blocks(n: int) -> list[int]:
    """The blocks whose class frequencies stand for the region's (the same for every shard).

    >>> prior_blocks(5), prior_blocks(40)[:4], len(prior_blocks(40))
    ([0, 1, 2, 3, 4], [0, 3, 5, 8], 16)
    """
    return sorted({int(round(v)) for v in np.linspace(0, n - 1, min(n, PRIOR_BLOCKS))})


@dataclass
class RegionPart:
    """What one shard found in its blocks: the coarse candidates of every block (with its
    number), the refined candidates of its best blocks, and each block's overview patch."""

    shard: Shard
    blocks: int
    coarse: list[tuple[Answer, int]]
    refined: dict[int, list[Answer]]
    patches: dict[int, np.ndarray]
    null: dict[int, float] = dataclasses.field(default_factory=dict)  # each block's best score of a scrambled query


def search_part(query: SemanticMap, camera: Camera, masks: BlockMasks, table: ClassTable, classes: LandmarkClasses,
                config: RegionConfig, profile: ProfileConfig = ProfileConfig(), shard: Shard = Shard(1, 1),
                progress: Progress | None = None) -> RegionPart:
    """Search the blocks ``shard`` owns (block ``b`` with ``b % N == K - 1``) for ``query``.

    Two passes, each over a block's core and one coarse cell around it (:func:`_core_box`). The
    first scores every block on the profile method's coarse grid alone (no refinement), which
    leaves candidates spread over the whole core, so that places far apart all compete: this is
    where the best distinct alternative comes from. The second
    searches again, coarse to fine, the blocks that hold this shard's best ``top_k`` coarse
    places. Every block is scored against the same class frequencies (those of
    :func:`prior_blocks`), so scores compare across blocks and shards, and a block's candidates
    depend on that block alone: :func:`merge_parts` of any number of shards gives the answer
    of one.
    """
    blocks = region_blocks(config)
    coarse = dataclasses.replace(profile, top_k=config.per_block, min_confidence=-1.0, min_kappa=-1.0, levels=0)
    fine = dataclasses.replace(profile, top_k=config.per_block, min_confidence=-1.0, min_kappa=-1.0)
    q = profile_query(query, camera, fine)
    # the null: scrambled copies of the query (each camera height's alike, so each position is scored
    # as the query is: with the height that fits it best; the copies' heights searched as one query's),
    # on a grid twice as sparse as the coarse one
    nulls = null_queries(q)
    sample = prior_blocks(len(blocks))
    mine = [b for b in range(len(blocks)) if shard.owns(b)]
    masks.prepare([*sample, *mine], progress)  # one pass over the OSM for every block this shard draws
    priors = []
    for b in track(sample, progress, "region's class frequencies", unit="block"):
        index = _index(masks.mask(b), blocks[b][0], table, classes, coarse)
        priors.append(class_prior(index, q, grid_positions(index.shape, index.grid_m / index.resolution_m)))
    prior = np.mean(priors, axis=0)
    found: list[tuple[Answer, int]] = []
    patches, null = {}, {}
    for b in track(mine, progress, "searching blocks", unit="block"):
        grid, core = blocks[b]
        mask = masks.mask(b)
        patches[b] = _core_patch(grid, core, mask)
        index = _index(mask, grid, table, classes, coarse)
        box = _core_box(grid, (coarse.coarse_m or index.grid_m) / index.resolution_m)
        found += [(a, b) for a in _in_core(run_profile(coarse, index, q, prior=prior, within=box), grid, core,
                                           config.zoom)]
        sparse = dataclasses.replace(coarse, coarse_m=NULL_GRID * (coarse.coarse_m or index.grid_m))
        scores = [a.score for n in nulls for a in _in_core(run_profile(sparse, index, n, prior=prior, within=box),
                                                              grid, core, config.zoom)]
        if scores:
            null[b] = max(scores)
    found.sort(key=_rank)
    refined: dict[int, list[Answer]] = {}
    for b in dict.fromkeys(b for _, b in found[:config.top_k]):  # the blocks of the best places, best first
        grid, core = blocks[b]
        index = _index(masks.mask(b), grid, table, classes, coarse)
        box = _core_box(grid, (coarse.coarse_m or index.grid_m) / index.resolution_m)
        refined[b] = _in_core(run_profile(fine, index, q, prior=prior, within=box), grid, core, config.zoom)
    return RegionPart(shard, len(blocks), found, refined, patches, null)


def _rank(item: tuple[Answer, int] | Answer) -> tuple[float, float, float]:
    a = item[0] if isinstance(item, tuple) else item
    return (-a.score, a.lat, a.lon)


def merge_parts(parts: Sequence[RegionPart], config: RegionConfig) -> RegionResult:
    """The answers of the region from every shard's part (see :func:`search_part`)."""
    shards = {p.shard.index for p in parts}
    counts = {p.shard.count for p in parts}
    if len(counts) != 1 or shards != set(range(1, next(iter(counts)) + 1)):
        raise ConfigError(f"a region's answer needs every shard's part: have {sorted(shards)} of {sorted(counts)}")
    blocks = region_blocks(config)
    found = sorted((ab for p in parts for ab in p.coarse), key=_rank)
    by_block = {b: answers for p in parts for b, answers in p.refined.items()}
    refined = sorted((a for b in dict.fromkeys(b for _, b in found[:config.top_k]) for a in by_block[b]), key=_rank)
    answers = _spaced(refined, config.top_k, min_m=1.0)
    # the alternative is refined as the answer was when one of the refined places is far enough
    # (the best blocks and each one's own alternative), else the best coarse place far enough
    alternative = next((a for a in refined if answers and distance_m(answers[0], a) >= config.distinct_m), None)
    everything = sorted([*refined, *(a for a, _ in found)], key=_rank)
    if alternative is None:
        alternative = next((a for a in everything if answers and distance_m(answers[0], a) >= config.distinct_m), None)
    answers = [_standing_out(a, alternative if i == 0 else None, everything, config.distinct_m)
               for i, a in enumerate(answers)]
    if alternative is not None:
        alternative = _standing_out(alternative, None, everything, config.distinct_m)
    overview = _Overview(blocks)
    for p in parts:
        for b, patch in p.patches.items():
            overview.paste(blocks[b][0], patch)
    nulls = [v for p in parts for v in p.null.values()]
    return RegionResult(tuple(answers), alternative, len(blocks), config, max(nulls) if nulls else None,
                        found[0][0].score if found else None, overview.pixels, overview.bounds)


def _standing_out(a: Answer, rival: Answer | None, everything: Sequence[Answer], distinct_m: float) -> Answer:
    """``a`` with its confidence: the share of its lead over chance that ``rival`` (else the best
    place ``distinct_m`` or more away) does not reach (as :mod:`localization.profile.search` in one image)."""
    rival = rival or next((r for r in everything if distance_m(a, r) >= distinct_m), None)
    if rival is None or a.chance is None:
        return a
    lead = a.score - a.chance
    return dataclasses.replace(a, confidence=min(1.0, max(0.0, (a.score - rival.score) / lead)) if lead > 0 else 0.0)


def search_region(query: SemanticMap, camera: Camera, osm: Sequence[Path | str], table: ClassTable,
                  classes: LandmarkClasses, config: RegionConfig, profile: ProfileConfig = ProfileConfig(),
                  progress: Progress | None = None, cache_dir: Path | None = None) -> RegionResult:
    """Search every block of the region for ``query`` (its semantic map, seen by ``camera``) in
    one process: :func:`search_part` of the one shard, merged. ``cache_dir``: see
    :class:`~localization.region.cache.BlockMasks`."""
    masks = BlockMasks(osm, table, [g for g, _ in region_blocks(config)], cache_dir)
    return merge_parts([search_part(query, camera, masks, table, classes, config, profile, Shard(1, 1), progress)],
                       config)


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

    def paste(self, grid: SampleGrid, patch: np.ndarray) -> None:
        """Paste a block's :func:`_core_patch` (its core tiles, every OVERVIEW_STEP-th pixel)."""
        first = grid.tiles[0]
        x0, y0 = first.x + 1, first.y + 1
        for y in range(patch.shape[0] // self.side):
            for x in range(patch.shape[1] // self.side):
                R, C = (y0 + y - self.y0) * self.side, (x0 + x - self.x0) * self.side
                self.pixels[R:R + self.side, C:C + self.side] = patch[y * self.side:(y + 1) * self.side,
                                                                      x * self.side:(x + 1) * self.side]

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        nw = mercantile.bounds(self.x0, self.y0, self.zoom)
        se = mercantile.bounds(self.x1, self.y1, self.zoom)
        return nw.west, se.south, se.east, nw.north


def _core_patch(grid: SampleGrid, core: frozenset[tuple[int, int]], mask: np.ndarray) -> np.ndarray:
    """The core of a block's mask (all but its outer ring of tiles), every OVERVIEW_STEP-th pixel."""
    tile = 256
    n = grid.size - 2
    return np.ascontiguousarray(mask[tile:tile * (n + 1), tile:tile * (n + 1)][OVERVIEW_STEP // 2::OVERVIEW_STEP,
                                                                            OVERVIEW_STEP // 2::OVERVIEW_STEP])


def _index(mask: np.ndarray, grid: SampleGrid, table: ClassTable, classes: LandmarkClasses,
           config: ProfileConfig) -> Any:
    """The profile method's aerial side of one block's mask."""
    return profile_index(semantic_map(mask, table, classes), ground_resolution(grid.lat, grid.zoom), config)


def _core_box(grid: SampleGrid, margin_px: float) -> tuple[float, float, float, float]:
    """The pixel box (x0, y0, x1, y1) of a block's core (all but its outer ring of tiles) and ``margin_px``
    around it: where the block is searched. Only its core's candidates are kept (:func:`_in_core`); the
    margin lets a position just outside refine into the core. The rays still read the whole block.

    >>> _core_box(SampleGrid(lon=0.0, lat=0.0, zoom=18, tiles=(), size=5), 10.0)
    (245.5, 245.5, 1033.5, 1033.5)
    """
    lo, hi = TILE_SIZE - 0.5 - margin_px, TILE_SIZE * (grid.size - 1) - 0.5 + margin_px
    return lo, lo, hi, hi


def _in_core(loc: Any, grid: SampleGrid, core: frozenset[tuple[int, int]], zoom: int) -> list[Answer]:
    """A block's candidates (``loc``: a profile-method :class:`~localization.common.result.Localization`)
    that lie in its core, each with its kappa against the block's chance agreement; the best
    distinct alternative the block found is one of them (refined as the answer was)."""
    if loc.unanswered and not loc.top_k:
        return []
    chance = loc.chance if loc.chance is not None else 0.0
    out = []
    b = grid.xy_bounds
    places = [(*place, heading) for place, heading in zip(loc.top_k, loc.headings)]
    if loc.alternative is not None:
        places.append((*loc.alternative, loc.alternative_heading))
    for x, y, score, heading in places:  # each place with the heading the query fits best there
        lon, lat = pixel_lonlat((b.left, b.bottom, b.right, b.top), (grid.height, grid.width), (x, y))
        tile = mercantile.tile(lon, lat, zoom)
        if (tile.x, tile.y) in core:
            kappa = (score - chance) / (1 - chance) if chance < 1 else 0.0
            out.append(Answer(lon, lat, score, None, heading, kappa, chance))
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
