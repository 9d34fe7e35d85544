"""The profile method (beyond the paper): class-wise angular profiles on a dense grid, coarse to fine.

:mod:`~localization.profile.profiles` turns a query view and an aerial mask or landmarks into
profiles (which class is seen first at each azimuth and ground distance),
:mod:`~localization.profile.search` scores every position of a grid coarse to fine with the
heading known or searched, and gives kappa and a confidence, and
:mod:`~localization.profile.horizon` reads a tilted camera's pitch and roll from its view.

Imports: osmseg core and :mod:`localization.common`; never the paper's method, its peer
(checked by ``lint-imports``).
"""
