"""Scores and pictures of predictions: confusion matrices and IoU (:mod:`~training.evaluation.metrics`),
panels, curves and matrices drawn (:mod:`~training.evaluation.figures`), and ``osmseg eval``
(:mod:`~training.evaluation.evaluate`).

Imports: the osmseg core and training's datasets, models and inference rooms.
"""
