"""What every subcommand shares: logging set-up, the output options, and osmseg errors as exit codes.

Imports: osmseg core (the commands of training and localization import this, never the reverse)."""

from __future__ import annotations

import functools
import importlib.util
import logging
import os
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import click
from tqdm import tqdm

from osmseg.cli.drawers import PROGRESS_DEFAULT, progress_mode
from osmseg.cli.options import PROGRESS, QUIET, VERBOSE
from osmseg.errors import ConfigError, OsmsegError
from osmseg.redact import RedactingFilter, command_line
from osmseg.runtime.processes import INTERRUPTED, TERMINATED, Terminated

F = TypeVar("F", bound=Callable[..., Any])


#: Loggers that warn once per broken OSM object: the build summary counts them instead.
PER_OBJECT_LOGGERS = ("osmseg.osm.features", "osmseg.osm.coastline")
#: Third-party loggers shown below WARNING only at -vvv.
CHATTY_LOGGERS = ("urllib3", "requests_cache", "vcr", "rasterio", "PIL", "fiona")


class _StderrFilter(logging.Filter):
    """Drops per-object OSM warnings (below -v) and third-party debug chatter (below -vvv)."""

    def __init__(self, verbosity: int) -> None:
        super().__init__()
        self.verbosity = verbosity

    def filter(self, record: logging.LogRecord) -> bool:
        name = record.name
        if self.verbosity < 1 and name.startswith(PER_OBJECT_LOGGERS) and record.levelno < logging.ERROR:
            return False
        if self.verbosity < 3 and name.startswith(CHATTY_LOGGERS) and record.levelno < logging.WARNING:
            return False
        return True


class _TqdmStderrHandler(logging.Handler):
    """Writes records to stderr through ``tqdm.write``, so they print above a progress bar."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            tqdm.write(self.format(record), file=sys.stderr)
        except Exception:  # logging must never take the command down
            self.handleError(record)


def configure_logging(verbosity: int) -> None:
    """Log to stderr: -q errors only, default warnings, -v info, -vv debug.

    Does nothing when the process already has log handlers (an application embedding the
    CLI, or pytest): the CLI never overrides someone else's logging set-up.
    """
    root = logging.getLogger()
    if root.handlers:
        return
    handler = _TqdmStderrHandler()
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    handler.addFilter(_StderrFilter(verbosity))
    handler.addFilter(RedactingFilter())  # every record, from any logger, loses its keys here
    root.addHandler(handler)
    root.setLevel({0: logging.WARNING, 1: logging.INFO}.get(verbosity, logging.DEBUG if verbosity > 1 else logging.ERROR))


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
        except OSError as exc:  # a folder that cannot be created, a full disk, a permission
            where = f"{exc.filename}: " if exc.filename else ""
            raise click.ClickException(f"{where}{exc.strerror or exc}; check the path and its permissions") from None
        except KeyboardInterrupt:
            click.echo(INTERRUPTED, err=True)
            sys.exit(130)
        except Terminated:
            click.echo(TERMINATED, err=True)
            sys.exit(143)

    return wrapper  # type: ignore[return-value]


def command_line_of(ctx: click.Context, **overrides: Any) -> str:
    """The command the user ran, rebuilt from the command's own option table (not from argv),
    with ``overrides`` (parameter name -> value) applied: what an error prints as "run instead".

    Options the user did not give are left out, so the line is the one they typed, corrected.
    """
    names: list[str] = []  # the subcommand names: the program may have been started as `python -m osmseg`
    node: click.Context | None = ctx
    while node is not None and node.parent is not None:
        names.insert(0, str(node.info_name))
        node = node.parent
    words = ["osmseg", *names]
    params = {**ctx.params, **overrides}
    for param in ctx.command.params:
        value = params.get(str(param.name))
        if isinstance(param, click.Argument):
            words += [str(v) for v in (value if isinstance(value, (list, tuple)) else [value]) if v is not None]
            continue
        given = param.name in overrides or ctx.get_parameter_source(str(param.name)) in (
            click.core.ParameterSource.COMMANDLINE, click.core.ParameterSource.ENVIRONMENT)
        if not isinstance(param, click.Option) or not given or value is None or value == ():
            continue
        name = max(param.opts, key=len)
        if param.is_flag:
            if value:
                words.append(name)
            continue
        for v in (value if param.multiple else [value]):
            words += [name, *(str(x) for x in (v if isinstance(v, tuple) else [v]))]
    return command_line(words)


def require_torch() -> None:
    """Fail with one line when the training extra (torch) is not installed."""
    if importlib.util.find_spec("torch") is None:
        raise click.UsageError(
            "this command needs PyTorch: pip install 'osmseg[train]' (or run `make test`, which installs it)"
        ) from None


def parse_size(value: str | None, option: str) -> tuple[int, int] | None:
    """An option's ``"WIDTHxHEIGHT"`` as ``(width, height)`` pixels; None stays None.

    >>> parse_size("1232x224", "--ground-size"), parse_size(None, "--ground-size")
    ((1232, 224), None)
    """
    if value is None:
        return None
    m = re.fullmatch(r"\s*(\d+)\s*[xX,]\s*(\d+)\s*", value)
    if not m or int(m.group(1)) < 1 or int(m.group(2)) < 1:
        raise ConfigError(f"{option} must be WIDTHxHEIGHT in pixels, e.g. 750x750; got {value!r}")
    return int(m.group(1)), int(m.group(2))


# --------------------------------------------------------------------------- options every command shares

#: where a subcommand's own -v/-q/--progress wait (in ``ctx.meta``) until the command runs
_OUTPUT_META = "osmseg.output_options"


def set_verbosity(verbosity: int) -> None:
    """Change the verbosity of the handler :func:`configure_logging` installed (a ``-v`` given
    after the subcommand). Leaves any other logging set-up alone, as that function does."""
    root = logging.getLogger()
    ours = [h for h in root.handlers if isinstance(h, _TqdmStderrHandler)]
    if not ours:
        return
    for handler in ours:
        for f in handler.filters:
            if isinstance(f, _StderrFilter):
                f.verbosity = verbosity
    root.setLevel({0: logging.WARNING, 1: logging.INFO}.get(verbosity, logging.DEBUG if verbosity > 1 else logging.ERROR))


def _remember(ctx: click.Context, param: click.Parameter, value: Any) -> Any:
    ctx.meta.setdefault(_OUTPUT_META, {})[param.name] = value
    return value


def apply_output_options(ctx: click.Context, verbose: int = 0, quiet: int = 0, progress: bool | None = None) -> dict[str, Any]:
    """Merge a subcommand's -v/-q/--progress into what the group's set (``ctx.obj``) and
    return it: counts add up (``osmseg -v build -v`` is -vv), a subcommand's ``--progress`` or
    ``--no-progress`` wins. A command run without the group gets the same defaults."""
    obj = ctx.find_root().obj
    if not isinstance(obj, dict):
        obj = {}
        ctx.find_root().obj = obj
    before = obj.get("verbosity", 0)
    verbosity = before + verbose - quiet
    asked = progress if progress is not None else obj.get("progress_asked")
    obj.update(verbosity=verbosity, progress_asked=asked, progress=progress_mode(asked, verbosity))
    if verbosity != before:
        set_verbosity(verbosity)
    ctx.obj = obj
    return obj


def output_options(func: F) -> F:
    """``-v/--verbose``, ``-q/--quiet`` and ``--progress/--no-progress`` on a subcommand, so
    they may follow it (``osmseg train DATA --out run -v``) as well as precede it. Shared by
    every command of the group, the plugins of training and localization included (as
    rasterio's ``rio`` shares its option decorators). The values reach the command through
    ``ctx.obj`` (``verbosity``, and ``progress``: :func:`osmseg.cli.drawers.progress_mode`'s answer),
    never as parameters."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        ctx = click.get_current_context()
        given = ctx.meta.get(_OUTPUT_META, {})
        apply_output_options(ctx, given.get("verbose") or 0, given.get("quiet") or 0, given.get("progress"))
        return func(*args, **kwargs)

    options = [
        VERBOSE.option(expose_value=False, callback=_remember, show_default=False),
        QUIET.option(expose_value=False, callback=_remember, show_default=False),
        PROGRESS.option(default=None, expose_value=False, callback=_remember, show_default=PROGRESS_DEFAULT),
    ]
    # click lists a command's parameters in reverse order of __click_params__: these come last in --help
    wrapper.__click_params__ = options[::-1] + list(getattr(func, "__click_params__", []))  # type: ignore[attr-defined]
    return wrapper  # type: ignore[return-value]


def typed_options(ctx: click.Context) -> set[str]:
    """The parameter names the user gave a value on the command line (or its environment
    variable); the others hold their defaults."""
    typed = (click.core.ParameterSource.COMMANDLINE, click.core.ParameterSource.ENVIRONMENT)
    return {name for name in ctx.params if ctx.get_parameter_source(name) in typed}


def default_cache_dir() -> Path:
    """Shared HTTP/OSM cache: $OSMSEG_CACHE_DIR, else $XDG_CACHE_HOME/osmseg, else ~/.cache/osmseg."""
    if "OSMSEG_CACHE_DIR" in os.environ:
        return Path(os.environ["OSMSEG_CACHE_DIR"])
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    return base / "osmseg"
