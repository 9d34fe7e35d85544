"""What every subcommand shares: logging set-up and turning osmseg errors into exit codes."""

from __future__ import annotations

import functools
import logging
import sys
from typing import Any, Callable, TypeVar

import click

from osmseg.errors import ConfigError, OsmsegError

F = TypeVar("F", bound=Callable[..., Any])


def configure_logging(verbosity: int) -> None:
    """Send log records to stderr: -q errors only, default warnings, -v info, -vv debug."""
    level = {0: logging.WARNING, 1: logging.INFO}.get(verbosity, logging.DEBUG if verbosity > 1 else logging.ERROR)
    logging.basicConfig(stream=sys.stderr, level=level, format="%(levelname)s %(name)s: %(message)s")
    # one warning per broken OSM object floods a build; the build summary counts them instead
    for name in ("osmseg.osm.features", "osmseg.osm.coastline"):
        logging.getLogger(name).setLevel(logging.INFO if verbosity >= 1 else logging.ERROR)
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
