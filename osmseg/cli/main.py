"""The ``osmseg`` command: a click group, with each package's commands as plugins (as rasterio's ``rio``).

The core's own commands (``build``, ``verify``: :data:`CORE_COMMANDS`) are named here; ``train``, ``predict`` and
``eval`` (:mod:`training.cli`), ``localize`` (:mod:`localization.cli.localize`), ``localize-region``
(:mod:`localization.cli.region`), ``localize-bench``
and ``localize-pairs`` (:mod:`localization.cli.bench`) and ``demo`` (:mod:`localization.cli.demo`)
register themselves through the ``osmseg.commands``
entry points of pyproject.toml, so the core never imports the packages above it. A command is
imported only when it runs or a listing (``osmseg --help``) asks for it (:class:`PluginGroup`):
``osmseg build`` does not load torch or the localization methods. A plugin that fails to load
shows up as a command that says why (click-plugins' ``BrokenCommand``).

Every command also takes ``-v``, ``-q`` and ``--progress`` after its name
(:func:`osmseg.cli.common.output_options`), and shows its defaults in ``--help`` (the group's
``show_default``, inherited by every command). Only the CLI configures logging. Data (paths,
JSON) goes to stdout; logs, progress and summaries go to stderr. Exit status: 0 success, 1 failure, 2 usage error.
"""

from __future__ import annotations

from importlib.metadata import EntryPoint, entry_points

import click
from click_plugins.core import BrokenCommand

from osmseg import __version__
from osmseg.cli.common import configure_logging
from osmseg.cli.drawers import PROGRESS_DEFAULT, progress_mode
from osmseg.cli.options import PROGRESS, QUIET, VERBOSE

#: the entry-point group other packages register ``osmseg`` subcommands in
PLUGIN_GROUP = "osmseg.commands"

#: the core's own commands, loaded as the plugins are (when asked for)
CORE_COMMANDS = {"build": "osmseg.cli.build:build_command", "verify": "osmseg.cli.verify:verify_command"}


class PluginGroup(click.Group):
    """A click group whose plugin commands (entry points of :data:`PLUGIN_GROUP`) are imported when
    first asked for, not when the group is: each command's start pays for its own imports only.

    A plugin that raises on import becomes a command that prints the traceback and exits 1 (as
    click-plugins' ``with_plugins`` does), so one broken package does not take the others down.
    """

    _found: dict[str, EntryPoint] | None = None

    def _plugins(self) -> dict[str, EntryPoint]:
        """The commands by name (read once: scanning the installed packages' entry points costs
        tens of milliseconds)."""
        if self._found is None:
            core = (EntryPoint(name, value, PLUGIN_GROUP) for name, value in CORE_COMMANDS.items())
            self._found = {e.name: e for e in (*core, *entry_points(group=PLUGIN_GROUP))}
        return self._found

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(set(self.commands) | set(self._plugins()))

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name not in self.commands:
            plugin = self._plugins().get(cmd_name)
            if plugin is None:
                return None
            try:
                command = plugin.load()
            except Exception:
                command = BrokenCommand(cmd_name)
            self.add_command(command, cmd_name)
        return self.commands[cmd_name]


@click.group(cls=PluginGroup, context_settings={"help_option_names": ["-h", "--help"], "show_default": True})
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


if __name__ == "__main__":  # pragma: no cover
    cli()
