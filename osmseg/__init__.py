"""osmseg: aerial segmentation datasets from OpenStreetMap, SegNet models and
ground-to-aerial localization by landmark graphs.

The package never configures logging; only the command line (``osmseg.cli``) does.
"""

__version__ = "0.1.0"
