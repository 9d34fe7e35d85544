"""A region search from files to files: the query and the OSM in, ``region.geojson``, ``region.png`` and
``region.html`` out.

One process searches the whole region (:func:`localization.region.search.search_region`). With
``--shard K/N`` each of N commands searches its share of the blocks and writes its part to
``OUT/region-parts/<key>/K-of-N.json`` (written whole or not at all); whichever shard finds all
N parts there merges them and writes the answers, the same answers one process gives. The key
is a hash of the query and of every setting that changes the answer, so parts of another query
or other settings never mix, and a corrected command starts beside a failed one's parts
instead of refusing the folder. A shard whose part is already there (a rerun, a requeued
array task) does not search again.

Imports: osmseg core, localization.common (inputs, landmarks, views, figures), localization.profile.search
and the region wing's own modules (search, cache).
"""

from __future__ import annotations

import base64
import dataclasses
import hashlib
import importlib.util
import json
import tempfile
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from localization.common.inputs import SideOptions
from localization.common.views import Camera, SemanticMap
from localization.profile.search import ProfileConfig
from localization.region.cache import BlockMasks, osm_key
from localization.region.search import (
    Answer,
    RegionConfig,
    RegionPart,
    RegionResult,
    distance_m,
    merge_parts,
    region_blocks,
    search_part,
)
from osmseg.errors import ConfigError
from osmseg.osm.localfile import LocalFileSource
from osmseg.output.atomic import atomic_write_text
from osmseg.output.manifest import refuse_busy
from osmseg.runtime.progress import Progress
from osmseg.runtime.shard import Shard

__all__ = ["RegionRequest", "RegionRun", "localize_region", "part_to_json", "part_from_json"]

PART_FORMAT = "osmseg-region-part"
#: 2: each block's best score of the scrambled query (the null) rides along; 3: each block searched in its
#: core alone (its candidates and null differ from a version 2 part's)
PART_VERSION = 3


@dataclass(frozen=True)
class RegionRequest:
    """``osmseg localize-region --osm FILE --bbox W,S,E,N``'s inputs: the query file and the region's OSM."""

    ground: Path
    ground_options: SideOptions
    osm: tuple[Path, ...]
    table: str = "classes13.toml"        # the classes the OSM is drawn in
    aerial_classes: str = "aerial13"     # their landmark dictionary
    fov_deg: float = 360.0
    camera_height_m: float = 2.0
    truth: tuple[float, float] | None = None  # lon, lat
    shard: Shard = Shard(1, 1)
    cache_dir: Path | None = None        # drawn blocks kept between runs (localization.region.cache)


@dataclass(frozen=True)
class RegionRun:
    """What a region command did: the result (None while other shards' parts are missing), the
    parts found so far, the folder of the parts, and the blocks drawn and read from the cache."""

    result: RegionResult | None
    parts: int
    shards: int
    parts_dir: Path | None
    drawn: int
    cached: int


def _answer_doc(a: Answer) -> dict[str, Any]:
    return dataclasses.asdict(a)  # full precision: the merge must rank exactly as one process


def part_to_json(part: RegionPart, key: str) -> str:
    """A shard's part as JSON (floats in full precision, overview patches deflated)."""
    return json.dumps({
        "format": PART_FORMAT, "format_version": PART_VERSION, "key": key, "shard": [part.shard.index, part.shard.count],
        "blocks": part.blocks,
        "coarse": [[_answer_doc(a), b] for a, b in part.coarse],
        "refined": {str(b): [_answer_doc(a) for a in answers] for b, answers in part.refined.items()},
        "patches": {str(b): [list(p.shape), base64.b64encode(zlib.compress(p.tobytes(), 6)).decode()]
                    for b, p in part.patches.items()},
        "null": {str(b): v for b, v in part.null.items()},
    }) + "\n"


def part_from_json(text: str) -> tuple[str, RegionPart]:
    """``(key, part)`` of :func:`part_to_json`'s text."""
    doc = json.loads(text)
    if doc.get("format") != PART_FORMAT:
        raise ConfigError("not a region part file (format osmseg-region-part)")
    patches = {int(b): np.frombuffer(zlib.decompress(base64.b64decode(data)), np.uint8).reshape(shape)
               for b, (shape, data) in doc["patches"].items()}
    part = RegionPart(Shard(*doc["shard"]), doc["blocks"], [(Answer(**a), b) for a, b in doc["coarse"]],
                      {int(b): [Answer(**a) for a in answers] for b, answers in doc["refined"].items()}, patches,
                      {int(b): float(v) for b, v in doc.get("null", {}).items()})
    return doc["key"], part


def _key(query: SemanticMap, camera: Camera, request: RegionRequest, config: RegionConfig,
         profile: ProfileConfig) -> str:
    """A hash of everything that changes the answers (the shard split does not)."""
    h = hashlib.sha256()
    h.update(f"part {PART_VERSION}".encode())  # a part of another version is another run's, never merged
    h.update(np.ascontiguousarray(query.labels).tobytes())
    h.update(np.ascontiguousarray(query.standing).tobytes())
    h.update(repr((query.classes, query.shape, camera, config, profile, request.table, request.aerial_classes,
                   osm_key(request.osm, _table(request.table), config.size))).encode())
    return h.hexdigest()[:16]


def _table(name: str) -> Any:
    from osmseg.classes import load_class_table

    return load_class_table(name)


def _load_query(request: RegionRequest) -> tuple[SemanticMap, Camera]:
    from localization.common.inputs import load_side
    from localization.common.views import check_view_shape

    ground = load_side(request.ground, request.ground_options)
    if ground.semantic is None:
        raise ConfigError(f"--ground {request.ground.name}: region search needs the query as a label mask "
                          "(or an RGB image with --ground-checkpoint), not a landmark file")
    g = ground.landmarks
    check_view_shape(g.width, g.height, request.fov_deg, f"--ground {request.ground.name}",
                     "give a panorama, or a photo with its field of view (--fov DEGREES)")
    return ground.semantic, Camera(g.width, g.height, hfov_deg=request.fov_deg,
                                   camera_height_m=request.camera_height_m)


def check_covered(osm: Sequence[Path], bbox: tuple[float, float, float, float], cache_dir: Path | None) -> None:
    """ConfigError when no OSM file of ``osm`` holds data over the region ``bbox`` (W, S, E, N degrees),
    naming each file's extent, as ``osmseg build`` says it of its area: every block would be drawn
    empty, and the search would answer that no place fits instead of that there is no data."""
    problems = []
    with tempfile.TemporaryDirectory() as scratch:  # where a node extent read from a file is kept without a cache
        workdir = Path(cache_dir) / "osm" if cache_dir is not None else Path(scratch)
        for path in osm:
            try:
                LocalFileSource(Path(path), workdir).check_covers(
                    *bbox, area="the region", fix="search where the data is (--bbox, or --lat/--lon/--radius-km)")
                return
            except ConfigError as exc:
                problems.append(str(exc))
    if problems:
        raise ConfigError(problems[0] if len(problems) == 1 else
                          "none of the --osm files holds data over the region: " + "; ".join(problems))


def localize_region(request: RegionRequest, config: RegionConfig, profile: ProfileConfig = ProfileConfig(),
                    out_dir: Path | None = None, progress: Progress | None = None) -> RegionRun:
    """Read the query, search the region (or this shard's share of it), and with ``out_dir``
    write ``region.geojson``, ``region.png`` and ``region.html`` once every shard's part is there."""
    from localization.common.landmarks import load_landmark_classes

    for path in request.osm:
        if not Path(path).is_file():
            raise ConfigError(f"--osm {path} is not a file: give the region's OSM extract (.osm, .osm.pbf)")
    refuse_busy(request.ground)  # a label a build is writing
    check_covered(request.osm, config.bbox, request.cache_dir)
    shard = request.shard
    if shard.count > 1 and out_dir is None:
        raise ConfigError(f"--shard {shard.index}/{shard.count} needs --out DIR: the folder every shard writes its "
                          "part to (the same for all shards)")
    query, camera = _load_query(request)
    table = _table(request.table)
    classes = load_landmark_classes(request.aerial_classes)
    masks = BlockMasks(request.osm, table, [g for g, _ in region_blocks(config)], request.cache_dir)
    if shard.count == 1:
        part = search_part(query, camera, masks, table, classes, config, profile, shard, progress)
        result = merge_parts([part], config)
        _write(result, request, out_dir)
        return RegionRun(result, 1, 1, None, masks.drawn, masks.read)
    assert out_dir is not None
    key = _key(query, camera, request, config, profile)
    folder = Path(out_dir) / "region-parts" / key
    mine = folder / f"{shard.index}-of-{shard.count}.json"
    if not mine.is_file():  # a rerun of a finished shard does not search again
        part = search_part(query, camera, masks, table, classes, config, profile, shard, progress)
        atomic_write_text(mine, part_to_json(part, key))
    parts = []
    for k in range(1, shard.count + 1):
        path = folder / f"{k}-of-{shard.count}.json"
        if path.is_file():
            parts.append(part_from_json(path.read_text())[1])
    if len(parts) < shard.count:
        return RegionRun(None, len(parts), shard.count, folder, masks.drawn, masks.read)
    result = merge_parts(parts, config)
    _write(result, request, out_dir)
    return RegionRun(result, len(parts), shard.count, folder, masks.drawn, masks.read)


def _write(result: RegionResult, request: RegionRequest, out_dir: Path | None) -> None:
    """``region.geojson`` (with the error when the truth is known), ``region.png`` and ``region.html`` in ``out_dir``."""
    if out_dir is None:
        return
    doc = result.to_geojson()
    error = (distance_m(result.best, request.truth) if request.truth is not None and result.best is not None
             else None)
    if request.truth is not None and error is not None:
        doc["properties"]["truth"] = {"lon": request.truth[0], "lat": request.truth[1], "error_m": round(error, 2)}
    atomic_write_text(Path(out_dir) / "region.geojson", json.dumps(doc, indent=2) + "\n")
    if importlib.util.find_spec("matplotlib") is not None:  # the picture is optional, the answers are not
        from localization.common.figures import region_png

        region_png(Path(out_dir) / "region.png", result, _table(request.table), request.truth, error)
    from localization.region.webmap import region_html  # folium: imported when a map is written

    region_html(Path(out_dir) / "region.html", result, _table(request.table), request.truth, error)
