"""osmseg: aerial segmentation datasets from OpenStreetMap, SegNet models and
ground-to-aerial localization by landmark graphs.

This package is the core layer: areas, grids, class tables, OSM, imagery, image I/O, output
and the dataset builder (:mod:`osmseg.builder`), with its command line. ``training`` builds on it and
``localization`` on both; the core imports neither (checked by ``lint-imports``). The library
never configures logging and never draws: only the command line (``osmseg.cli``) does.
Imports: the standard library and third-party packages only.
"""

__version__ = "0.5.0"
