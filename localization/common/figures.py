"""The localization pictures: candidates on the aerial image, both landmark graphs, a region's answers.

* :func:`localization_png`: the aerial image (or its colourised mask) with the method's answer
  in its own terms. The paper method: every candidate location (orange dots), the top-k (green
  windows, numbered by rank, the MAP marked with a cross), as the authors' code draws it
  (``landmark_graphs_matching.m``: candidates orange, top-k green). The profile method: the
  positions of its finest grid, the top-k positions (numbered), the best position and the best
  distinct alternative. Both: the ground-truth viewpoint with the answer's error in pixels (and
  metres given the ground resolution), and "unanswered" with the reason when there is no answer.
* :func:`graph_png`: an image with its landmark graph overlaid: dots in the class table's colour
  of each landmark class (:func:`~localization.common.landmarks.landmark_colours`, the colour of
  the mask under them and of the map's legend), the covisibility edges in grey (a panorama's
  edges across its left/right seam are drawn the short way round, leaving one side and
  entering the other).
* :func:`region_png`: a searched region in its class colours with the ranked answers, the best
  distinct alternative and the truth, on axes in plain degrees.

Each ``*_png`` draws with a ``draw_*`` function on a new figure and writes it. House style as
:mod:`training.evaluation.figures`: matplotlib's object-oriented API on an Agg canvas (never ``pyplot``),
style through :func:`matplotlib.rc_context`, PNGs rendered in memory without a software stamp
(same input, same bytes), cut to everything drawn (no title cut off) and written atomically
(:mod:`osmseg.output.plotting`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib
import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Rectangle
from matplotlib.patheffects import withStroke

from localization.common.landmarks import Landmarks
from localization.common.marks import CANDIDATE, TOP_K, TRUTH
from localization.common.result import Localization
from osmseg import units
from osmseg.errors import ConfigError
from osmseg.output.plotting import degree_axis, figure as _figure, legend_below, save_png as _save

if TYPE_CHECKING:
    from osmseg.classes import ClassTable

__all__ = ["CANDIDATE", "TERMS", "TOP_K", "TRUTH", "draw_graph", "draw_localization", "draw_region", "graph_png",
           "landmark_palette", "localization_png", "region_png"]

#: What each method's marks are called in the legend: the paper method ranks candidate windows
#: (the MAP is the best), the profile method scores positions on a grid (localization.profile.locate).
TERMS = {
    "paper": {"candidates": "candidates", "top": "top-{k} windows", "best": "best (MAP)"},
    "profile": {"candidates": "positions of the finest grid", "top": "top-{k} positions", "best": "best position"},
}
#: Largest picture side in inches (at DPI 100: 900 px).
MAX_INCHES = 9.0


def landmark_palette(classes: Sequence[str], colours: Mapping[str, Sequence[int]] | None = None) -> list[str]:
    """A colour per landmark class: its class-table colour from ``colours``
    (:func:`~localization.common.landmarks.landmark_colours`), else (a dictionary with no class
    table) one of ``tab10`` in order.

    >>> landmark_palette(["building", "road", "lamp"], {"building": (255, 255, 0), "road": (50, 50, 255)})
    ['#ffff00', '#3232ff', '#1f77b4']
    """
    cycle = [matplotlib.colors.to_hex(c) for c in matplotlib.colormaps["tab10"](range(10))]
    known = colours or {}
    spare = iter(cycle * (1 + len(classes) // len(cycle)))
    return ["#{:02x}{:02x}{:02x}".format(*(int(v) for v in known[name][:3])) if name in known else next(spare)
            for name in classes]


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


def draw_localization(fig: Figure, result: Localization, aerial: Landmarks, *, image: np.ndarray | None = None,
                      truth: tuple[float, float] | None = None, resolution: float | None = None,
                      title: str | None = None, classes: Sequence[tuple[str, Sequence[int]]] = ()) -> Axes:
    """:func:`localization_png`'s picture on ``fig``; returns its axes."""
    w, h = aerial.width, aerial.height
    terms = TERMS.get(result.method, TERMS["paper"])
    ax = fig.add_subplot()
    _background(ax, image, w, h)
    handles: list[Any] = []
    n = len(result.candidates)
    if n:
        ax.scatter(result.candidates[:, 0], result.candidates[:, 1], s=10, c=CANDIDATE, edgecolors="black",
                   linewidths=0.3, zorder=3)
    handles.append(Line2D([], [], ls="", marker="o", color=CANDIDATE, label=f"{terms['candidates']} ({n})"))
    if result.top_k:
        _top_k(ax, result)
        top = terms["top"].format(k=len(result.top_k))
        handles.append(Line2D([], [], ls="-", color=TOP_K, lw=2, label=top) if result.method == "paper" else
                       Line2D([], [], ls="", marker="o", ms=8, mfc="none", mec=TOP_K, mew=2, label=top,
                              path_effects=[withStroke(linewidth=4, foreground="black")]))
    if result.map_xy is not None:
        ax.plot(*result.map_xy, marker="+", ms=14, mew=2.5, color=TOP_K, zorder=5)
        handles.append(Line2D([], [], ls="", marker="+", ms=10, mew=2, color=TOP_K, label=terms["best"]))
    if result.method == "profile" and result.alternative is not None:
        ax.plot(result.alternative[0], result.alternative[1], marker="D", ms=8, color=CANDIDATE, mec="black", zorder=5)
        margin = f" (margin {units.ratio(result.margin)})" if result.margin is not None else ""
        handles.append(Line2D([], [], ls="", marker="D", color=CANDIDATE, mec="black",
                              label=f"best distinct alternative{margin}"))
    if truth is not None:
        ax.plot(*truth, marker="*", ms=16, mfc=TRUTH, mec="white", mew=1.0, zorder=7)
        handles.append(Line2D([], [], ls="", marker="*", ms=12, mfc=TRUTH, mec="white", label="ground truth"))
    ax.set_title(title or _summary(result, truth, resolution))
    swatches = [Rectangle((0, 0), 1, 1, fc=np.asarray(rgb) / 255.0, ec="0.3", label=name) for name, rgb in classes]
    legend_below(fig, handles + swatches)
    return ax


def _top_k(ax: Axes, result: Localization) -> None:
    """The top-k, numbered by rank (1 drawn last, on top): the paper method's as the squares of
    its windows, the profile method's (a position, no window) as rings."""
    half = result.window / 2.0
    for r, (x, y, _) in reversed(list(enumerate(result.top_k))):
        if result.method == "paper":
            ax.add_patch(Rectangle((x - half, y - half), result.window, result.window, fill=False,
                                   ec=TOP_K, lw=3.0 if r == 0 else 1.5, zorder=4))
            corner = (x - half, y - half)
        else:
            ax.plot(x, y, marker="o", ms=12 if r == 0 else 9, mfc="none", mec=TOP_K, mew=2.5 if r == 0 else 1.8,
                    zorder=4, path_effects=[withStroke(linewidth=4.5 if r == 0 else 3.8, foreground="black")])
            corner = (x, y)
        ax.annotate(str(r + 1), corner, xytext=(2, -2) if result.method == "paper" else (6, -6),
                    textcoords="offset points", ha="left", va="top", color="white", fontsize=8, fontweight="bold",
                    zorder=6, bbox={"boxstyle": "round,pad=0.15", "fc": TOP_K, "ec": "none"})


def localization_png(path: Path | str, result: Localization, aerial: Landmarks, *, image: np.ndarray | None = None,
                     truth: tuple[float, float] | None = None, resolution: float | None = None,
                     title: str | None = None, classes: Sequence[tuple[str, Sequence[int]]] = ()) -> Path:
    """The aerial image with the method's answer in its own terms (:data:`TERMS`) and the truth.

    ``image`` is the aerial RGB image or a colourised mask (``(H, W[, 3])``, the landmarks'
    size); without it a grey canvas. ``classes``: ``(name, rgb)`` of a colourised mask's
    classes, added to the legend. The paper method's candidates are window centres, its top-k
    drawn as squares of the result's window size; the profile method's are the positions of its
    finest grid, its top-k and best position marked, with its best distinct alternative. The
    title says how many there are, the ties and the answer's error to ``truth`` (px, and m with
    ``resolution`` in metres per pixel), or that the query is unanswered and why.
    """
    with _figure(*_size(aerial.width, aerial.height, extra=0.9)) as fig:
        draw_localization(fig, result, aerial, image=image, truth=truth, resolution=resolution, title=title,
                          classes=classes)
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


def draw_graph(fig: Figure, lm: Landmarks, adjacency: np.ndarray, *, image: np.ndarray | None = None,
               title: str | None = None, colours: Mapping[str, Sequence[int]] | None = None,
               classes: Sequence[tuple[str, Sequence[int]]] = ()) -> Axes:
    """:func:`graph_png`'s picture on ``fig``; returns its axes."""
    k = len(lm.xy)
    adj = np.asarray(adjacency)
    if adj.shape != (k, k):
        raise ConfigError(f"adjacency of shape {adj.shape} does not match {k} landmarks")
    w, h = lm.width, lm.height
    palette = landmark_palette(lm.classes, colours)
    ax = fig.add_subplot()
    _background(ax, image, w, h)
    segments = _segments(lm, adj)
    ax.add_collection(LineCollection(list(segments), colors="0.25", linewidths=0.6, alpha=0.6, zorder=2))
    cls = np.asarray(lm.cls, dtype=np.int64)
    if k:
        ax.scatter(lm.xy[:, 0], lm.xy[:, 1], s=28, c=[palette[c] for c in cls], edgecolors="black",
                   linewidths=0.6, zorder=3)
    present = sorted(set(cls.tolist()))
    handles: list[Any] = [Line2D([], [], ls="", marker="o", mfc=palette[c], mec="black", label=lm.classes[c]) for c in present]
    handles.append(Line2D([], [], color="0.25", lw=1, label="covisible"))
    dots = {palette[c] for c in present}  # a colour a landmark's dot names needs no swatch of its own
    handles += [Rectangle((0, 0), 1, 1, fc=np.asarray(rgb[:3]) / 255.0, ec="0.3", label=name) for name, rgb in classes
                if "#{:02x}{:02x}{:02x}".format(*(int(v) for v in rgb[:3])) not in dots]
    n_edges = int(np.triu(adj.astype(bool), k=1).sum())
    ax.set_title(title or f"{k} landmarks, {n_edges} edges" + (" (panorama)" if lm.panorama else ""))
    legend_below(fig, handles, columns=6)
    return ax


def graph_png(path: Path | str, lm: Landmarks, adjacency: np.ndarray, *, image: np.ndarray | None = None,
              title: str | None = None, colours: Mapping[str, Sequence[int]] | None = None,
              classes: Sequence[tuple[str, Sequence[int]]] = ()) -> Path:
    """``lm``'s landmark graph over ``image``: class-coloured dots, grey edges, a class legend.

    ``adjacency`` is the ``(K, K)`` binary landmark adjacency (:func:`localization.paper.graph.adjacency`);
    ``colours``: each landmark class's RGB in the class table of the image's mask
    (:func:`~localization.common.landmarks.landmark_colours`), so a dot has the colour of the
    mask under it and of its class in every other picture. ``classes``: ``(name, rgb)`` of the
    classes a colourised mask ``image`` shows (a rendered panorama's sky, unlabeled ground, ...),
    added to the legend as swatches, but for a colour a landmark's dot there already names.
    """
    with _figure(*_size(lm.width, lm.height, extra=0.7)) as fig:
        draw_graph(fig, lm, adjacency, image=image, title=title, colours=colours, classes=classes)
        return _save(fig, path)


def draw_region(fig: Figure, result: Any, table: ClassTable, truth: tuple[float, float] | None = None,
                error_m: float | None = None) -> Axes:
    """:func:`region_png`'s picture on ``fig``; returns its axes."""
    if result.overview is None or result.overview_bounds is None:
        raise ConfigError("the region result has no overview to draw")
    w, s, e, n = result.overview_bounds
    ax = fig.add_subplot()
    ax.imshow(table.colorize(result.overview), extent=(w, e, s, n), interpolation="nearest")
    ax.set_aspect(1 / np.cos(np.radians((s + n) / 2)))
    ax.set_xlabel("longitude (°)")
    ax.set_ylabel("latitude (°)")
    degree_axis(ax.xaxis)
    degree_axis(ax.yaxis)
    handles: list[Any] = []
    for rank, a in reversed(list(enumerate(result.answers, start=1))):
        ax.plot(a.lon, a.lat, marker="o", ms=9 if rank == 1 else 6, color=TOP_K, mec="black", zorder=4)
        ax.annotate(str(rank), (a.lon, a.lat), xytext=(4, 4), textcoords="offset points", fontsize=8, zorder=5)
    if result.answers:
        handles.append(Line2D([], [], ls="", marker="o", color=TOP_K, mec="black", label="answers, ranked"))
    if result.alternative is not None:
        alt = result.alternative
        ax.plot(alt.lon, alt.lat, marker="D", ms=7, color=CANDIDATE, mec="black", zorder=4)
        handles.append(Line2D([], [], ls="", marker="D", color=CANDIDATE, mec="black",
                              label=f"best distinct alternative (margin {units.ratio(result.margin)})"))
    title = result.headline(error_m)
    if truth is not None:
        ax.plot(*truth, marker="*", ms=13, color=TRUTH, mec="black", zorder=6)
        handles.append(Line2D([], [], ls="", marker="*", color=TRUTH, mec="black", label="truth"))
    present = set(np.unique(result.overview).tolist())
    handles += [Patch(color=tuple(v / 255 for v in c.color[:3]), label=c.name)  # type: ignore[arg-type]
                for c in table.classes if c.id in present]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    ax.set_title(title, fontsize=10)
    return ax


def region_png(path: Path | str, result: Any, table: ClassTable, truth: tuple[float, float] | None = None,
               error_m: float | None = None) -> Path:
    """The searched region (its OSM as drawn, in class colours) with the answers ranked, the
    best distinct alternative and the truth, on axes in plain degrees, with a legend; a region
    with no answer says "unanswered". ``result``: a :class:`localization.region.search.RegionResult`
    (which imports this module, not the reverse); ``error_m``: the answer's distance from the
    truth, for the title."""
    if result.overview is None or result.overview_bounds is None:
        raise ConfigError("the region result has no overview to draw")
    h, wd = result.overview.shape
    with _figure(*_size(wd, h, extra=1.6)) as fig:
        draw_region(fig, result, table, truth, error_m)
        return _save(fig, path)
