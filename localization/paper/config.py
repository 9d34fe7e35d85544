"""How the paper's method localizes: one settings object from the command line down to the graphs.

:class:`PaperConfig` holds the windows, the candidate extension's ``p``, the stride, how many
best candidates to keep, which clique builder (the exact event sweep or the paper's plain
sliding window), the window hierarchy and the conventions (ours, or the authors' MATLAB
demo's). :func:`~localization.paper.match.localize`,
:func:`~localization.paper.refine.localize_hierarchical` and
:func:`~localization.paper.match.match_cliques` take it whole, and
:meth:`PaperConfig.cliques` is the one place the clique builder is chosen.

Imports: osmseg.errors, localization.common, localization.paper.graph.
"""

from __future__ import annotations

from dataclasses import dataclass

from localization.common.landmarks import Landmarks
from localization.common.result import DEFAULT_P
from localization.paper.graph import CONVENTIONS, Cliques, cliques_fast, cliques_reference
from osmseg.errors import ConfigError

__all__ = ["HIERARCHY", "PaperConfig"]

#: The dissertation's hierarchy of aerial windows, coarse to fine (pixels).
HIERARCHY = (400, 200, 100)


@dataclass(frozen=True)
class PaperConfig:
    """The settings of the landmark-graph method (the paper's defaults).

    ``window`` None is the automatic window (mean + 5 sd of nearest-neighbour distances,
    :func:`~localization.paper.graph.window_size_auto`); ``query_window`` None is the
    panorama's height (the paper's square window as tall as the image), else the aerial window
    (an aerial crop has the aerial's scale); ``hierarchical`` uses ``windows`` coarse to fine
    (eq. 3.8) instead of one window; ``fast`` builds the cliques by the exact event sweep
    (:func:`~localization.paper.graph.cliques_fast`), False by the paper's plain sliding window.

    >>> PaperConfig(p=0)
    Traceback (most recent call last):
    osmseg.errors.ConfigError: p must be in (0, 1], got 0
    """

    window: int | None = None
    query_window: int | None = None
    p: float = DEFAULT_P
    stride: int = 1
    top_k: int = 5
    fast: bool = True
    hierarchical: bool = False
    windows: tuple[int, ...] = HIERARCHY
    conventions: str = "osmseg"  # or "authors": their MATLAB demo's windows, positions and tie-break

    def __post_init__(self) -> None:
        if not 0 < self.p <= 1:
            raise ConfigError(f"p must be in (0, 1], got {self.p}")
        if self.top_k < 1:
            raise ConfigError(f"top_k must be at least 1, got {self.top_k}")
        if self.stride < 1:
            raise ConfigError(f"stride must be at least 1 pixel, got {self.stride}")
        if self.conventions not in CONVENTIONS:
            raise ConfigError(f"conventions must be one of {', '.join(CONVENTIONS)}, got {self.conventions!r}")
        if self.conventions == "authors" and self.hierarchical:
            raise ConfigError("the authors' conventions are those of their demo: one window, no feature edges")
        for name, value in (("window", self.window), ("query_window", self.query_window)):
            if value is not None and value < 1:
                raise ConfigError(f"{name} must be at least 1 pixel, got {value}")
        if not self.windows or min(self.windows) < 1:
            raise ConfigError(f"windows must be positive pixel sizes, coarse to fine, got {list(self.windows)}")

    def cliques(self, lm: Landmarks, window: int) -> Cliques:
        """``lm``'s cliques at ``window`` pixels, with this config's builder, stride and conventions."""
        build = cliques_fast if self.fast else cliques_reference
        return build(lm, window, self.stride, self.conventions)

    def query_window_for(self, query: Landmarks, aerial_window: int) -> int:
        """The query's window: :attr:`query_window`, else a panorama's height, else the aerial window."""
        if self.query_window is not None:
            return int(self.query_window)
        return query.height if query.panorama else aerial_window
