"""The shared wing: what both methods, the benchmarks and the command line describe alike.

:mod:`~localization.common.landmarks` (the labelled points an image is reduced to, and the
class dictionaries), :mod:`~localization.common.landmark_files` (annotated ``x y Class``
files), :mod:`~localization.common.views` (a ground view's camera and its pixels in landmark
classes), :mod:`~localization.common.result` (a :class:`~localization.common.result.Localization`:
the ranking, ties and answer either method returns), :mod:`~localization.common.inputs` (reading
one side of a pair: mask, landmark file, RGB, GeoTIFF, dataset sample),
:mod:`~localization.common.figures` (the maps of an answer and a graph) and
:mod:`~localization.common.marks` (the colours of their marks, which the HTML map shares).

Imports: osmseg core and training (when an RGB side is segmented); nothing else of
localization (checked by ``lint-imports``).
"""
