"""Locate and read the project's data manifests (``data_manifests/*.toml``).

City presets and class tables are data, not code: they live in ``data_manifests/`` at the
repository root so that users can read and extend them without touching Python.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from osmseg.errors import ConfigError

MANIFEST_DIR = Path(__file__).resolve().parent.parent / "data_manifests"


def manifest_path(name: str) -> Path:
    """Path of a data manifest: a bare file name is looked up in ``data_manifests/``."""
    path = Path(name)
    if path.is_file():
        return path
    candidate = MANIFEST_DIR / name
    if candidate.is_file():
        return candidate
    raise ConfigError(f"data manifest {name!r} not found (looked in {MANIFEST_DIR}); give a path to a .toml file")


def load_toml(name: str) -> dict[str, Any]:
    """Read a TOML data manifest, with a one-line error naming the file on a syntax error."""
    path = manifest_path(name)
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc}); fix the file") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read it ({exc.strerror})") from None
