"""A region search's map a person can pan: ``region.html``, one self-contained file that opens offline.

Drawn with folium (Leaflet): the region as the search drew it from OpenStreetMap (its class
colours, the overview ``region.png`` shows; unlabeled pixels transparent) as an image overlay, the ranked answers, the best
distinct alternative and the truth as circles whose popups give rank, place, score,
confidence, kappa and heading, the verdict ("here", "not sure", "not found here") in a box
over the map, a legend of the classes and the marks, and a scale bar. Online, OpenStreetMap's
tiles lie under the overlay (a layer switch turns either off); offline the overlay, the marks
and the controls still show, because the scripts and style sheet folium links from CDNs are
written into the file instead: Leaflet and jQuery (folium's popups parse their HTML with it)
from the XStatic-Leaflet and XStatic-jQuery packages, the releases folium's own template names
(1.9.3 and 3.7.1). Folium's other default assets (Bootstrap, Font Awesome, awesome-markers)
are left out: nothing here uses them. The file's only outside addresses are the basemap's tiles, and the same
search writes the same bytes (folium's random element names are numbered).

Imports: folium, xstatic.pkg (leaflet, jquery), PIL, numpy, osmseg core,
localization.common.marks and localization.region.search (the result drawn).
"""

from __future__ import annotations

import base64
import html
import io
import re
from pathlib import Path

import folium
import numpy as np
from PIL import Image
from xstatic.pkg import jquery as xjquery, leaflet as xleaflet

from localization.common.marks import CANDIDATE, TOP_K, TRUTH
from localization.region.search import Answer, RegionResult, distance_m
from osmseg import units
from osmseg.classes import ClassTable
from osmseg.errors import ConfigError
from osmseg.output.atomic import atomic_write_text

__all__ = ["region_html"]

#: Leaflet's files in the XStatic-Leaflet package (its BASE_DIR)
LEAFLET = Path(xleaflet.BASE_DIR)
#: the scripts written into the page: folium's name for each, and its file
SCRIPTS = {"leaflet": LEAFLET / "leaflet.js", "jquery": Path(xjquery.BASE_DIR) / "jquery.min.js"}
#: how opaque the drawn region lies over the basemap
OVERLAY_OPACITY = 0.75
#: the verdict's colour in the box over the map
VERDICT_COLOURS = {"here": "#1a7f37", "not sure": "#9a6700", "not found here": "#cf222e"}


def region_html(path: Path | str, result: RegionResult, table: ClassTable, truth: tuple[float, float] | None = None,
                error_m: float | None = None) -> Path:
    """Write ``path``: the region, its answers and verdict on a map that pans and zooms (see the module doc)."""
    if result.overview is None or result.overview_bounds is None:
        raise ConfigError("the region result has no overview to draw")
    w, s, e, n = result.overview_bounds
    fmap = folium.Map(location=[(s + n) / 2, (w + e) / 2], tiles=None, control_scale=True, prefer_canvas=False)
    fmap.default_js = [(name, f"{name}.js") for name in SCRIPTS]  # written in below; nothing else is needed
    fmap.default_css = [("leaflet_css", "leaflet.css")]
    folium.TileLayer("OpenStreetMap", name="OpenStreetMap (online)", max_zoom=21, max_native_zoom=19).add_to(fmap)
    folium.raster_layers.ImageOverlay(_png_url(_rgba(result.overview, table)), bounds=[[s, w], [n, e]],
                                      opacity=OVERLAY_OPACITY, name="the region as drawn from OSM",
                                      interactive=False).add_to(fmap)
    marks = folium.FeatureGroup(name="answers").add_to(fmap)
    for rank, a in reversed(list(enumerate(result.answers, start=1))):
        _circle(a, f"answer {rank}" if rank > 1 else "answer 1 (best)", TOP_K, 9 if rank == 1 else 6, result).add_to(marks)
    if result.alternative is not None:
        _circle(result.alternative, "best distinct alternative", CANDIDATE, 7, result).add_to(marks)
    if truth is not None:
        extra = "" if error_m is None else f"<br>answer {units.metres(error_m)} away"
        folium.CircleMarker([truth[1], truth[0]], radius=7, color="black", weight=1, fill=True, fill_color=TRUTH,
                            fill_opacity=1.0, popup=folium.Popup(f"<b>truth</b><br>{_lonlat(*truth)}{extra}"),
                            tooltip="truth").add_to(marks)
    folium.LayerControl(collapsed=True).add_to(fmap)
    fmap.fit_bounds([[s, w], [n, e]])
    root = fmap.get_root()
    root.html.add_child(folium.Element(_verdict_box(result, error_m)))  # type: ignore[attr-defined]
    root.html.add_child(folium.Element(_legend(result, table, truth is not None)))  # type: ignore[attr-defined]
    page = _self_contained(_numbered(root.render()), result.headline(error_m))
    out = Path(path)
    atomic_write_text(out, page)
    return out


def _rgba(classes: np.ndarray, table: ClassTable) -> np.ndarray:
    """The class colours, unlabeled pixels transparent (online, the basemap shows where OSM drew nothing)."""
    alpha = np.where(classes == table.unlabeled.id, 0, 255).astype(np.uint8)
    return np.dstack([table.colorize(classes).astype(np.uint8), alpha])


def _png_url(rgba: np.ndarray) -> str:
    """``rgba`` as a ``data:`` URL of a PNG (nearest neighbour when Leaflet scales it: see the CSS below)."""
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgba, np.uint8), "RGBA").save(buf, format="PNG", optimize=True)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _lonlat(lon: float, lat: float) -> str:
    return f"{lon:.6f}, {lat:.6f}"


def _circle(a: Answer, label: str, colour: str, radius: int, result: RegionResult) -> folium.CircleMarker:
    """A mark for answer ``a`` whose popup gives its place, score, confidence, kappa and heading."""
    rows = [("place (lon, lat)", _lonlat(a.lon, a.lat)), ("score", f"{a.score:.4f}"),
            ("confidence", units.ratio(a.confidence)), ("kappa", units.ratio(a.kappa)),
            ("heading", units.degrees(a.heading_deg))]
    if result.best is not None and a is not result.best:
        rows.append(("from the answer", units.metres(distance_m(result.best, a))))
    table = "".join(f"<tr><td>{html.escape(k)}</td><td>{html.escape(v)}</td></tr>" for k, v in rows)
    return folium.CircleMarker([a.lat, a.lon], radius=radius, color="black", weight=1, fill=True, fill_color=colour,
                               fill_opacity=1.0, tooltip=label,
                               popup=folium.Popup(f"<b>{html.escape(label)}</b><table>{table}</table>", max_width=320))


_BOX = ("position:absolute;z-index:1000;background:rgba(255,255,255,0.92);padding:6px 10px;border-radius:4px;"
        "font:13px/1.35 sans-serif;box-shadow:0 1px 4px rgba(0,0,0,0.4);")


def _verdict_box(result: RegionResult, error_m: float | None) -> str:
    """The verdict over the map, top centre, in its colour; lift and confidence beside it."""
    colour = VERDICT_COLOURS.get(result.verdict, "black")
    best = result.best
    facts = [f"lift over the null {units.ratio(result.lift)}"] if result.lift is not None else []
    if best is not None:
        facts.append(f"confidence {units.ratio(best.confidence)}")
    return (f'<div id="osmseg-verdict" data-verdict="{html.escape(result.verdict)}" style="{_BOX}top:10px;left:56px;'
            f'max-width:calc(100% - 130px);"><b style="color:{colour}">'
            f'{html.escape(result.headline(error_m))}</b><br>{html.escape("; ".join(facts))}</div>')


def _legend(result: RegionResult, table: ClassTable, truth: bool) -> str:
    """The classes drawn in the region and the marks, bottom right."""
    assert result.overview is not None
    present = set(np.unique(result.overview).tolist())

    def swatch(colour: str, label: str, round_: bool = False) -> str:
        shape = "border-radius:50%;border:1px solid black;" if round_ else ""
        return (f'<div><span style="display:inline-block;width:12px;height:12px;margin-right:6px;{shape}'
                f'background:{colour}"></span>{html.escape(label)}</div>')

    rows = [swatch(TOP_K, "answers, ranked", True)]
    if result.alternative is not None:
        rows.append(swatch(CANDIDATE, f"best distinct alternative (margin {units.ratio(result.margin)})", True))
    if truth:
        rows.append(swatch(TRUTH, "truth", True))
    rows += [swatch("#" + "".join(f"{v:02x}" for v in c.color[:3]), c.name) for c in table.classes if c.id in present]
    return f'<div id="osmseg-legend" style="{_BOX}bottom:24px;right:10px;">{"".join(rows)}</div>'


def _numbered(page: str) -> str:
    """``page`` with folium's random element names (``map_<32 hex digits>``) numbered in order of
    appearance instead: the same search writes the same bytes (base64 has no ``_``, so a picture's
    data is never mistaken for a name)."""
    names: dict[str, str] = {}
    return re.sub(r"_[0-9a-f]{32}(?![0-9a-f])", lambda m: names.setdefault(m.group(0), f"_{len(names) + 1}"), page)


def _self_contained(page: str, title: str) -> str:
    """``page`` with its scripts and Leaflet's style sheet written in (its images as ``data:`` URLs), a title,
    and the overlay scaled without smoothing (class colours stay class colours)."""

    def image(match: re.Match[str]) -> str:
        data = (LEAFLET / match.group(1)).read_bytes()
        return f"url(data:image/png;base64,{base64.b64encode(data).decode('ascii')})"

    css = re.sub(r"url\((images/[\w.-]+\.png)\)", image, (LEAFLET / "leaflet.css").read_text(encoding="utf-8"))
    css += "\n.leaflet-image-layer { image-rendering: pixelated; }\n"
    tags = {f'<script src="{name}.js"></script>': "<script>" + path.read_text(encoding="utf-8").replace(
        "</script", "<\\/script") + "</script>" for name, path in SCRIPTS.items()}
    tags['<link rel="stylesheet" href="leaflet.css"/>'] = f"<style>{css}</style>"
    for tag, inline in tags.items():
        if tag not in page:
            raise RuntimeError(f"folium's page no longer links {tag}: region.html would not open offline")
        page = page.replace(tag, inline)
    return page.replace("<head>", f"<head>\n<title>{html.escape(title)}</title>", 1)
