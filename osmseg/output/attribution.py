"""ATTRIBUTION.md: the licences and attribution a dataset's users must keep.

Two sources, two sets of terms:

* the labels (``segmented/``, ``labels/``, ``geo/``) are made from OpenStreetMap data,
  © OpenStreetMap contributors, under the Open Database License (ODbL) 1.0;
* the images (``images/``) stay under the imagery provider's own terms, whose attribution
  line comes from the provider's ``describe()`` (recorded in the manifest).

The text explains what the ODbL asks of someone who shares the dataset, following the OSMF's
community guidelines (Produced Work guideline, 2014; Horizontal Layers guideline). It is
guidance, not legal advice.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from osmseg.output.atomic import atomic_write_text
from osmseg.output.manifest import DatasetManifest, Provenance

ATTRIBUTION_NAME = "ATTRIBUTION.md"
OSM_NOTICE = "© OpenStreetMap contributors"
ODBL_URL = "https://opendatacommons.org/licenses/odbl/1-0/"
OSM_COPYRIGHT_URL = "https://www.openstreetmap.org/copyright"


def _imagery_lines(imagery: Provenance) -> list[str]:
    """What the manifest says about the imagery provider's terms."""
    name = imagery.name or imagery.provider or "the imagery provider"
    lines = [f"- Provider: **{name}**"]
    attribution = imagery.attribution
    lines.append(f"- Attribution: {attribution}" if attribution else
                 "- Attribution: *(the provider gave none; look up its terms before sharing the images)*")
    for key, value in imagery.stated_terms():
        lines.append(f"- {key.replace('_', ' ').capitalize()}: {value}")
    if imagery.brand_logo_uri:
        lines.append("- Bing Maps terms ask that the logo above is shown with the imagery.")
    return lines


@dataclass(frozen=True)
class LabelSource:
    """Where a dataset's labels come from, for every text that states their licence.

    OSM sources (the API, Overpass, OSM files) give OpenStreetMap data under the ODbL. A
    ``geojson:`` source gives features of unknown origin: osmseg cannot tell their licence and
    must not claim the ODbL (they may be OSM-derived, an agency's footprints, hand-drawn).
    """

    is_osm: bool
    name: str  # "OpenStreetMap data" or "the GeoJSON features of PATH"
    notice: str  # the line to keep with the labels
    spdx: str | None  # SPDX licence id of the labels, None when unknown

    @classmethod
    def of(cls, osm: Provenance) -> LabelSource:
        """The label source a manifest records (its ``osm``).

        >>> LabelSource.of(Provenance({"source": "geojson", "path": "f.geojson"})).spdx is None
        True
        """
        if osm.source == "geojson":
            where = f"the GeoJSON features of `{osm.path or '?'}`"
            return cls(False, where, f"labels made by osmseg from {where}: keep the licence and attribution of "
                       "that file's source (if it was exported from OpenStreetMap: © OpenStreetMap contributors, "
                       "ODbL 1.0)", None)
        return cls(True, "OpenStreetMap data", f"{OSM_NOTICE}, ODbL 1.0", "ODbL-1.0")


def _geojson_section(source: LabelSource) -> list[str]:
    return [
        f"## Labels: {source.name}",
        "",
        f"`segmented/`, `labels/` and `geo/` are rasterised from {source.name} (`--osm geojson:`).",
        "osmseg does not know where those features come from, so it states no licence for the labels:",
        "they carry the licence of the file's source. If it was exported from OpenStreetMap (a HOT",
        f"export, an Overpass query saved as GeoJSON), the labels are {OSM_NOTICE}'s data under the",
        f"ODbL 1.0 ({ODBL_URL}) and the OpenStreetMap guidance of an osmseg OSM build applies:",
        "attribute, and share the label files under the ODbL. Otherwise follow the source's own terms.",
        "",
    ]


def render_attribution(manifest: DatasetManifest) -> str:
    """The ATTRIBUTION.md text for ``manifest`` (pure function of the manifest)."""
    imagery = manifest.imagery
    osm_extra = manifest.osm.attribution
    source = LabelSource.of(manifest.osm)
    if not source.is_osm:
        return "\n".join([
            "# Attribution and licences", "",
            "This dataset combines two sources under different terms. Keep this file with any copy.", "",
            *_geojson_section(source),
            "## Images: imagery provider's terms", "",
            "`images/` come from the provider below and remain under its terms of use, which may",
            "restrict redistribution. Check them before you publish the images.", "",
            *_imagery_lines(imagery), "",
        ])
    out = [
        "# Attribution and licences",
        "",
        "This dataset combines two sources under different terms. Keep this file with any copy.",
        "",
        "## Labels: OpenStreetMap data, ODbL 1.0",
        "",
        f"`segmented/`, `labels/` and `geo/` are made from OpenStreetMap data, **{OSM_NOTICE}**,",
        f"available under the Open Database License (ODbL) 1.0: {ODBL_URL}",
        f"(details: {OSM_COPYRIGHT_URL}).",
    ]
    if osm_extra and osm_extra != OSM_NOTICE:
        out.append(f"Source attribution as reported: {osm_extra}")
    out += [
        "",
        "What this means when you share the dataset (guidance, not legal advice):",
        "",
        "- **Attribution is always required.** Wherever the labels, or anything made from them, are",
        f'  shown or shared, say "{OSM_NOTICE}" and that the data is available under the ODbL.',
        "- **The label files are best treated as a Derivative Database.** The ODbL calls a work",
        "  made from the data (a map image, a chart) a *Produced Work*, which you may license as you",
        "  like with the notice above. But the OSMF guideline says something made for extracting",
        "  the original data is a database, not a Produced Work, and per-pixel class masks are",
        "  shipped precisely to be read back as data. So if you publicly share the label files,",
        "  share them under the ODbL 1.0 (share-alike), keep this notice, and offer the data or",
        "  the means to recreate it: `manifest.json` (tiles, OSM source and timestamp per sample)",
        "  and the osmseg command line in it serve as that machine-readable recipe.",
        "- **Produced Works** made from the dataset (figures, rendered maps, a published model's",
        "  predictions shown as images) need only the notice.",
        "- **The images are a separate layer.** Combining OSM labels with imagery does not put the",
        "  imagery under the ODbL (OSMF Horizontal Layers guideline), nor the labels under the",
        "  imagery's terms: each keeps its own licence.",
        "",
        "## Images: imagery provider's terms",
        "",
        "`images/` come from the provider below and remain under its terms of use, which may",
        "restrict redistribution (commercial providers often allow only the use their API key",
        "was issued for). Check them before you publish the images.",
        "",
        *_imagery_lines(imagery),
        "",
    ]
    return "\n".join(out)


def write_attribution(out_dir: Path, manifest: DatasetManifest) -> Path:
    """Write ``OUT/ATTRIBUTION.md`` atomically and return its path."""
    return atomic_write_text(Path(out_dir) / ATTRIBUTION_NAME, render_attribution(manifest))
