"""Training, inference and evaluation of SegNet models on osmseg datasets (AirSegNet6/13).

The modules form a pipeline: :mod:`training.data` finds image/mask pairs, cuts them into
360x480 patches and computes class weights; :mod:`training.splits` splits them by area
(overlapping samples together); :mod:`training.model` defines SegNet and the AirSegNet
presets; :mod:`training.engine` runs the training and validation loops (CPU or CUDA, AMP,
DDP); :mod:`training.checkpoint` saves and reloads everything needed to use a trained model;
:mod:`training.infer` runs a model over images of any size (split-join or rescale) and
:mod:`training.predict` over image files (PNG or COG masks, at the training resolution if
asked); :mod:`training.metrics` and :mod:`training.figures` score predictions and draw
confusion matrices, qualitative panels and training curves.

Imports: the osmseg core only (never :mod:`localization`).
"""
