"""Matplotlib figures for osmseg's pictures, without pyplot's global state.

Every picture module (training curves and panels, localization maps) draws on a Figure with
its own Agg canvas inside a style context, and saves PNG bytes with no software stamp through
an atomic write, so the same input gives the same file and nothing leaks between pictures.

What every picture a person reads gets here, once for all of them:

* :func:`save_png` writes the whole drawing: a title wider than its room is wrapped onto more
  lines first (:func:`wrap_titles`), and the PNG holds everything drawn, with a white margin
  (a title above an equal-aspect map, which constrained layout can leave over the top edge,
  included), so no title, legend or label is ever cut off;
* :func:`degree_axis` writes an axis in degrees as plain degrees (``60.172°``), never with an
  offset (``+6.017e1``) or in scientific notation, with as many decimals as its ticks need;
* :func:`legend_below` puts a legend under the axes in as many columns as fit the figure's
  width, so it does not run past the picture's sides.

Import this module lazily: matplotlib is only needed for pictures.
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib
from matplotlib.axis import Axis
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.legend import Legend
from matplotlib.text import Text
from matplotlib.ticker import FuncFormatter, MaxNLocator

from osmseg.output.atomic import atomic_write_bytes

if TYPE_CHECKING:  # matplotlib >= 3.8 names its rcParams keys; older releases run without it
    from matplotlib.typing import RcKeyType

__all__ = ["DPI", "MARGIN_INCHES", "STYLE", "degree_axis", "degree_label", "figure", "legend_below", "save_png",
           "wrap_titles"]

DPI = 100
STYLE: dict[RcKeyType, Any] = {"font.size": 9, "axes.titlesize": 10, "figure.titlesize": 11,
                               "image.interpolation_stage": "rgba"}
#: white margin around everything drawn in a saved picture (inches: 8 px at DPI)
MARGIN_INCHES = 0.08


@contextmanager
def figure(width: float, height: float) -> Iterator[Figure]:
    """A constrained-layout figure of ``width`` x ``height`` inches on an Agg canvas, with our style."""
    with matplotlib.rc_context(STYLE):
        fig = Figure(figsize=(width, height), dpi=DPI, layout="constrained")
        FigureCanvasAgg(fig)
        try:
            yield fig
        finally:
            fig.clear()


def _titles(fig: Figure) -> Iterator[tuple[Text, float]]:
    """Every title of ``fig`` with the width (pixels) it may take: an axes' title its axes' width
    (beside another axes' title it must not run into it), the figure's title the figure's."""
    for ax in fig.axes:
        if ax.title.get_text():
            yield ax.title, ax.get_window_extent().width
    suptitle = getattr(fig, "_suptitle", None)  # matplotlib gives its text (get_suptitle), not the artist
    if isinstance(suptitle, Text) and suptitle.get_text():
        yield suptitle, fig.bbox.width


def _wrapped(text: Text, line: str, room: float, renderer: Any) -> list[str]:
    """``line`` broken into lines no wider than ``room`` pixels as ``text`` draws them, each filled
    in turn: after a semicolon where it can be (a title's clauses stay whole), else at spaces (a
    single word wider than ``room`` keeps a line of its own)."""

    def width(candidate: str) -> float:
        text.set_text(candidate)
        return float(text.get_window_extent(renderer).width)

    def fill(parts: list[str], split: Callable[[str], list[str]] | None) -> list[str]:
        lines: list[str] = []
        current = ""
        for part in parts:
            attempt = f"{current} {part}" if current else part
            if width(attempt) <= room:
                current = attempt
                continue
            if current:
                lines.append(current)
            if split is not None and width(part) > room:
                *whole, current = fill(split(part), None)
                lines += whole
            else:
                current = part
        return [*lines, current]

    clauses = [c + ";" for c in line.split("; ")]
    clauses[-1] = clauses[-1][:-1]
    return fill(clauses, lambda clause: clause.split(" "))


def wrap_titles(fig: Figure) -> None:
    """Wrap every title of ``fig`` wider than its room (:func:`_titles`) onto more lines, at
    spaces, keeping the lines it already has; the layout then makes room for them."""
    fig.draw_without_rendering()  # lays the figure out: the axes' widths are known
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]  # our canvases are Agg (figure())
    for title, room in _titles(fig):
        original = title.get_text()
        title.set_text(original)
        if title.get_window_extent(renderer).width <= room:
            continue
        lines = [part for line in original.split("\n") for part in _wrapped(title, line, room, renderer)]
        title.set_text("\n".join(lines))


def legend_below(fig: Figure, handles: Sequence[Any], columns: int = 5, **options: Any) -> Legend:
    """A legend of ``handles`` under the figure's axes, in as many columns (up to ``columns``) as
    fit in the figure's width: more rows rather than a legend that runs past its sides."""
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]  # our canvases are Agg (figure())
    for n in range(max(1, min(columns, len(handles))), 0, -1):
        legend = fig.legend(handles=handles, loc="outside lower center", ncols=n, frameon=False, **options)
        if n == 1 or legend.get_window_extent(renderer).width <= fig.bbox.width:
            break
        legend.remove()  # matplotlib lays a legend's columns out once: a narrower one is a new legend
    return legend


def save_png(fig: Figure, path: Path | str) -> Path:
    """Render ``fig`` to PNG in memory (no timestamp/software stamp) and write it atomically.

    Titles too wide for their room are wrapped (:func:`wrap_titles`), and the picture is cut
    to everything drawn plus a white margin of :data:`MARGIN_INCHES`: nothing that was drawn
    lies outside it, and no empty band is left around it.
    """
    wrap_titles(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None}, facecolor="white",
                bbox_inches="tight", pad_inches=MARGIN_INCHES)
    return atomic_write_bytes(Path(path), buf.getvalue())


def degree_label(value: float, step: float) -> str:
    """``value`` degrees written with as many decimals as ticks ``step`` degrees apart need to differ.

    >>> degree_label(60.172, 0.001), degree_label(26.95, 0.005), degree_label(24.0, 0.5), degree_label(10.0, 2.0)
    ('60.172°', '26.950°', '24.0°', '10°')
    """
    decimals = max(0, math.ceil(-math.log10(step) - 1e-9)) if step > 0 else 6
    if step > 0 and abs(round(step, decimals) - step) > step * 1e-6:  # 0.25 apart: 2 decimals, not 1
        decimals += 1
    return f"{value:.{decimals}f}°"


def degree_axis(axis: Axis, ticks: int = 6) -> None:
    """Tick ``axis`` (a longitude or latitude axis) in plain degrees: at most ``ticks`` round
    values, each written whole (:func:`degree_label`), with no offset and no scientific notation."""
    axis.set_major_locator(MaxNLocator(nbins=ticks, steps=[1, 2, 2.5, 5, 10]))

    def label(value: float, _pos: int | None) -> str:
        locs = axis.get_major_locator()()
        step = min((b - a for a, b in zip(locs, locs[1:]) if b > a), default=0.0)
        return degree_label(value, float(step))

    axis.set_major_formatter(FuncFormatter(label))
