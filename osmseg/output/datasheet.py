"""DATASHEET.md: a datasheet (Gebru et al., "Datasheets for Datasets", CACM 2021) filled from the manifest.

Resek (2022) documents its dataset with such a datasheet (Appendix A). osmseg writes one for
every build, with the sections of Gebru et al. (Motivation, Composition, Collection process,
Preprocessing/cleaning/labeling, Uses, Distribution, Maintenance) and the facts of this build:
counts, classes with colours and pixel shares, area, zoom and ground resolution, imagery and
OSM sources with timestamps, filter thresholds, rejections by reason, seed and command line.
Everything comes from the manifest, so the datasheet is as deterministic as the manifest.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

from osmseg.classes import ClassDef
from osmseg.output.atomic import atomic_write_text
from osmseg.output.attribution import LabelSource
from osmseg.output.manifest import (
    AreaRecord,
    DatasetManifest,
    DatasetSummary,
    Json,
    Provenance,
    RejectionRecord,
    SampleRecord,
    class_totals,
)

DATASHEET_NAME = "DATASHEET.md"

_FILTER_TEXT = {
    "max_unlabeled": "reject when at least this fraction of pixels is unlabeled",
    "min_classes": "reject when fewer distinct OSM classes than this appear",
    "max_placeholder_tiles": "reject when more tiles than this are the provider's 'no imagery' placeholder",
    "max_invalid_imagery": "reject when more than this fraction of pixels has no imagery",
    "min_contrast": "reject when the grey-level standard deviation (0-255) is below this",
}
_REASON_TEXT = {
    "unlabeled": "too much unlabeled area",
    "single_class": "fewer classes than required",
    "placeholder_imagery": "provider placeholder ('no imagery') tiles",
    "missing_imagery": "pixels without imagery",
    "low_contrast": "low-contrast imagery",
}


def _value(v: Json) -> str:
    """A manifest value in one line of Markdown."""
    if isinstance(v, (dict, list)):
        return "`" + json.dumps(v, sort_keys=True, ensure_ascii=False) + "`"
    return str(v)


def _description(source: Provenance) -> list[str]:
    """Bullet lines for a source's ``describe()`` record (sorted keys; long lists summarised)."""
    if not source.fields:
        return ["- (not recorded)"]
    lines = []
    for key, v in sorted(source.fields.items()):
        if isinstance(v, list) and len(v) > 8:
            v = f"{len(v)} entries (see manifest.json)"
        lines.append(f"- {key}: {_value(v)}")
    return lines


def _hex(rgb: Sequence[int]) -> str:
    """``#rrggbb`` of an RGB triple.

    >>> _hex([50, 50, 255])
    '#3232ff'
    """
    return "#" + "".join(f"{c:02x}" for c in rgb)


def _area_text(area: AreaRecord) -> str:
    name = area.name or "an area"
    parts = [f"**{name}**"]
    if area.kind:
        parts.append(f"({area.kind})")
    if area.bbox:
        w, s, e, n = area.bbox
        parts.append(f"box W {w:.5f}, S {s:.5f}, E {e:.5f}, N {n:.5f}")
    elif area.lat is not None and area.lon is not None:
        radius = f" within {area.radius_km:g} km" if area.radius_km is not None else ""
        parts.append(f"centred on lat {area.lat:.5f}, lon {area.lon:.5f}{radius}")
    return " ".join(parts)


def _timestamps(samples: Sequence[SampleRecord]) -> str:
    stamps = sorted({s.osm.timestamp for s in samples if s.osm.timestamp})
    if not stamps:
        return "not reported by the source"
    return stamps[0] if len(stamps) == 1 else f"{stamps[0]} to {stamps[-1]}"


_FORMAT_TEXT = {"cog": "RGB Cloud-Optimized GeoTIFF on the grid of `geo/` (EPSG:3857)",
                "png": "RGB PNG", "jpg": "RGB JPEG (quality 95, 4:4:4)"}


def render_datasheet(manifest: DatasetManifest) -> str:
    """The datasheet Markdown for ``manifest`` (pure function of the manifest)."""
    samples, rejected, summary, area = manifest.samples, manifest.rejected, manifest.summary, manifest.area
    table = manifest.classes
    classes = sorted((table.unlabeled, *table.classes), key=lambda c: c.id)
    totals = class_totals(samples)
    res = manifest.ground_resolutions()
    res_text = f"{min(res):.3f}-{max(res):.3f} m" if res and max(res) - min(res) >= 0.0005 else (f"{res[0]:.3f} m" if res else "n/a")
    title = manifest.name or f"osmseg dataset: {area.name or 'custom area'}"
    n_classes = len(classes) - 1
    labels = LabelSource.of(manifest.osm)

    out: list[str] = [f"# Datasheet: {title}", ""]
    out += _composition(manifest, manifest.tool.text(), len(samples), n_classes, res_text)
    out += _class_rows(classes, totals)
    out += _collection(samples, rejected, summary, manifest.imagery, manifest.osm)
    out += _preprocessing(manifest, summary, rejected)
    out += _closing(manifest, labels)
    return "\n".join(out)


def _known(value: int | None) -> str:
    """A count the manifest may not record: ``?`` then."""
    return "?" if value is None else str(value)


def _composition(manifest: DatasetManifest, tool_text: str, n_samples: int, n_classes: int, res_text: str) -> list[str]:
    """Motivation, and composition up to the class table's header."""
    zoom = manifest.zoom
    grid = 5 if manifest.grid_size is None else manifest.grid_size
    size = grid * 256
    fmt = manifest.image_format or "png"
    return [
        f"Generated by {tool_text} from `manifest.json`, following the sections of Gebru et al.,",
        '"Datasheets for Datasets" (Communications of the ACM 64(12), 2021), as Appendix A of',
        "Resek (2022, UNICAMP) does. Edit the parts marked *(to fill in)* before you publish.",
        "",
        "## Motivation",
        "",
        f"- **Purpose.** Training and evaluating semantic segmentation of aerial images into {n_classes}",
        f"  classes derived from OpenStreetMap (class table `{manifest.classes.name}`), the task of",
        "  Resek (2022): masks come from OSM, so a dataset can be made for any place with imagery.",
        f"- **Created by** running `{manifest.command}` with {tool_text}. Creator and funding: *(to fill in)*.",
        "",
        "## Composition",
        "",
        f"- **Instances.** {n_samples} samples (requested {_known(manifest.summary.requested)}). Each is an aerial image",
        f"  of {size}x{size} px ({grid}x{grid} Web Mercator tiles of 256 px at zoom {zoom}) and its labels:",
        "",
        "  | folder | content |",
        "  |---|---|",
        f"  | `images/` | aerial image, {_FORMAT_TEXT.get(fmt, 'RGB ' + fmt.upper())} |",
        "  | `segmented/` | labels in class colours, RGB PNG, same file names |",
        "  | `labels/` | class ids, 8-bit greyscale PNG (0 = unlabeled) |",
        "  | `geo/` | class ids as Cloud-Optimized GeoTIFF in EPSG:3857 with a colour table and class names (QGIS, torchgeo), "
        "and beside each its QGIS style (`.qml`: class colours and names in QGIS's legend) |",
        "",
        f"- **Area.** {_area_text(manifest.area)}.",
        f"- **Ground resolution.** zoom {zoom}: {res_text} per pixel at the samples' latitudes.",
        f"- **Sampling.** Sample centres are drawn uniformly at random over the area with seed {manifest.seed};",
        "  a centre is kept only if it passes the filters below, so the dataset is a filtered random sample",
        "  of the area, not all of it. Samples may overlap.",
        f"- **Labels.** {n_classes} classes + unlabeled. Pixel counts over all samples:",
        "",
        "  | id | class | colour (RGB) | pixels | share |",
        "  |---:|---|---|---:|---:|",
    ]


def _class_rows(classes: list[ClassDef], totals: dict[str, int]) -> list[str]:
    """The class table's rows: id, name, colour, pixels and share over all samples."""
    all_pixels = sum(totals.values())
    rows = []
    for c in classes:
        count = totals.get(c.name, 0)
        share = 100.0 * count / all_pixels if all_pixels else 0.0
        rgb = c.color
        rows.append(f"  | {c.id} | {c.name} | {_hex(rgb)} ({rgb[0]}, {rgb[1]}, {rgb[2]}) | {count:,} | {share:.2f}% |")
    return rows


def _collection(samples: Sequence[SampleRecord], rejected: Sequence[RejectionRecord], summary: DatasetSummary,
                imagery: Provenance, osm: Provenance) -> list[str]:
    """Composition's notes after the class table, and the collection process."""
    return [
        "",
        "- **Unlabeled is not background.** Class 0 marks pixels no OSM feature covers: unmapped",
        "  buildings and roads there are real objects without a label.",
        "- **Errors and noise.** OSM is volunteered and uneven: features can be missing, outdated or",
        "  offset from the imagery; road and footway widths come from tags or per-type defaults;",
        "  the imagery and the OSM data were captured at different dates.",
        "- **Sensitive content.** Public aerial imagery and public OSM data only; at this resolution",
        "  vehicles and sometimes people are visible. No other personal data.",
        "",
        "## Collection process",
        "",
        "- **Imagery** (tiles per sample in `manifest.json`):",
        *[f"  {line}" for line in _description(imagery)],
        "- **OpenStreetMap** source:",
        *[f"  {line}" for line in _description(osm)],
        f"- **OSM data timestamp:** {_timestamps(samples)}.",
        f"- **Attempts.** {_known(summary.attempts or len(samples) + len(rejected))} centres drawn"
        f" (limit {_known(summary.max_attempts)}): {len(samples)} accepted, {len(rejected)} rejected.",
    ]


def _preprocessing(manifest: DatasetManifest, summary: DatasetSummary, rejected: Sequence[RejectionRecord]) -> list[str]:
    """Labeling, the filters as used and the rejected samples by reason."""
    out = [
        "",
        "## Preprocessing / cleaning / labeling",
        "",
        "- **Labeling.** OSM features are matched to classes by the tag rules of the class table and",
        "  rasterised with rasterio.features on each sample's pixel grid: areas first, lines buffered",
        "  to their width on top, buildings last. Nothing is labelled by hand.",
        "- **Filtering** (thresholds as used):",
        "",
        "  | setting | value | rule |",
        "  |---|---:|---|",
    ]
    for key, value in sorted(manifest.filters.items()):
        out.append(f"  | `{key}` | {value:g} | {_FILTER_TEXT.get(key, '')} |" if isinstance(value, (int, float))
                   else f"  | `{key}` | {_value(value)} | {_FILTER_TEXT.get(key, '')} |")
    by_reason = dict(summary.rejected_by_reason or {})
    if not by_reason:
        for r in rejected:
            by_reason[r.reason] = by_reason.get(r.reason, 0) + 1
    out += ["", "- **Rejected samples by reason:**", ""]
    if by_reason:
        out += ["  | reason | count | meaning |", "  |---|---:|---|"]
        out += [f"  | `{k}` | {v} | {_REASON_TEXT.get(k, '')} |" for k, v in by_reason.items()]
    else:
        out.append("  none.")
    return out


def _closing(manifest: DatasetManifest, labels: LabelSource) -> list[str]:
    """Raw data, uses, distribution and maintenance."""
    return [
        "",
        "- **Raw data.** Not included, but `manifest.json` lists every tile (z/x/y and quadkey) and the",
        "  OSM source of every sample, so it can be fetched again.",
        "",
        "## Uses",
        "",
        "- **Intended:** training and evaluating aerial segmentation models (e.g. SegNet as in",
        "  Resek 2022), studying OSM label noise, ground-to-aerial localisation research.",
        "- **Not suited for:** surveying, navigation or legal boundaries; judging OSM completeness",
        "  from `unlabeled` alone; identifying or tracking individuals.",
        "- **Caveat.** Class shares above are specific to this area and filter settings; models",
        "  trained here may not transfer to other regions, seasons or sensors.",
        "",
        "## Distribution",
        "",
        *(["- Labels (`segmented/`, `labels/`, `geo/`) derive from OpenStreetMap: © OpenStreetMap",
           "  contributors, ODbL 1.0. Images follow the imagery provider's terms. See `ATTRIBUTION.md`."]
          if labels.is_osm else
          [f"- Labels (`segmented/`, `labels/`, `geo/`) derive from {labels.name}, whose licence osmseg does",
           "  not know: keep the source's terms. Images follow the imagery provider's terms. See `ATTRIBUTION.md`."]),
        "- `osmseg build --zip` packs the folder into a deterministic zip archive.",
        "",
        "## Maintenance",
        "",
        f"- **Reproduce:** `{manifest.command}` (seed {manifest.seed}). With the same sources this",
        "  gives byte-identical files; live OSM and imagery change over time, so for exact",
        "  reproduction build from a pinned `.osm.pbf` extract and a local GeoTIFF or a cache.",
        "- **Check integrity:** every file's SHA-256 is in `manifest.json`",
        "  (`osmseg.output.manifest.verify`).",
        "- Maintainer, contact and errata: *(to fill in)*.",
        "",
    ]


def write_datasheet(out_dir: Path, manifest: DatasetManifest) -> Path:
    """Write ``OUT/DATASHEET.md`` atomically and return its path."""
    return atomic_write_text(Path(out_dir) / DATASHEET_NAME, render_datasheet(manifest))
