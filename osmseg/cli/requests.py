"""A command's request: its options as one typed, frozen value, built from click's parameters.

Every command hands one request to one library call (as ``BuildOptions`` does for ``osmseg
build``). A request is a frozen dataclass whose fields are named as the command's parameters; a
field may itself be a frozen dataclass, a *part* (the paper method's options, the ground side...),
whose fields are again parameters. :func:`make_request` fills the whole tree from click's flat
``**params`` and refuses a parameter no field takes (a command and its request cannot drift
apart); :func:`part_options` names the parameters a part holds, so a command refuses the options
of a method it does not run from the request type itself, never from a hand-kept list.

Imports: the standard library only. (``tests/cli/test_cli_options.py`` shows a request tree built.)
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Mapping
from typing import Any, TypeVar

__all__ = ["make_request", "part_options"]

R = TypeVar("R")


def _parts(cls: type) -> list[tuple[str, type | None]]:
    """``cls``'s init fields, each with its dataclass type when it is a part (else None)."""
    hints = typing.get_type_hints(cls)
    return [(f.name, hints[f.name] if dataclasses.is_dataclass(hints[f.name]) else None)
            for f in dataclasses.fields(cls) if f.init]


def part_options(cls: type) -> tuple[str, ...]:
    """The parameters a request (or a part of one) holds, its parts' flattened in field order."""
    names: list[str] = []
    for name, part in _parts(cls):
        names.extend(part_options(part) if part is not None else [name])
    return tuple(names)


def _fill(cls: type[R], params: Mapping[str, Any], used: set[str], given: Mapping[str, Any]) -> R:
    kwargs: dict[str, Any] = {}
    for name, part in _parts(cls):
        if name in given:
            kwargs[name] = given[name]
        elif part is not None:
            kwargs[name] = _fill(part, params, used, {})
        elif name in params:
            kwargs[name] = params[name]
            used.add(name)
    return cls(**kwargs)


def make_request(cls: type[R], params: Mapping[str, Any], **given: Any) -> R:
    """``cls`` from a command's flat parameters (``given`` fills top-level fields directly, e.g.
    ``typed``); TypeError when a parameter has no field to go to."""
    used: set[str] = set()
    request = _fill(cls, params, used, given)
    if stray := sorted(set(params) - used):
        raise TypeError(f"{cls.__name__} has no field for the parameters {', '.join(stray)}")
    return request
