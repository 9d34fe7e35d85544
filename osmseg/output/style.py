"""A QGIS layer style (``.qml``) beside every class-id GeoTIFF, so QGIS's legend names the classes.

QGIS draws a single-band raster with a colour table as a *paletted* layer, but its legend and
its identify tool label the entries with the pixel values only: the ``CLASS_<id>`` band tags of
:mod:`osmseg.output.geotiff` are shown in the layer's metadata, not in the legend (neither are
GDAL category names). What QGIS does read is a style file with the raster's name and the suffix
``.qml`` in the same folder: when a layer is added, QGIS loads ``NAME.qml`` as the default style
of ``NAME.tif``. :func:`qml_style` writes one with a paletted renderer whose entries are the
class ids, colours and names, so ``geo/NAME.tif`` opens with the legend "0 unlabeled,
1 building, ...", in the class colours, with no osmseg and no plugin. QGIS's own "Create
default paletted raster renderer" tool writes the same kind of sidecar.

The file holds the symbology only (``styleCategories="Symbology"``): loading it leaves every
other layer setting at QGIS's default. Resampling is nearest neighbour (a class id is never
averaged). The bytes depend only on the class table, like every file osmseg writes.

>>> from osmseg.classes import load_class_table
>>> text = qml_style(load_class_table("classes6.toml")).decode()
>>> 'type="paletted"' in text and 'label="dirt road"' in text
True
>>> style_path("geo/berlin_0001.tif")
'geo/berlin_0001.qml'
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import PurePosixPath

from osmseg.classes import ClassTable

#: Suffix of the style file QGIS loads as a raster's default style.
STYLE_SUFFIX = ".qml"
#: The QGIS version the style is written as (QGIS reads styles of older versions).
QGIS_VERSION = "3.22.0"
_DOCTYPE = "<!DOCTYPE qgis PUBLIC 'http://mrcc.com/qgis.dtd' 'SYSTEM'>\n"


def style_path(raster: str) -> str:
    """The relative (POSIX) path of the style file of the raster at ``raster``: same name, ``.qml``."""
    return str(PurePosixPath(raster).with_suffix(STYLE_SUFFIX))


def qml_style(table: ClassTable, band: int = 1) -> bytes:
    """The QGIS style (UTF-8 XML) of a class-id raster of ``table``: a paletted renderer of ``band``
    with one entry per class (value = class id, colour, label = class name), ordered by id."""
    root = ET.Element("qgis", {"version": QGIS_VERSION, "styleCategories": "Symbology"})
    pipe = ET.SubElement(root, "pipe")
    provider = ET.SubElement(pipe, "provider")
    ET.SubElement(provider, "resampling", {"enabled": "false", "zoomedInResamplingMethod": "nearestNeighbour",
                                           "zoomedOutResamplingMethod": "nearestNeighbour", "maxOversampling": "2"})
    renderer = ET.SubElement(pipe, "rasterrenderer", {"type": "paletted", "band": str(band), "opacity": "1",
                                                      "alphaBand": "-1", "nodataColor": ""})
    ET.SubElement(renderer, "rasterTransparency")
    palette = ET.SubElement(renderer, "colorPalette")
    for c in sorted((table.unlabeled, *table.classes), key=lambda c: c.id):
        ET.SubElement(palette, "paletteEntry", {"value": str(c.id), "color": "#{:02x}{:02x}{:02x}".format(*c.color),
                                                "alpha": "255", "label": c.name})
    ET.SubElement(pipe, "brightnesscontrast", {"brightness": "0", "contrast": "0", "gamma": "1"})
    ET.SubElement(pipe, "huesaturation", {"saturation": "0", "grayscaleMode": "0", "colorizeOn": "0",
                                          "colorizeRed": "255", "colorizeGreen": "128", "colorizeBlue": "128",
                                          "colorizeStrength": "100"})
    ET.SubElement(pipe, "rasterresampler", {"maxOversampling": "2"})
    ET.SubElement(root, "blendMode").text = "0"
    ET.indent(root, space="  ")
    return (_DOCTYPE + ET.tostring(root, encoding="unicode") + "\n").encode("utf-8")
