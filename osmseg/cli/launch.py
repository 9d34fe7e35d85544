"""The ``osmseg`` executable: start the build's fork server first, then import and run the group.

Importing the command line takes about 0.7 s (numpy, pyproj, rasterio, OpenCV, osmium), and so
does the fork server that ``osmseg build --workers N`` makes its workers from
(:mod:`osmseg.runtime.processes`). Started from the builder, the server imports only once the command
has finished importing, and the workers begin that much later. This entry point reads just
enough of the command line to see a build with several workers coming, starts the server, and
only then imports :mod:`osmseg.cli.main` and the module of the command named (the group loads
each command when asked for it), so the two import side by side on two cores, and a Ctrl-C or
SIGTERM during the imports ends in the command's one line and status.

Reading the line is a guess that never changes what runs: click still parses it in full, and a
wrong guess costs only an idle server, which ends with the command (or 0.4 s later workers).
The group's own options (``-v``, ``-q``, ``--progress``) take no value, so the first word that
is not an option names the command. Imports: the standard library and :mod:`osmseg.runtime.processes`
before the group; the group after.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from osmseg.runtime.processes import (
    INTERRUPTED,
    TERMINATED,
    Terminated,
    available_cores,
    quiet_resource_tracker,
    signals_held,
    start_fork_server,
    terminate_by_exception,
    use_private_temp_dir,
)

__all__ = ["builds_with_workers", "main"]


def builds_with_workers(args: Sequence[str], cores: int | None = None) -> bool:
    """Whether ``osmseg ARGS`` is a build that will want worker processes.

    >>> builds_with_workers(["-q", "build", "--city", "Berlin", "--out", "b"], cores=2)
    True
    >>> builds_with_workers(["build", "--workers", "1", "--out", "b"], cores=8)
    False
    >>> builds_with_workers(["build", "--workers=4", "--out", "b"], cores=1)
    True
    >>> builds_with_workers(["build", "--out", "b"], cores=1), builds_with_workers(["build", "--help"], cores=8)
    (False, False)
    >>> builds_with_workers(["verify", "build"], cores=8), builds_with_workers([], cores=8)
    (False, False)
    """
    if command_word(args) != "build" or "--help" in args or "-h" in args:
        return False
    workers = None
    for i, arg in enumerate(args):
        if arg == "--workers" and i + 1 < len(args):
            workers = args[i + 1]
        elif arg.startswith("--workers="):
            workers = arg.split("=", 1)[1]
    try:
        wanted = int(workers) if workers is not None else 0
    except ValueError:
        return False  # click will say what is wrong with it
    if wanted == 0:  # the default: every core this process may use
        wanted = available_cores() if cores is None else cores
    return wanted > 1


def command_word(args: Sequence[str]) -> str | None:
    """The command ``osmseg ARGS`` names: the first word that is not an option (the group's own
    options take no value), or None.

    >>> command_word(["-q", "--no-progress", "localize", "--help"]), command_word(["-v"])
    ('localize', None)
    """
    return next((a for a in args if not a.startswith("-")), None)


def main() -> None:
    """Run the ``osmseg`` command line (console script ``osmseg``, ``python -m osmseg``).

    Before anything else: a SIGTERM becomes an exception that unwinds the command like a Ctrl-C
    (temporary files removed, workers stopped) and ends it with one line and exit 143; the run
    gets its own temporary folder, removed at its end (or by the next run after a ``kill -9``);
    the resource tracker keeps its warnings about what a killed build held to itself.
    """
    terminate_by_exception()
    try:
        use_private_temp_dir()
        quiet_resource_tracker()
        if builds_with_workers(sys.argv[1:]):
            try:
                start_fork_server()
            except OSError:  # no room for its socket, no file descriptors left: the build tries again, and says why
                pass
        with signals_held():  # not inside a compiled module's start (see signals_held)
            import click

            from osmseg.cli.main import cli  # after the server has started: the reason for this module

            word = command_word(sys.argv[1:])  # its command's imports too, before click catches a Ctrl-C
            if word is not None:
                cli.get_command(click.Context(cli), word)
    except KeyboardInterrupt:  # Ctrl-C before the command runs: the line and exit status of one, no traceback
        _end(INTERRUPTED, 130)
    except Terminated:
        _end(TERMINATED, 143)
    try:
        cli()
    except Terminated:  # what report_errors does not see: a SIGTERM while click parses the line
        _end(TERMINATED, 143)


def _end(line: str, status: int) -> None:
    print(line, file=sys.stderr)
    sys.exit(status)
