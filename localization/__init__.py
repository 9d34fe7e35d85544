"""Where was a ground view taken inside an aerial image? Two methods, their benchmarks, one entry point.

The paper's method is that of T. Resek's dissertation (UNICAMP 2022, chapter 3) and Verde,
Resek, Milani & Rocha, "Ground-to-Aerial Viewpoint Localization via Landmark Graphs Matching"
(IEEE Signal Processing Letters, 2020): both images are reduced to a few labelled landmarks,
each to a graph of which landmarks are seen together, and the query's graph is compared with
sub-graphs of the aerial one. The profile method (beyond the paper) compares which class is
seen first at each azimuth and ground distance with what the aerial image predicts at every
position of a dense grid. The package is built in wings, one folder each, layered:

==========================  ===============================================================
:mod:`localization.cli`     ``osmseg localize``, ``localize-region``, ``localize-bench``, ``localize-pairs``, ``demo``
:mod:`localization.bench`   the benchmarks: rendered views and annotated pairs, both renderers
:mod:`localization.region`  a region from OpenStreetMap alone, in blocks and shards
:mod:`localization.pipeline` the one entry point: :func:`~localization.pipeline.run` localizes
                            a query with the method its :class:`~localization.pipeline.LocalizeConfig`
                            names, :func:`~localization.pipeline.localize_files` a pair of files
:mod:`localization.paper`   landmark-graph matching (the paper)   | peers: neither imports
:mod:`localization.profile` angular profiles on a dense grid     | the other
:mod:`localization.common`  landmarks, class dictionaries, views, results, inputs, figures
==========================  ===============================================================

Each wing imports only the wings below it (``lint-imports`` checks it: the layers contract in
``pyproject.toml``), and a name starting with ``_`` is used only inside its own wing
(``tests/project/test_code_shape.py`` checks it).
Coordinates are pixels throughout: ``x`` is the column, ``y`` the row. numpy and scipy do the
work; only :mod:`localization.paper.features` runs a network, with torch (the ``train`` extra).
Imports: osmseg core and training (the top layer: nothing imports localization).
"""
