"""The command line of localization: ``osmseg localize``, ``localize-bench``, ``localize-pairs`` and ``demo``.

Registered as plugins of the ``osmseg`` group (``osmseg.commands`` entry points):
:mod:`~localization.cli.commands` (``localize``), :mod:`~localization.cli.bench` (the two
benchmark protocols), :mod:`~localization.cli.options` (their
shared option parsing), :mod:`~localization.cli.region` (the region search's options),
:mod:`~localization.cli.summary` (what a bench prints) and :mod:`~localization.cli.demo`.
Each command parses options, builds a config, calls one library function and prints.

Imports: everything below it (osmseg core, training, every wing of localization); nothing
imports it but the entry points.
"""
