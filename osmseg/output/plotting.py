"""Matplotlib figures for osmseg's pictures, without pyplot's global state.

Every picture module (training curves and panels, localization maps) draws on a Figure with
its own Agg canvas inside a style context, and saves PNG bytes with no software stamp through
an atomic write, so the same input gives the same file and nothing leaks between pictures.
Import this module lazily: matplotlib is only needed for pictures.
"""

from __future__ import annotations

import io
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from osmseg.output.atomic import atomic_write_bytes

if TYPE_CHECKING:  # matplotlib >= 3.8 names its rcParams keys; older releases run without it
    from matplotlib.typing import RcKeyType

DPI = 100
STYLE: dict[RcKeyType, Any] = {"font.size": 9, "axes.titlesize": 10, "figure.titlesize": 11,
                               "image.interpolation_stage": "rgba"}


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


def save_png(fig: Figure, path: Path | str) -> Path:
    """Render ``fig`` to PNG in memory (no timestamp/software stamp) and write it atomically."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None}, facecolor="white")
    return atomic_write_bytes(Path(path), buf.getvalue())
