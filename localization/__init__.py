"""Where was a 360° ground panorama taken inside an aerial image? Landmark-graph matching.

The method of T. Resek's dissertation (UNICAMP 2022, chapter 3) and Verde, Resek, Milani &
Rocha, "Ground-to-Aerial Viewpoint Localization via Landmark Graphs Matching" (IEEE Signal
Processing Letters, 2020). Both images -- the aerial one and the panorama -- are reduced to
a few labelled landmarks, each to a graph of which landmarks are seen together, and the
panorama's graph is compared with sub-graphs of the aerial one. The pipeline, one module a
step:

1. :mod:`localization.landmarks` -- **landmarks**: from a segmentation mask (connected
   components per landmark class, as centroids, grid points or whole components) or from a
   landmark file (``x y Class`` lines, CSV, ``.npy``; :mod:`localization.landmark_files`). A class dictionary
   (``data_manifests/landmarks-*.toml``) says which mask classes become the four landmark
   classes: building, road, vegetation, footway. :class:`~localization.landmarks.Landmarks`
   is the data model every other step takes.
2. :mod:`localization.graph` -- **landmark graph**: a square covisibility window slides over
   the image (wrapping around a panorama); each position's landmarks form a clique;
   ``A = H(Cᵀ C)``. :func:`~localization.graph.cliques_fast` gives exactly the cliques of the
   paper's plain sliding window (:func:`~localization.graph.cliques_reference`) in
   milliseconds; the window size is given or automatic (mean + 5 sigma of nearest-neighbour
   distances).
3. :mod:`localization.match` -- **matching**: candidate sub-graphs of the aerial graph (cliques
   holding every class the panorama shows, extended by overlapping cliques), class adjacency
   matrices, normalised cross-correlation, posterior over candidate positions, MAP and top-k
   (:mod:`localization.result`: the ranking, ties and the answer). :mod:`localization.refine`
   adds the dissertation's options: the window hierarchy (eq. 3.8) and feature-based edge removal,
   with features (a SegNet encoder's output at each landmark) from :mod:`localization.features`.
4. :mod:`localization.render`, :mod:`localization.figures`, :mod:`localization.evaluate`,
   :mod:`localization.pairs` -- **render / figures / evaluation**: semantic panoramas rendered
   from aerial masks (real panoramas paired with aerial images are not available offline), the
   paper's figures (candidates and top-k on the aerial image, both graphs overlaid), and the
   two evaluations: rendered panoramas from seeded viewpoints (``osmseg localize-bench`` on a
   dataset or mask) and annotated aerial/ground pairs (``localize-bench`` on a pairs folder),
   with their error plots (:mod:`localization.evaluate_plots`). :mod:`localization.georender`
   is a second renderer that shares no code with the first or with the methods: ground views
   ray-cast over 3-D geometry in metres (prisms with their own base and top, see-through tree
   crowns, a tilted camera), so a benchmark is not drawn only by the model it measures.

5. :mod:`localization.profile`, :mod:`localization.search`, :mod:`localization.compare` --
   **the profile method** (beyond the paper, ``--method profile``): the query's class-wise
   angular profile (which class is seen first at each azimuth and ground distance) against
   the profile the aerial mask or landmarks predict at every position of a dense grid, coarse
   to fine, with the heading known or searched by circular cross-correlation, photos of a
   limited field of view, kappa (the best match against chance: "not in this image") and a
   confidence (how far the answer stands out from the best place 50 m or more away: "not
   sure" when a look-alike fits as well); :mod:`localization.horizon` reads a tilted camera's
   pitch and roll from where the query's sky meets its ground; :mod:`localization.compare` runs
   the methods side by side in the benchmarks and :mod:`localization.scores` turns their
   answers into errors, recall and baselines.
   (:mod:`localization.windows` and :mod:`localization.cells` hold the window arithmetic and
   the component-landmark sweep of :mod:`localization.graph`.)
6. :mod:`localization.region` -- **a region from OpenStreetMap alone** (``osmseg localize
   --osm FILE --bbox W,S,E,N``, command line in :mod:`localization.cli_region`): the region
   drawn by the builder's rasteriser in overlapping blocks (kept and cached by
   :mod:`localization.region_cache`), each searched by the profile method against the
   region's class frequencies, answers in degrees with the best distinct alternative, the
   margin between them and a confidence; split into ``--shard K/N`` parts and merged by
   :mod:`localization.region_files`, which also reads the query and writes the GeoJSON.

Coordinates are pixels throughout: ``x`` is the column, ``y`` the row. numpy and scipy do
the work; only :mod:`localization.features` runs a network, with torch (the ``train`` extra).
:func:`localization.pipeline.run` localizes one query given a :class:`LocalizeConfig`; the
command line (:mod:`localization.cli`), the rendered benchmark and the annotated pairs all
call it. Imports: osmseg core and training (the top layer: nothing imports localization).
"""
