"""A training run: its settings (:mod:`~training.run.config`), how it learns
(:mod:`~training.run.recipe`, :mod:`~training.run.fitting`), the loops
(:mod:`~training.run.engine`) on one device or several (:mod:`training.devices`), the files it
writes and resumes from (:mod:`~training.run.files`; checkpoints: :mod:`training.models.checkpoint`), and
the run itself (:mod:`~training.run.train`, behind ``osmseg train``).

Imports: the osmseg core and training's datasets, models and evaluation rooms, and
:mod:`training.devices`.
"""
