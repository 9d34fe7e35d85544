"""A trained network over images of any size: by overlapping windows or a rescaled whole
(:mod:`~training.inference.windows`), block by block for large rasters
(:mod:`~training.inference.tiling`), at the training data's ground resolution when asked
(:mod:`~training.inference.resolution`), and over image files into masks
(:mod:`~training.inference.predict`, behind ``osmseg predict``); and a model trained elsewhere
(TorchScript or ONNX) read through a class mapping (:mod:`~training.inference.foreign`).

Imports: the osmseg core, training's datasets and models rooms, and :mod:`training.devices`.
"""
