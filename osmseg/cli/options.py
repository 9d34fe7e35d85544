"""The command line's options, each declared once: one name, one type, one meaning.

As rasterio's ``rio/options.py``: an option is a :class:`Declared` value (its flags, the
parameter it fills, its click type, its help), made by :func:`declare` and used as a decorator
(``@OUT(required=True, detail="checkpoints, log.csv")``) by every command that takes it. A
command may choose the option's default, whether it is required, and add a few words to its
help about what it does there; it cannot change the name, the type or the meaning.

Each flag is registered in :data:`DECLARED` when declared, and a flag declared a second time
(another meaning under the same name) is an error at import: two commands cannot say ``--mode``
and mean two things. ``tests/cli/test_cli_options.py`` walks every command of the group and fails
on any option not made from a declaration. Options shared by commands of more than one layer,
and the core's own, are declared here; training's and localization's own in ``training.cli``
and ``localization.cli.options``.

A former spelling stays as a hidden :func:`moved` option that refuses in one line, naming what
to type now (exit 2): the old name keeps no meaning of its own.

Imports: click and the standard library only; every layer's command line uses it.

>>> SEED.flags, SEED.dest
(('--seed',), 'seed')
>>> DECLARED["--seed"] is SEED
True
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import click

__all__ = ["DECLARED", "Declared", "DeclaredOption", "MovedOption", "declare", "moved"]

F = TypeVar("F", bound=Callable[..., object])

#: every flag of every declared option (``--freeze-bn`` and ``--train-bn`` both) -> its declaration
DECLARED: dict[str, Declared] = {}

_UNSET = object()


@dataclass(frozen=True)
class Declared:
    """One option: ``flags`` as click takes them (``("-v", "--verbose")``, ``("--tta",)``,
    ``("--freeze-bn/--train-bn",)``), the parameter ``dest`` it fills, its click ``type`` (None:
    text, or a flag), its ``help`` (the one meaning), and click's ``metavar``, ``is_flag``,
    ``multiple``, ``count`` and ``nargs``. ``module`` is where it was declared."""

    flags: tuple[str, ...]
    dest: str
    help: str
    type: object = None
    metavar: str | None = None
    is_flag: bool = False
    multiple: bool = False
    count: bool = False
    nargs: int = 1
    module: str = field(default="", compare=False)

    @property
    def names(self) -> tuple[str, ...]:
        """Every spelling a user may type (both sides of an ``--x/--no-x`` pair)."""
        return tuple(n.strip() for f in self.flags for n in f.split("/") if n.strip())

    def __call__(self, *, default: object = _UNSET, required: bool = False, show_default: bool | str | None = None,
                 detail: str = "", dest: str | None = None, callback: Callable[..., object] | None = None,
                 expose_value: bool = True) -> Callable[[F], F]:
        """The decorator adding this option to a command. ``detail`` is appended to the help
        (what the option does in that command); ``dest`` renames the parameter the command's
        function receives (an internal name: users never see it)."""
        kwargs = self._settings(default=default, required=required, show_default=show_default, detail=detail,
                                callback=callback, expose_value=expose_value)
        return click.option(*self.flags, dest or self.dest, cls=DeclaredOption, declared=self, **kwargs)

    def option(self, *, default: object = _UNSET, show_default: bool | str | None = None,
               callback: Callable[..., object] | None = None, expose_value: bool = True) -> DeclaredOption:
        """The click option itself, for a decorator that adds its parameters by hand (the output
        options every command takes after its name)."""
        return DeclaredOption([*self.flags, self.dest], declared=self,
                              **self._settings(default=default, show_default=show_default, callback=callback,
                                               expose_value=expose_value))

    def _settings(self, default: object = _UNSET, required: bool = False, show_default: bool | str | None = None,
                  detail: str = "", callback: Callable[..., object] | None = None,
                  expose_value: bool = True) -> dict[str, Any]:
        text = (self.help.rstrip(".") + detail) if detail else self.help
        kwargs: dict[str, Any] = {"help": text if text.endswith((".", "?", "!")) else text + ".", "required": required, "show_default": show_default,
                                  "callback": callback, "expose_value": expose_value}
        if self.count:
            kwargs["count"] = True
        else:
            kwargs.update(is_flag=self.is_flag or None, multiple=self.multiple, nargs=self.nargs)
            if self.type is not None:
                kwargs["type"] = self.type
            if self.metavar is not None:
                kwargs["metavar"] = self.metavar
        if default is not _UNSET:
            kwargs["default"] = default
        return kwargs


class DeclaredOption(click.Option):
    """A click option made from a :class:`Declared` (what the registry test looks for)."""

    def __init__(self, *args: Any, declared: Declared, **kwargs: Any) -> None:
        self.declared = declared
        super().__init__(*args, **kwargs)


class MovedOption(click.Option):
    """A former spelling: hidden from ``--help``; given, it refuses in one line with ``message``."""

    def __init__(self, *args: Any, message: str, **kwargs: Any) -> None:
        self.message = message
        super().__init__(*args, **kwargs)


def declare(*flags: str, dest: str | None = None, help: str, type: object = None, metavar: str | None = None,
            is_flag: bool = False, multiple: bool = False, count: bool = False, nargs: int = 1) -> Declared:
    """Declare an option once; ValueError when one of its flags is already another option's."""
    module = sys._getframe(1).f_globals.get("__name__", "")
    longest = max((f.split("/")[0].strip() for f in flags), key=len)  # --x/--no-x fills x, as click names it
    declared = Declared(flags=tuple(flags), dest=dest or longest.lstrip("-").replace("-", "_"), help=help, type=type,
                        metavar=metavar, is_flag=is_flag, multiple=multiple, count=count, nargs=nargs, module=module)
    for name in declared.names:
        before = DECLARED.get(name)
        if before is not None and before.module != module:
            raise ValueError(f"{name} is declared in {before.module} and again in {module}: one name, one meaning; "
                             "use that declaration, or give the new meaning another name")
    for name in declared.names:
        DECLARED[name] = declared
    return declared


def moved(old: str, message: str) -> Callable[[F], F]:
    """A hidden ``old`` flag that refuses in one line: ``message`` says what to type now."""

    def refuse(ctx: click.Context, param: click.Parameter, value: object) -> object:
        if value is not None:
            raise click.UsageError(message, ctx)
        return value

    return click.option(old, "moved_" + old.lstrip("-").replace("-", "_"), cls=MovedOption, message=message,
                        hidden=True, expose_value=False, callback=refuse, default=None)


def moved_each(flags: Sequence[str], message: str) -> Callable[[F], F]:
    """:func:`moved` for each of ``flags``, ``message`` a template naming it as ``{flag}``
    (another command's options, each refused in one line that names that command)."""

    def hide(func: F) -> F:
        for flag in reversed(flags):
            func = moved(flag, message.format(flag=flag))(func)
        return func

    return hide


# ------------------------------------------------------------------------------------------ every layer's


def _folder() -> click.Path:
    return click.Path(file_okay=False, path_type=Path)


OUT = declare("--out", dest="out_dir", type=_folder(), help="Output folder")
SEED = declare("--seed", type=click.IntRange(min=0), help="Seed of every random choice (recorded)")
DEVICE = declare("--device", help="auto (a GPU when there is one) | cpu | cuda | cuda:N.")
CACHE_DIR = declare("--cache-dir", type=_folder(), help="Where downloaded and derived data are kept for the next run")
#: where OpenStreetMap data come from (a command may take only files)
OSM = declare("--osm", multiple=True, metavar="SOURCE",
              help="OpenStreetMap data: api | overpass | PATH.osm(.pbf) | geojson:PATH (docs/osm.md)")
CLASSES = declare("--classes", metavar="TOML",
                  help="Class table (classes13.toml or classes6.toml from data_manifests/, or a TOML file's path)")
ZOOM = declare("--zoom", type=click.IntRange(1, 23),
               help="Web Mercator tile zoom: 18 is ~0.6 m/px at the equator, ~0.37 m/px at 52°N")

# an area on the map: a centre and radius, or a box
LAT = declare("--lat", type=float, help="Centre latitude, degrees (with --lon)")
LON = declare("--lon", type=float, help="Centre longitude, degrees (with --lat)")
RADIUS_KM = declare("--radius-km", type=click.FloatRange(min=0, min_open=True), help="Radius around the centre, km")
BBOX = declare("--bbox", metavar="W,S,E,N", help="A box in degrees: west, south, east, north")
SHARD = declare("--shard", metavar="K/N",
                help="Do only this process's share K of N of the work (array jobs); rerun without it to finish")

# every command's output
VERBOSE = declare("-v", "--verbose", count=True,
                  help="More log output on stderr (-vv for debug); before or after the command.")
QUIET = declare("-q", "--quiet", count=True,
                help="Less output on stderr: only errors, no progress; before or after the command.")
PROGRESS = declare("--progress/--no-progress", dest="progress", is_flag=True,
                   help="Show long work on stderr: bars on a terminal; in a log (a file, a pipe) a plain line per "
                        "tenth of a task or per minute, and per epoch of training; before or after the command.")
