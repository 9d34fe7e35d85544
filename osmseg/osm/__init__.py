"""OpenStreetMap in: sources that give an OSM file for a box, and the parser that classifies it.

:mod:`osmseg.osm.sources` turns ``--osm SPEC`` into a source (:mod:`.api`, :mod:`.overpass`,
:mod:`.localfile`, :mod:`.geojson`, :mod:`.josm` for JOSM's files), each ending in an OSM file
on disk (:mod:`.base`); a local file cuts every sample's box of a build in one pass
(:mod:`.cut`). :mod:`.features` streams that file once with osmium and returns the classified
features of a sample, projected and clipped (class decisions memoised per tag look-up and
geometry built in bulk by :mod:`.objects`, :mod:`.geometry`, coastlines in :mod:`.coastline`,
ids made unique across files by :mod:`.renumber`). Imports: osmseg core
(classes, grid, errors, net, output.atomic); never imagery, training or localization.
"""
