"""The ``osmseg`` command: a click group with one module per subcommand (as rasterio's ``rio``).

Only the CLI configures logging. Data (paths, JSON) goes to stdout; logs, progress and
summaries go to stderr. Exit status: 0 success, 1 failure, 2 usage error.
"""

from __future__ import annotations

import functools
import logging
import sys
from typing import Any, Callable, TypeVar

import click

from osmseg import __version__
from osmseg.errors import ConfigError, OsmsegError

F = TypeVar("F", bound=Callable[..., Any])


def configure_logging(verbosity: int) -> None:
    """Send log records to stderr: -q errors only, default warnings, -v info, -vv debug."""
    level = {0: logging.WARNING, 1: logging.INFO}.get(verbosity, logging.DEBUG if verbosity > 1 else logging.ERROR)
    logging.basicConfig(stream=sys.stderr, level=level, format="%(levelname)s %(name)s: %(message)s")
    # third-party chatter stays at WARNING unless -vv
    for name in ("urllib3", "requests_cache", "vcr", "rasterio", "PIL"):
        logging.getLogger(name).setLevel(logging.DEBUG if verbosity >= 3 else logging.WARNING)


def report_errors(func: F) -> F:
    """Turn osmseg errors into one line on stderr: exit 2 for usage/config errors, 1 otherwise."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except ConfigError as exc:
            raise click.UsageError(str(exc)) from None
        except OsmsegError as exc:
            raise click.ClickException(str(exc)) from None
        except KeyboardInterrupt:
            click.echo("interrupted: rerun the same command to resume; finished work is kept", err=True)
            sys.exit(130)

    return wrapper  # type: ignore[return-value]


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, "--version", prog_name="osmseg")
@click.option("-v", "--verbose", count=True, help="More log output on stderr (-vv for debug).")
@click.option("-q", "--quiet", count=True, help="Less output on stderr: only errors, no progress bar.")
@click.pass_context
def cli(ctx: click.Context, verbose: int, quiet: int) -> None:
    """osmseg: aerial segmentation datasets from OpenStreetMap, and what to do with them."""
    verbosity = verbose - quiet
    configure_logging(verbosity)
    ctx.obj = {"verbosity": verbosity}


def _register() -> None:
    from osmseg.cli.build import build_command
    from osmseg.cli.demo import demo_command

    cli.add_command(build_command)
    cli.add_command(demo_command)


_register()

if __name__ == "__main__":  # pragma: no cover
    cli()
