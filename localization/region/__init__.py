"""A region from OpenStreetMap alone: ``osmseg localize-region --osm FILE --bbox W,S,E,N``.

:mod:`~localization.region.search` draws the region in overlapping blocks with the builder's
rasteriser and searches each with the profile method against the region's class frequencies;
:mod:`~localization.region.cache` keeps the drawn blocks; :mod:`~localization.region.files` reads the query, splits the search into ``--shard K/N``
parts, merges them and writes the GeoJSON, the picture and :mod:`~localization.region.webmap`'s
``region.html`` (folium).

Imports: osmseg core, :mod:`localization.common` and :mod:`localization.profile` (the layers
contract would let it use :mod:`localization.pipeline` too); never the benchmarks or the
command line.
"""
