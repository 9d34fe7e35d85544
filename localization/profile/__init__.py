"""The profile method (beyond the paper): class-wise angular profiles on a dense grid, coarse to fine.

:mod:`~localization.profile.profiles` turns a query view and an aerial mask or landmarks into
profiles (which class is seen first at each azimuth and ground distance),
:mod:`~localization.profile.search` scores the positions of a grid with the heading known or
searched, :mod:`~localization.profile.locate` runs that search coarse to fine and gives kappa
and a confidence, :mod:`~localization.profile.horizon` reads a tilted camera's pitch and roll
from its view, :mod:`~localization.profile.null` scrambles a query into its null hypothesis
(the same contents, no place's arrangement), and :mod:`~localization.profile.method` holds the method's entry points (an
aerial side indexed once, a query's profile, a localization).

Imports: osmseg core and :mod:`localization.common`; never the paper's method, its peer
(checked by ``lint-imports``).
"""
