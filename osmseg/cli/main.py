"""The ``osmseg`` command: a click group, with each package's commands as plugins (as rasterio's ``rio``).

The core's own commands (``build``, ``verify``) are added here; ``train``, ``predict`` and
``eval`` (:mod:`training.cli`), ``localize`` (:mod:`localization.cli.localize`), ``localize-region``
(:mod:`localization.cli.region`), ``localize-bench``
and ``localize-pairs`` (:mod:`localization.cli.bench`) and ``demo`` (:mod:`localization.cli.demo`)
register themselves through the ``osmseg.commands``
entry points of pyproject.toml and are loaded by click-plugins, so the core never imports the
packages above it. A plugin that fails to load shows up as a command that says why.

Every command also takes ``-v``, ``-q`` and ``--progress`` after its name
(:func:`osmseg.cli.common.output_options`), and shows its defaults in ``--help`` (the group's
``show_default``, inherited by every command). Only the CLI configures logging. Data (paths,
JSON) goes to stdout; logs, progress and summaries go to stderr. Exit status: 0 success, 1 failure, 2 usage error.
"""

from __future__ import annotations

from importlib.metadata import entry_points

import click
from click_plugins import with_plugins

from osmseg import __version__
from osmseg.cli.build import build_command
from osmseg.cli.common import configure_logging
from osmseg.cli.drawers import PROGRESS_DEFAULT, progress_mode
from osmseg.cli.options import PROGRESS, QUIET, VERBOSE
from osmseg.cli.verify import verify_command

#: the entry-point group other packages register ``osmseg`` subcommands in
PLUGIN_GROUP = "osmseg.commands"


@with_plugins(sorted(entry_points(group=PLUGIN_GROUP), key=lambda e: e.name))  # type: ignore[untyped-decorator]
@click.group(context_settings={"help_option_names": ["-h", "--help"], "show_default": True})
@click.version_option(__version__, "--version", prog_name="osmseg")
@VERBOSE(show_default=False)
@QUIET(show_default=False)
@PROGRESS(default=None, show_default=PROGRESS_DEFAULT)
@click.pass_context
def cli(ctx: click.Context, verbose: int, quiet: int, progress: bool | None) -> None:
    """osmseg: aerial segmentation datasets from OpenStreetMap, and what to do with them."""
    verbosity = verbose - quiet
    configure_logging(verbosity)
    ctx.obj = {"verbosity": verbosity, "progress_asked": progress, "progress": progress_mode(progress, verbosity)}


cli.add_command(build_command)
cli.add_command(verify_command)

if __name__ == "__main__":  # pragma: no cover
    cli()
