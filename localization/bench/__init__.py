"""The benchmarks: how well the methods localize, measured on views neither method drew.

Two protocols: :mod:`~localization.bench.rendered` renders ground views from seeded viewpoints
of an aerial mask or dataset (``osmseg localize-bench``), with the mask renderer
:mod:`~localization.bench.render` or the independent geometry renderer
:mod:`~localization.bench.georender` (3-D prisms and tree crowns in metres, from OSM:
:mod:`~localization.bench.georender_osm`, set up by :mod:`~localization.bench.geobench`);
:mod:`~localization.bench.pairs` scores annotated aerial/ground pairs. Both run the methods
side by side through :mod:`~localization.bench.compare`, score them with
:mod:`~localization.bench.scores` (errors, recall, chance and simple baselines) and draw with
:mod:`~localization.bench.plots`; :mod:`~localization.bench.visible` says which aerial
landmarks a rendered view shows.

Imports: osmseg core, :mod:`localization.common`, both methods and :mod:`localization.pipeline`;
never the command line.
"""
