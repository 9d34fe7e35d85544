"""Training data on disk, as the network sees it: image/label pairs found and checked
(:mod:`~training.datasets.patches`), split by area (:mod:`~training.datasets.splits`), drawn as
random crops (:mod:`~training.datasets.sampling`) with flips, turns, zoom and colour jitter
(:mod:`~training.datasets.augment`), and the class table a run learns
(:mod:`~training.datasets.classes`).

Imports: the osmseg core and :mod:`training.models` (the presets' class tables).
"""
