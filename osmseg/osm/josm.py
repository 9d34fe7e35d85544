"""OSM XML saved by JOSM: objects the user deleted are still in the file, marked ``action="delete"``.

A user drawing or correcting their own labels in JOSM saves the layer as ``.osm``. Objects they
deleted from downloaded data stay in that file with ``action="delete"`` until the layer is
uploaded, and libosmium (which ignores the ``action`` attribute) would read them as live: labels
the user removed would still be drawn. :func:`without_deleted` writes a copy without them, which
the local-file source then reads. Negative ids (objects not yet uploaded) are handled by
:mod:`osmseg.osm.renumber`.

>>> import tempfile, pathlib
>>> src = pathlib.Path(tempfile.mkdtemp()) / "edit.osm"
>>> _ = src.write_text("<osm version='0.6'><node id='1' lat='0' lon='0'/>"
...                    "<node id='2' action='delete' lat='1' lon='1'/></osm>")
>>> has_deletions(src), without_deleted(src, src.with_name("kept.osm")).read_text().count("<node")
(True, 1)
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

from osmseg.errors import OSMDataError
from osmseg.output.atomic import atomic_path

_DELETED = re.compile(rb"""action\s*=\s*['"]delete['"]""")
#: top-level elements of an OSM XML document
_OBJECTS = ("node", "way", "relation")


def has_deletions(path: Path, chunk: int = 1 << 20) -> bool:
    """True if an uncompressed OSM XML file holds objects marked ``action="delete"`` (a byte scan)."""
    tail = b""
    with open(path, "rb") as f:
        while block := f.read(chunk):
            if _DELETED.search(tail + block):
                return True
            tail = block[-32:]
    return False


def without_deleted(src: Path, dst: Path) -> Path:
    """Write ``src`` to ``dst`` (atomically) without the objects JOSM marked deleted; streams. Returns ``dst``."""
    try:
        with atomic_path(dst) as tmp, open(tmp, "wb") as out:
            depth, root = 0, None
            for event, elem in ET.iterparse(src, events=("start", "end")):
                if event == "start":
                    depth += 1
                    if depth == 1:  # the <osm ...> root, with its attributes
                        root = elem
                        attrs = "".join(f' {k}="{_escape(v)}"' for k, v in elem.attrib.items())
                        out.write(f"<?xml version='1.0' encoding='UTF-8'?>\n<{elem.tag}{attrs}>\n".encode())
                    continue
                depth -= 1
                if depth == 1 and root is not None:  # a top-level object (or <bounds>), complete
                    if not (elem.tag in _OBJECTS and elem.get("action") == "delete"):
                        out.write(ET.tostring(elem, encoding="utf-8", short_empty_elements=True, xml_declaration=False))
                    root.remove(elem)  # stream: keep nothing of what was written
            if root is None:
                raise OSMDataError(f"--osm {src}: empty XML; save it again from JOSM")
            out.write(f"</{root.tag}>\n".encode())
    except ET.ParseError as exc:
        raise OSMDataError(f"--osm {src}: not valid OSM XML ({exc}); save it again from JOSM") from None
    return dst


def _escape(value: str) -> str:
    return value.replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;")


def count_deleted(path: Path) -> int:
    """How many objects of an OSM XML file are marked ``action="delete"``."""
    with open(path, "rb") as f:
        return len(_DELETED.findall(f.read()))
