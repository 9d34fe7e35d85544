"""JSON values as the manifest holds them, and the checks that turn parsed JSON into typed fields.

:data:`Json` is any value ``json.loads`` gives; the typed records of :mod:`osmseg.output.manifest`
keep a value exactly as it was read (an int stays an int, a list keeps its order), so that
writing a record back gives the same bytes. Each check raises :class:`DatasetError` with one line
naming the place (``manifest.json samples[3] zoom``) and what to do. Imports: osmseg.errors.

>>> number_list([1, 2.5], 2, "box")
(1, 2.5)
>>> optional_int("18", "zoom")
Traceback (most recent call last):
osmseg.errors.DatasetError: zoom must be an integer or null, not '18'; rebuild the dataset or restore its manifest.json
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TypeAlias

from osmseg.errors import DatasetError

#: A JSON value as :func:`json.loads` gives it.
Json: TypeAlias = "None | bool | int | float | str | list[Json] | dict[str, Json]"
#: A JSON object.
JsonObject: TypeAlias = "dict[str, Json]"

__all__ = ["Json", "JsonObject", "extra_keys", "int_map", "json_object", "number_list", "optional_bool",
           "optional_int", "optional_number", "optional_text", "string_list", "text"]

_FIX = "rebuild the dataset or restore its manifest.json"


def _refuse(where: str, wanted: str, value: object) -> DatasetError:
    return DatasetError(f"{where} must be {wanted}, not {value!r}; {_FIX}")


def json_object(value: object, where: str) -> JsonObject:
    """``value`` if it is a JSON object (keys are strings), else a one-line error."""
    if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
        raise _refuse(where, "an object", value)
    return value


def text(value: object, where: str) -> str:
    """``value`` if it is a string."""
    if not isinstance(value, str):
        raise _refuse(where, "a string", value)
    return value


def optional_text(value: object, where: str) -> str | None:
    """``value`` if it is a string or null."""
    return None if value is None else text(value, where)


def optional_int(value: object, where: str) -> int | None:
    """``value`` if it is an integer (not a boolean) or null."""
    if value is None:
        return None
    if not isinstance(value, int) or isinstance(value, bool):
        raise _refuse(where, "an integer or null", value)
    return value


def optional_number(value: object, where: str) -> float | None:
    """``value`` if it is a number (an int stays an int, to be written back as it was) or null."""
    if value is None:
        return None
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        raise _refuse(where, "a number or null", value)
    return value


def optional_bool(value: object, where: str) -> bool | None:
    """``value`` if it is true, false or null."""
    if value is not None and not isinstance(value, bool):
        raise _refuse(where, "true, false or null", value)
    return value


def number_list(value: object, n: int, where: str) -> tuple[float, ...]:
    """``value`` if it is a list of ``n`` numbers, as a tuple."""
    if not (isinstance(value, list) and len(value) == n
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
        raise _refuse(where, f"{n} numbers", value)
    return tuple(value)


def string_list(value: object, where: str) -> tuple[str, ...]:
    """``value`` if it is a list of strings, as a tuple."""
    if not (isinstance(value, list) and all(isinstance(v, str) for v in value)):
        raise _refuse(where, "a list of strings", value)
    return tuple(value)


def int_map(value: object, where: str) -> dict[str, int]:
    """``value`` if it is an object of integers (a class histogram, counts by reason)."""
    data = json_object(value, where)
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in data.values()):
        raise _refuse(where, "an object of integers", value)
    return {k: v for k, v in data.items() if isinstance(v, int)}


def extra_keys(data: Mapping[str, Json], known: frozenset[str]) -> JsonObject:
    """The keys of ``data`` a record does not know: kept as they are and written back (readers
    ignore keys they do not know, and a manifest read and written again keeps its bytes)."""
    return {k: v for k, v in data.items() if k not in known}
