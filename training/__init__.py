"""Training, inference and evaluation of SegNet models on osmseg datasets (AirSegNet6/13).

Its modules stand in rooms by role, as torchgeo's do, each importing only the rooms below it
(``lint-imports`` checks it):

=============================  ==========================================================
:mod:`training.cli`            ``osmseg train``, ``predict``, ``eval``
:mod:`training.run`            a training run: settings, recipe, loops, run files
:mod:`training.evaluation`     metrics, pictures, ``osmseg eval``
:mod:`training.inference`      a network over images of any size, into mask files
:mod:`training.datasets`       image/label pairs, splits by area, crops, augmentation
:mod:`training.models`         SegNet, AirSegNet, unet-lite0; checkpoints
:mod:`training.devices`,       CPU, CUDA and DDP process groups; training's errors
:mod:`training.errors`
=============================  ==========================================================

Imports: the osmseg core only (never :mod:`localization`).
"""
