"""OpenStreetMap in: sources that give an OSM file for a box, and the parser that classifies it.

:mod:`osmseg.osm.sources` turns ``--osm SPEC`` into a source (:mod:`.api`, :mod:`.overpass`,
:mod:`.localfile`, :mod:`.geojson`, :mod:`.josm` for JOSM's files), each ending in an OSM file
on disk (:mod:`.base`); :mod:`.features` streams that file once with osmium and returns the
classified features of a sample, projected and clipped (:mod:`.geometry`, coastlines in
:mod:`.coastline`, ids made unique across files by :mod:`.renumber`). Imports: osmseg core
(classes, grid, errors, net, output.atomic); never imagery, training or localization.
"""
