"""The ``osmseg`` command line: the executable (:mod:`osmseg.cli.launch`: starts a build's fork
server before the group is imported), the group (:mod:`osmseg.cli.main`), the core's own commands
(``build``, ``verify``, ``bing-key``) and what every command shares (:mod:`osmseg.cli.common`:
logging set-up, progress bars, errors as exit codes 1 and 2; :mod:`osmseg.cli.options`: every
option declared once, one name for one meaning across all commands).

The commands of ``training`` and ``localization`` live in those packages (``training.cli``,
``localization.cli.localize``, ``localization.cli.bench``, ``localization.cli.demo``) and join the group as plugins through the
``osmseg.commands`` entry points, so this package never imports them. It is the only place
that configures logging or draws progress. Imports: osmseg core only.
"""
