"""The command line of localization: ``osmseg localize``, ``localize-region``, ``localize-bench``, ``localize-pairs``, ``demo``.

Registered as plugins of the ``osmseg`` group (``osmseg.commands`` entry points):
:mod:`~localization.cli.localize` (``localize``: an aerial image), :mod:`~localization.cli.region`
(``localize-region``: a region of OpenStreetMap), :mod:`~localization.cli.bench` (the two
benchmark protocols), :mod:`~localization.cli.options` (the options more than one command takes,
and their parsers), :mod:`~localization.cli.query` (the ground view both localize commands take),
:mod:`~localization.cli.summary` (what a bench prints) and :mod:`~localization.cli.demo`.
Each command builds one typed, frozen request from its options (:mod:`osmseg.cli.requests`),
calls its one library function and prints.

Imports: everything below it (osmseg core, training, every wing of localization); nothing
imports it but the entry points.
"""
