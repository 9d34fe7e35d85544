"""The networks: SegNet and the AirSegNet presets (:mod:`~training.models.networks`), the
architectures by name and what a checkpoint records of one (:mod:`~training.models.spec`), and
unet-lite0 on its packaged ImageNet weights (:mod:`~training.models.lite0`).

Imports: the osmseg core, :mod:`training.devices` and :mod:`training.errors`. The checkpoint a
run writes is read here (:mod:`~training.models.checkpoint`): every room above rebuilds its
network from one.
"""
