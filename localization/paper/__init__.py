"""The paper's method: landmark-graph matching (Verde, Resek, Milani & Rocha 2020; Resek 2022, ch. 3).

:mod:`~localization.paper.graph` builds a landmark graph from a sliding covisibility window
(:mod:`~localization.paper.windows` holds the window arithmetic, :mod:`~localization.paper.cells`
the component-landmark sweep), :mod:`~localization.paper.match` matches the query's graph
against candidate sub-graphs of the aerial one, :mod:`~localization.paper.refine` adds the
window hierarchy (eq. 3.8) and feature-based edge removal, with the features of
:mod:`~localization.paper.features` (a SegNet encoder's output at each landmark).

Imports: osmseg core, training (features only) and :mod:`localization.common`; never the
profile method, its peer (checked by ``lint-imports``).
"""
