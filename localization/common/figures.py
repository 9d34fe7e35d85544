"""The localization pictures of the paper: candidates on the aerial image, and both landmark graphs.

* :func:`localization_png`: the aerial image (or its colourised mask) with every candidate
  location (orange dots), the top-k (green windows, numbered by rank, the MAP marked with a
  cross) and, when known, the ground-truth viewpoint with the MAP's error in pixels (and metres
  given the ground resolution). The authors' code draws the same picture
  (``landmark_graphs_matching.m``: candidates orange, top-k green).
* :func:`graph_png`: an image with its landmark graph overlaid: dots coloured by landmark
  class, the covisibility edges in grey (a panorama's edges across its left/right seam are
  drawn the short way round, leaving one side and entering the other).

House style as :mod:`training.figures`: matplotlib's object-oriented API on an Agg canvas
(never ``pyplot``), style through :func:`matplotlib.rc_context`, PNGs rendered in memory
without a software stamp (same input, same bytes) and written atomically.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib
import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.lines import Line2D
from matplotlib.patches import Rectangle

from localization.common.landmarks import Landmarks
from localization.common.result import Localization
from osmseg import units
from osmseg.errors import ConfigError
from osmseg.output.plotting import figure as _figure, save_png as _save

if TYPE_CHECKING:
    from osmseg.classes import ClassTable

__all__ = ["CANDIDATE", "TOP_K", "TRUTH", "class_colours", "graph_png", "localization_png", "region_png"]

#: Colours of the paper's localization picture.
CANDIDATE = "#ff9900"
TOP_K = "#00c000"
TRUTH = "#ff1a1a"
#: Landmark class colours by name (the paper's four classes and their usual synonyms).
KNOWN_COLOURS = {
    "building": "#ffd400", "road": "#4a4aff", "highway": "#4a4aff", "tree": "#1f9e1f", "vegetation": "#1f9e1f",
    "pavement": "#e040e0", "footway": "#e040e0", "sidewalk": "#e040e0", "grass": "#8fe08f", "water": "#3fd0e0",
}
#: Largest picture side in inches (at DPI 100: 900 px).
MAX_INCHES = 9.0


def class_colours(classes: Sequence[str]) -> list[str]:
    """A colour per landmark class: the known ones by name, others from ``tab10`` in order.

    >>> class_colours(["building", "Road", "lamp"])
    ['#ffd400', '#4a4aff', '#1f77b4']
    """
    cycle = [matplotlib.colors.to_hex(c) for c in matplotlib.colormaps["tab10"](range(10))]
    out, spare = [], iter(cycle * (1 + len(classes) // len(cycle)))
    for name in classes:
        out.append(KNOWN_COLOURS.get(name.lower()) or next(spare))
    return out


#: The most pixels across a background is drawn from: more than the picture holds (MAX_INCHES at its dpi),
#: and a 6400 px mask drawn whole took 2.6 GB in matplotlib.
MAX_BACKGROUND_PX = 2048


def _size(width: int, height: int, extra: float = 0.6) -> tuple[float, float]:
    scale = MAX_INCHES / max(width, height, 1)
    return max(3.0, width * scale), max(1.5, height * scale) + extra


def _background(ax: Axes, image: np.ndarray | None, width: int, height: int) -> None:
    if image is not None:
        img = np.asarray(image)
        if img.shape[:2] != (height, width):
            raise ConfigError(f"background of {img.shape[1]}x{img.shape[0]} px does not match the "
                              f"landmarks' image of {width}x{height} px")
        step = -(-max(height, width) // MAX_BACKGROUND_PX)  # matplotlib holds several float copies of what it draws
        ax.imshow(img[::step, ::step], cmap="gray" if img.ndim == 2 else None, interpolation="antialiased",
                  extent=(-0.5, width - 0.5, height - 0.5, -0.5))
    else:
        ax.add_patch(Rectangle((-0.5, -0.5), width, height, color="0.93", zorder=0))
    ax.set_xlim(-0.5, width - 0.5)
    ax.set_ylim(height - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])


def localization_png(path: Path | str, result: Localization, aerial: Landmarks, *, image: np.ndarray | None = None,
                     truth: tuple[float, float] | None = None, resolution: float | None = None,
                     title: str | None = None, classes: Sequence[tuple[str, Sequence[int]]] = ()) -> Path:
    """The aerial image with all candidates (orange), the top-k (green, ranked) and the truth.

    ``image`` is the aerial RGB image or a colourised mask (``(H, W[, 3])``, the landmarks'
    size); without it a grey canvas. ``classes``: ``(name, rgb)`` of a colourised mask's
    classes, added to the legend. Top-k windows are squares of the result's window size
    around their centres. The title says how many candidates there are, the ties and the
    MAP's error to ``truth`` (px, and m with ``resolution`` in metres per pixel).
    """
    w, h = aerial.width, aerial.height
    with _figure(*_size(w, h, extra=0.9)) as fig:
        ax = fig.add_subplot()
        _background(ax, image, w, h)
        handles: list[Line2D] = []
        if len(result.candidates):
            ax.scatter(result.candidates[:, 0], result.candidates[:, 1], s=10, c=CANDIDATE, edgecolors="black",
                       linewidths=0.3, zorder=3)
        n = len(result.candidates)
        handles.append(Line2D([], [], ls="", marker="o", color=CANDIDATE, label=f"candidates ({n})"))
        half = result.window / 2.0
        for r, (x, y, _) in reversed(list(enumerate(result.top_k))):  # rank 1 drawn last, on top
            ax.add_patch(Rectangle((x - half, y - half), result.window, result.window, fill=False,
                                   ec=TOP_K, lw=3.0 if r == 0 else 1.5, zorder=4))
            ax.annotate(str(r + 1), (x - half, y - half), xytext=(2, -2), textcoords="offset points", ha="left",
                        va="top", color="white", fontsize=8, fontweight="bold", zorder=6,
                        bbox={"boxstyle": "round,pad=0.15", "fc": TOP_K, "ec": "none"})
        if result.map_xy is not None:
            ax.plot(*result.map_xy, marker="+", ms=14, mew=2.5, color=TOP_K, zorder=5)
            handles.append(Line2D([], [], ls="-", color=TOP_K, lw=2, label=f"top-{len(result.top_k)} windows"))
            handles.append(Line2D([], [], ls="", marker="+", ms=10, mew=2, color=TOP_K, label="best (MAP)"))
        if truth is not None:
            ax.plot(*truth, marker="*", ms=16, mfc=TRUTH, mec="white", mew=1.0, zorder=7)
            handles.append(Line2D([], [], ls="", marker="*", ms=12, mfc=TRUTH, mec="white", label="ground truth"))
        ax.set_title(title or _summary(result, truth, resolution))
        swatches = [Rectangle((0, 0), 1, 1, fc=np.asarray(rgb) / 255.0, ec="0.3", label=name) for name, rgb in classes]
        fig.legend(handles=handles + swatches, loc="outside lower center", ncol=min(len(handles) + len(swatches), 5),
                   frameon=False)
        return _save(fig, path)


def _summary(result: Localization, truth: tuple[float, float] | None, resolution: float | None) -> str:
    if result.unanswered:
        return f"unanswered: {result.reason}"
    text = (f"profile method, heading {units.degrees(result.heading_deg)}, confidence {units.ratio(result.confidence)}, "
            f"{len(result.candidates)} positions" if result.method == "profile" and result.confidence is not None
            else f"window {result.window} px, {len(result.candidates)} candidates")
    if result.ties > 1:
        text += f", {result.ties} tied at the top"
    px, metres = result.error(truth, resolution)
    if px is not None:
        text += f"; error {units.pixels(px)}" + (f" ({units.metres(metres)})" if metres is not None else "")
    return text


def _segments(lm: Landmarks, adjacency: np.ndarray) -> np.ndarray:
    """Line segments ``(n, 2, 2)`` of the graph's edges; panorama edges wrap when that is shorter."""
    adj = np.asarray(adjacency, dtype=bool)
    i, j = np.nonzero(np.triu(adj, k=1))
    a, b = lm.xy[i].astype(np.float64), lm.xy[j].astype(np.float64)
    if not lm.panorama or len(i) == 0:
        return np.stack([a, b], axis=1) if len(i) else np.zeros((0, 2, 2))
    dx = b[:, 0] - a[:, 0]
    wrap = np.abs(dx) > lm.width / 2.0
    shift = np.where(dx > 0, -lm.width, lm.width)[wrap]  # where b would sit seen across the seam
    direct = np.stack([a[~wrap], b[~wrap]], axis=1)
    b_across = b[wrap] + np.stack([shift, np.zeros_like(shift)], axis=1)
    a_across = a[wrap] - np.stack([shift, np.zeros_like(shift)], axis=1)
    return np.concatenate([direct, np.stack([a[wrap], b_across], axis=1), np.stack([a_across, b[wrap]], axis=1)])


def graph_png(path: Path | str, lm: Landmarks, adjacency: np.ndarray, *, image: np.ndarray | None = None,
              title: str | None = None) -> Path:
    """``lm``'s landmark graph over ``image``: class-coloured dots, grey edges, a class legend.

    ``adjacency`` is the ``(K, K)`` binary landmark adjacency (:func:`localization.paper.graph.adjacency`).
    """
    k = len(lm.xy)
    adj = np.asarray(adjacency)
    if adj.shape != (k, k):
        raise ConfigError(f"adjacency of shape {adj.shape} does not match {k} landmarks")
    w, h = lm.width, lm.height
    colours = class_colours(lm.classes)
    with _figure(*_size(w, h, extra=0.7)) as fig:
        ax = fig.add_subplot()
        _background(ax, image, w, h)
        segments = _segments(lm, adj)
        ax.add_collection(LineCollection(list(segments), colors="0.25", linewidths=0.6, alpha=0.6, zorder=2))
        cls = np.asarray(lm.cls, dtype=np.int64)
        if k:
            ax.scatter(lm.xy[:, 0], lm.xy[:, 1], s=28, c=[colours[c] for c in cls], edgecolors="black",
                       linewidths=0.6, zorder=3)
        present = sorted(set(cls.tolist()))
        handles = [Line2D([], [], ls="", marker="o", mfc=colours[c], mec="black", label=lm.classes[c])
                   for c in present]
        handles.append(Line2D([], [], color="0.25", lw=1, label="covisible"))
        n_edges = int(np.triu(adj.astype(bool), k=1).sum())
        ax.set_title(title or f"{k} landmarks, {n_edges} edges" + (" (panorama)" if lm.panorama else ""))
        fig.legend(handles=handles, loc="outside lower center", ncol=min(len(handles), 6), frameon=False)
        return _save(fig, path)


def region_png(path: Path | str, result: Any, table: ClassTable, truth: tuple[float, float] | None = None,
               error_m: float | None = None) -> Path:
    """The searched region (its OSM as drawn, in class colours) with the answers ranked, the
    best distinct alternative and the truth, in degrees, with a legend. ``result``: a
    :class:`localization.region.search.RegionResult` (which imports this module, not the reverse);
    ``error_m``: the answer's distance from the truth, for the title."""
    from matplotlib.patches import Patch

    if result.overview is None or result.overview_bounds is None:
        raise ConfigError("the region result has no overview to draw")
    w, s, e, n = result.overview_bounds
    h, wd = result.overview.shape
    with _figure(*_size(wd, h, extra=1.6)) as fig:
        ax = fig.add_subplot()
        ax.imshow(table.colorize(result.overview), extent=(w, e, s, n), interpolation="nearest")
        ax.set_aspect(1 / np.cos(np.radians((s + n) / 2)))
        ax.set_xlabel("longitude (°)")
        ax.set_ylabel("latitude (°)")
        handles: list[Any] = []
        for rank, a in reversed(list(enumerate(result.answers, start=1))):
            ax.plot(a.lon, a.lat, marker="o", ms=9 if rank == 1 else 6, color=TOP_K, mec="black", zorder=4)
            ax.annotate(str(rank), (a.lon, a.lat), xytext=(4, 4), textcoords="offset points", fontsize=8, zorder=5)
        handles.append(Line2D([], [], ls="", marker="o", color=TOP_K, mec="black", label="answers, ranked"))
        if result.alternative is not None:
            alt = result.alternative
            ax.plot(alt.lon, alt.lat, marker="D", ms=7, color=CANDIDATE, mec="black", zorder=4)
            handles.append(Line2D([], [], ls="", marker="D", color=CANDIDATE, mec="black",
                                  label=f"best distinct alternative (margin {units.ratio(result.margin)})"))
        title = f"{result.blocks} blocks searched"
        if truth is not None:
            ax.plot(*truth, marker="*", ms=13, color=TRUTH, mec="black", zorder=6)
            handles.append(Line2D([], [], ls="", marker="*", color=TRUTH, mec="black", label="truth"))
            if error_m is not None:
                title += f"; answer {units.metres(error_m)} from the truth"
        present = set(np.unique(result.overview).tolist())
        handles += [Patch(color=tuple(v / 255 for v in c.color[:3]), label=c.name)  # type: ignore[arg-type]
                    for c in table.classes if c.id in present]
        ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
        ax.set_title(title, fontsize=10)
        return _save(fig, path)
