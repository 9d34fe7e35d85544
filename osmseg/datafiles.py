"""Find and read the TOML files shipped in ``data_manifests/``: city presets, class tables,
class mappings and landmark dictionaries.

They are data, not code: they live in ``data_manifests/`` at the repository root so that
users can read and extend them without touching Python. (A dataset's ``manifest.json`` is
something else: :mod:`osmseg.output.manifest` writes and reads it.) Imports: osmseg.errors.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, cast

import tomllib

from osmseg.errors import ConfigError

DATA_DIR = Path(__file__).resolve().parent.parent / "data_manifests"


def find_data_file(name: str) -> Path:
    """Path of a shipped data file: a path as given, else a bare file name in ``data_manifests/``."""
    path = Path(name)
    if path.is_file():
        return path
    candidate = DATA_DIR / name
    if candidate.is_file():
        return candidate
    raise ConfigError(f"data manifest {name!r} not found (looked in {DATA_DIR}); give a path to a .toml file")


def load_toml(name: str) -> dict[str, Any]:
    """Read a TOML data manifest, with a one-line error naming the file on a syntax error."""
    path = find_data_file(name)
    try:
        with path.open("rb") as f:
            return cast("dict[str, Any]", tomllib.load(f))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc}); fix the file") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read it ({exc.strerror})") from None
