"""A copy of an OSM file whose negative ids (JOSM's objects not yet uploaded) are made positive.

JOSM writes the objects a user drew and has not uploaded with negative ids.  pyosmium's node
location index (``FileProcessor.with_locations()``) ignores negative node ids (libosmium keeps
them only in a second index pyosmium does not set up), so the ways through such nodes have no
geometry, and neither do the multipolygons made of them.  :func:`write_renumbered` streams a
file into a copy without negative ids, changing the node refs of ways and the member refs of
relations alike; readers name objects by :func:`original_id`, the id the user sees in JOSM.

The renumbering keeps the order of the ids, because osmium's multipolygon assembler refuses
ways out of order ("Way IDs out of order").  Osmium's order (``osmium::id_order``, also the
order JOSM writes and ``osmium sort`` makes) is ``-1, -2, ...`` then ``1, 2, ...``: a scheme
that moved only the negative ids (``-k`` to a base above all real ids, plus ``k``) would put
them after the positive ones of a file that mixes downloaded and new objects.  So every id
changes: ``-k`` becomes ``k`` and ``p`` becomes ``RENUMBER_BASE + p``.  With
:data:`RENUMBER_BASE` = 2 * 10**15 (OSM's ids are below 2e10 today; :mod:`osmseg.osm.geojson`
makes ids from 10**15 on) this is one-to-one for every id a file holds, except negative ids
beyond ``-RENUMBER_BASE``, which are refused.

>>> [renumbered_id(i) for i in (-1, -201, 7)]
[1, 201, 2000000000000007]
>>> [original_id(renumbered_id(i)) for i in (-1, -201, 7)]
[-1, -201, 7]
"""

from __future__ import annotations

from pathlib import Path

import osmium

from osmseg.errors import OSMDataError

#: Positive id ``p`` becomes ``RENUMBER_BASE + p`` in the renumbered copy; ``-k`` becomes ``k``.
RENUMBER_BASE = 2 * 10**15


def renumbered_id(osm_id: int) -> int:
    """The id of ``osm_id`` in the renumbered copy (order kept: -1, -2, ... before 1, 2, ...)."""
    return -osm_id if osm_id <= 0 else RENUMBER_BASE + osm_id


def original_id(osm_id: int) -> int:
    """The id in the original file of ``osm_id`` read from a renumbered copy."""
    return osm_id - RENUMBER_BASE if osm_id > RENUMBER_BASE else -osm_id


def write_renumbered(source: osmium.io.File | str, out: Path, name: str) -> int:
    """Stream ``source`` into ``out`` (``.osm.pbf``) renumbered with :func:`renumbered_id`.

    Object order, tags, locations and metadata are kept.  Returns the number of objects with
    a negative id.  Raises ``OSMDataError`` when ``source`` (named ``name`` in the message)
    has an id at or below ``-RENUMBER_BASE``; osmium's read errors arrive as ``RuntimeError``.
    """
    negative = 0
    with osmium.SimpleWriter(osmium.io.File(str(out), "pbf"), overwrite=True) as writer:
        for obj in osmium.FileProcessor(source, osmium.osm.NODE | osmium.osm.WAY | osmium.osm.RELATION):
            if obj.id < 0:
                negative += 1
                if obj.id <= -RENUMBER_BASE:
                    raise OSMDataError(f"OSM file {name} has {obj.type_str()}{obj.id}, a negative id below "
                                       f"-{RENUMBER_BASE}: cannot renumber its negative ids (objects not uploaded "
                                       "from JOSM) to read it; renumber the file with osmium renumber")
            new_id = renumbered_id(obj.id)
            if isinstance(obj, osmium.osm.Node):
                writer.add(obj.replace(id=new_id))
            elif isinstance(obj, osmium.osm.Way):
                writer.add(obj.replace(id=new_id, nodes=[renumbered_id(n.ref) for n in obj.nodes]))
            elif isinstance(obj, osmium.osm.Relation):  # the only kind left: the processor reads no others
                writer.add(obj.replace(id=new_id, members=[(m.type, renumbered_id(m.ref), m.role) for m in obj.members]))
    return negative
