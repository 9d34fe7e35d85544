"""The dataset manifest (``manifest.json``): what was built, from what, and the hash of every file.

The builder assembles the manifest dict (schema in ``docs/dataset-format.md``); this module
gives it the per-sample and per-rejection entries, writes it deterministically (sorted keys,
2-space indent, UTF-8, trailing newline, atomic), checks its shape and re-verifies a dataset
folder against it, so a user can tell that a copy is complete and unmodified.

>>> print(command_line(["osmseg", "build", "--imagery", "xyz:https://t.example/{z}/{x}/{y}?key=SECRET"]))
osmseg build --imagery 'xyz:https://t.example/{z}/{x}/{y}?key=REDACTED'
"""

from __future__ import annotations

import json
import os
import re
import shlex
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypedDict, cast

import mercantile

from osmseg.classes import ClassTable, load_class_table
from osmseg.errors import DatasetBusy, DatasetError, OsmsegError
from osmseg.grid import SampleGrid
from osmseg.output.atomic import atomic_path, sha256_file
from osmseg.redact import redact
from osmseg.runtime.folderlock import STATE_DIR, FolderLock

MANIFEST_NAME = "manifest.json"
FORMAT = "osmseg-dataset"
#: Version 2 writes each build setting once: the top-level keys (area, seed, zoom, grid_size,
#: image_format, filters) and ``config`` for the rest; version 1 repeated them all in ``config``.
FORMAT_VERSION = 2
#: The versions this osmseg reads.
READ_VERSIONS = (1, 2)
#: Build settings written at the top level, so not again in ``config`` (version 2).
TOP_LEVEL_SETTINGS = ("area", "seed", "zoom", "grid_size", "image_format", "filters")
#: Folders holding per-sample files (each file listed in the manifest).
SAMPLE_DIRS = ("images", "segmented", "labels", "geo")
#: Keys every manifest has (see docs/dataset-format.md).
REQUIRED_KEYS = (
    "format", "format_version", "tool", "command", "seed", "area", "zoom", "grid_size", "classes",
    "filters", "imagery", "osm", "samples", "rejected", "summary",
)
#: Keys every entry of ``samples`` has.
SAMPLE_KEYS = (
    "name", "center", "bbox_wgs84", "bounds_3857", "zoom", "ground_resolution_m", "tiles",
    "imagery", "osm", "class_histogram", "files",
)

#: Why the builder rejects a sample, in the order its filters check (:mod:`osmseg.builder.filters`):
#: the manifest lists the rejected attempts by these reasons.
REASONS: tuple[str, ...] = ("unlabeled", "single_class", "placeholder_imagery", "missing_imagery", "low_contrast")


@dataclass(frozen=True)
class Rejection:
    """Why a sample was rejected: a machine ``reason`` (one of :data:`REASONS`) and a human ``detail``."""

    reason: str
    detail: str

    def to_dict(self) -> dict[str, str]:
        """JSON-able form for the manifest's list of rejected attempts."""
        return {"reason": self.reason, "detail": self.detail}


_SECRET_OPTION = re.compile(r"(?i)^--?[\w-]*(key|token|secret|password)[\w-]*$")


def command_line(argv: Sequence[str]) -> str:
    """The command that made the dataset, shell-quoted, with secrets removed.

    Values of options named like ``--*key*``/``--*token*``/``--*secret*``/``--*password*``
    become ``REDACTED``, and every other argument goes through :func:`osmseg.redact.redact`
    (secret URL parameters such as ``key=``/``access_token=``, passwords in URLs).

    >>> command_line(["osmseg", "build", "--bing-key", "abc", "--api-token=xyz", "--seed", "3"])
    'osmseg build --bing-key REDACTED --api-token=REDACTED --seed 3'
    """
    out: list[str] = []
    hide_next = False
    for arg in argv:
        if hide_next:
            out.append("REDACTED")
            hide_next = False
            continue
        option, eq, _ = arg.partition("=")
        if _SECRET_OPTION.match(option):
            if eq:
                out.append(f"{option}=REDACTED")
            else:
                out.append(arg)
                hide_next = True
            continue
        out.append(redact(arg))
    return shlex.join(out)


def tile_entry(tile: mercantile.Tile) -> dict[str, Any]:
    """A tile as ``{"z", "x", "y", "quadkey"}``.

    >>> tile_entry(mercantile.Tile(3, 5, 3))
    {'z': 3, 'x': 3, 'y': 5, 'quadkey': '213'}
    """
    return {"z": tile.z, "x": tile.x, "y": tile.y, "quadkey": mercantile.quadkey(tile)}


def sample_entry(
    name: str,
    grid: SampleGrid,
    written: dict[str, Any],
    *,
    imagery: dict[str, Any],
    osm: dict[str, Any],
    osm_timestamp: str | None,
) -> dict[str, Any]:
    """The manifest entry of one accepted sample.

    Args:
        name: sample name (file stem).
        grid: the sample's grid (centre, tiles, bounds).
        written: what :func:`osmseg.output.writer.write_sample` returned.
        imagery: ``Imagery.info`` (provider provenance, no keys).
        osm: ``OsmExtract.info`` (source provenance, no keys).
        osm_timestamp: ``OsmExtract.timestamp`` (ISO 8601) or None when unknown.
    """
    return {
        "name": name,
        "center": {"lon": grid.lon, "lat": grid.lat},
        "bbox_wgs84": list(grid.bbox),
        "bounds_3857": list(grid.xy_bounds),
        "zoom": grid.zoom,
        "ground_resolution_m": grid.ground_resolution,
        "tiles": [tile_entry(t) for t in grid.tiles],
        "imagery": imagery,
        "osm": {**osm, "timestamp": osm_timestamp},
        "class_histogram": dict(written["class_histogram"]),
        "files": dict(written["files"]),
    }


def rejection_entry(lon: float, lat: float, rejection: Rejection, attempt: int | None = None) -> dict[str, Any]:
    """The manifest entry of one rejected attempt: centre, reason, detail (and attempt number).

    >>> rejection_entry(1.5, 2.0, Rejection("unlabeled", "80.0% unlabeled >= 70.0%"), attempt=4)["reason"]
    'unlabeled'
    """
    entry: dict[str, Any] = {"center": {"lon": lon, "lat": lat}, **rejection.to_dict()}
    if attempt is not None:
        entry["attempt"] = attempt
    return entry


class Counts(TypedDict):
    """What a build asked for and got: the first keys of the manifest's ``summary``."""

    requested: int
    accepted: int
    rejected: int
    attempts: int
    max_attempts: int
    rejected_by_reason: dict[str, int]
    complete: bool


class Summary(Counts):
    """The manifest's ``summary`` (docs/dataset-format.md): the :class:`Counts`, and how the
    samples fall relative to each other and to OSM."""

    duplicate_samples: int      # samples on the very tiles of another
    overlapping_samples: int    # samples sharing pixels with another
    overlap_groups: int         # groups of samples that overlap; a lone sample is a group
    osm_unplaced: int           # OSM objects of a class that could not be drawn (no node located)


def summary_entry(
    samples: Sequence[dict[str, Any]],
    rejected: Sequence[dict[str, Any]],
    *,
    requested: int,
    max_attempts: int,
) -> Counts:
    """Counts for the manifest's ``summary``: accepted, rejected (total and by reason), attempts.

    >>> summary_entry([{}], [{"reason": "unlabeled"}] * 2, requested=3, max_attempts=10)["rejected_by_reason"]
    {'unlabeled': 2}
    """
    by_reason = Counter(r["reason"] for r in rejected)
    return {
        "requested": requested,
        "accepted": len(samples),
        "rejected": len(rejected),
        "attempts": len(samples) + len(rejected),
        "max_attempts": max_attempts,
        "rejected_by_reason": {k: by_reason[k] for k in sorted(by_reason, key=_reason_order)},
        "complete": len(samples) >= requested,
    }


def _reason_order(reason: str) -> tuple[int, str]:
    return (REASONS.index(reason) if reason in REASONS else len(REASONS), reason)


def class_totals(samples: Iterable[dict[str, Any]]) -> dict[str, int]:
    """Pixel count per class name summed over samples.

    >>> class_totals([{"class_histogram": {"a": 1, "b": 2}}, {"class_histogram": {"a": 3}}])
    {'a': 4, 'b': 2}
    """
    totals: Counter[str] = Counter()
    for s in samples:
        totals.update(s["class_histogram"])
    return dict(totals)


def manifest_text(manifest: dict[str, Any]) -> str:
    """The manifest as deterministic JSON text (sorted keys, indent 2, UTF-8, trailing newline).

    >>> m = {"b": [], "a": {"x": "São Paulo"}}
    >>> manifest_text(m) == json.dumps(m, sort_keys=True, indent=2, ensure_ascii=False) + "\\n"
    True
    """
    return "".join(manifest_chunks(manifest))


def _dumps(value: Any, level: int) -> str:
    """``value`` as JSON with indent 2, for a place ``level`` deep in the manifest."""
    try:
        text = json.dumps(value, sort_keys=True, indent=2, ensure_ascii=False, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise DatasetError(f"manifest is not JSON-serialisable ({exc}); pass plain str/int/float/list/dict values") from None
    return text.replace("\n", "\n" + "  " * level)  # JSON strings hold no raw newline: only layout lines


def manifest_chunks(manifest: dict[str, Any]) -> Iterable[str]:
    """The text of :func:`manifest_text` in pieces, a sample or rejection at a time.

    ``samples`` and ``rejected`` may be any sequences of entries, also lazy ones that read each
    entry as it is iterated (a build's finaliser passes such): the whole text is never in memory,
    and its bytes are exactly those of one ``json.dumps(manifest, sort_keys=True, indent=2,
    ensure_ascii=False)``.
    """
    yield "{"
    for n, key in enumerate(sorted(manifest)):
        value = manifest[key]
        yield ("," if n else "") + "\n  " + _dumps(key, 1) + ": "
        if isinstance(value, Sequence) and not isinstance(value, (str, bytes, list, tuple)):
            empty = True
            for i, entry in enumerate(value):
                yield ("[" if i == 0 else ",") + "\n    " + _dumps(entry, 2)
                empty = False
            yield "[]" if empty else "\n  ]"
        else:
            yield _dumps(value, 1)
    yield "\n}\n" if manifest else "}\n"


def write_manifest(out_dir: Path, manifest: dict[str, Any]) -> Path:
    """Write ``OUT/manifest.json`` atomically, piece by piece (see :func:`manifest_chunks`); return its path."""
    path = Path(out_dir) / MANIFEST_NAME
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8", newline="\n") as f:
            for chunk in manifest_chunks(manifest):
                f.write(chunk)
            f.flush()
            os.fsync(f.fileno())
    return path


def manifest_path(path: Path) -> Path:
    """``path`` itself if it is a file, else ``path/manifest.json``."""
    path = Path(path)
    return path / MANIFEST_NAME if path.is_dir() else path


def dataset_class_table(manifest: dict[str, Any], root: Path) -> ClassTable:
    """The class table of a dataset: the one it was built with, tag rules and all, when that file is
    at hand (a shipped name such as ``classes13.toml``, or a path as the build was given it, read
    from the current folder or the dataset's) and still names the classes the manifest records;
    else the recorded one, which names and colours the classes but cannot draw OSM (no rules).

    >>> t = dataset_class_table({"classes": load_class_table().to_dict(),
    ...                          "config": {"classes": "classes13.toml"}}, Path("."))
    >>> t.name, t.has_rules
    ('osm13', True)
    >>> dataset_class_table({"classes": t.to_dict(), "config": {"classes": "missing.toml"}}, Path(".")).has_rules
    False
    """
    where = f"{manifest_path(root)} classes"
    recorded = ClassTable.from_dict(manifest["classes"], where)
    source = (manifest.get("config") or {}).get("classes")
    if not isinstance(source, str) or not source:
        return recorded
    for candidate in (source, str(Path(root) / source)):
        try:
            table = load_class_table(candidate)
        except (OsmsegError, OSError):
            continue
        if table.to_dict() == recorded.to_dict():
            return table
    return recorded


def _refuse_busy_folder(folder: Path) -> None:
    busy = FolderLock.busy(folder / STATE_DIR)
    if busy is not None:
        raise DatasetBusy(f"{folder} is being built now ({busy.describe_holders()}): use it when the build has ended")


def refuse_busy(*paths: Path | str | None) -> None:
    """:class:`DatasetBusy` when one of ``paths`` is a dataset folder that a build holds now, or lies
    in one (a file or folder up to two levels down: ``DATASET/labels/NAME.png``, ``DATASET/labels``).

    What every command that reads a dataset, or writes into one, asks first (``train``, ``eval``,
    ``predict``, ``localize``, ``localize-bench``; ``verify`` through :func:`read_manifest`): a
    build's files and manifest are still being written, and a first build has no manifest yet to
    say so. Changes nothing; a folder this process holds itself is not busy (:meth:`FolderLock.busy`).
    """
    for path in paths:
        if path is None:
            continue
        p = Path(path)
        for folder in dict.fromkeys((p, p.parent, p.parent.parent)):
            _refuse_busy_folder(folder)


def read_manifest(path: Path) -> dict[str, Any]:
    """Read and validate a manifest (a dataset folder or the manifest file itself).

    Refuses a dataset that a build holds now (:mod:`osmseg.runtime.folderlock`): its files and manifest
    are still being written, and what would be read may not be what the build ends with.
    """
    file = manifest_path(path)
    _refuse_busy_folder(file.parent)
    try:
        manifest = json.loads(file.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DatasetError(f"{file} not found; give a dataset folder made by 'osmseg build'") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DatasetError(f"{file} is not valid JSON ({exc}); rebuild the dataset or restore the file") from None
    validate_manifest(manifest, where=str(file))
    return cast("dict[str, Any]", manifest)


def config_entry(identity: dict[str, Any]) -> dict[str, Any]:
    """The manifest's ``config``: the build's identity less what the top level already says.

    >>> config_entry({"seed": 1, "zoom": 18, "samples": 4, "imagery": "bing"})
    {'samples': 4, 'imagery': 'bing'}
    """
    return {k: v for k, v in identity.items() if k not in TOP_LEVEL_SETTINGS}


def build_identity(manifest: dict[str, Any]) -> dict[str, Any]:
    """Everything that decided a dataset's content (``BuildConfig.identity()``), from a manifest
    of any version: version 1 kept it whole in ``config``, version 2 once across the top level
    and ``config``."""
    if manifest.get("format_version") == 1:
        return dict(manifest.get("config") or {})
    top = {key: manifest[key] for key in TOP_LEVEL_SETTINGS if key in manifest}
    if isinstance(top.get("area"), dict):
        top["area"] = {k: v for k, v in top["area"].items() if v is not None}
    return {**top, **(manifest.get("config") or {})}


def validate_manifest(manifest: Any, where: str = "manifest") -> None:
    """Raise :class:`DatasetError` (one line) if ``manifest`` does not have the documented shape."""
    if not isinstance(manifest, dict):
        raise DatasetError(f"{where}: top level must be a JSON object")
    if manifest.get("format") != FORMAT:
        raise DatasetError(f"{where}: format is {manifest.get('format')!r}, expected {FORMAT!r}")
    if manifest.get("format_version") not in READ_VERSIONS:
        raise DatasetError(
            f"{where}: format_version {manifest.get('format_version')!r} is not one of {list(READ_VERSIONS)}; "
            "use a matching osmseg"
        )
    missing = [k for k in REQUIRED_KEYS if k not in manifest]
    if missing:
        raise DatasetError(f"{where}: missing keys {missing}")
    # any sequence, not only a list: a build passes lazy ones that read each entry from disk (iterated once here)
    if not all(isinstance(manifest[k], Sequence) and not isinstance(manifest[k], (str, bytes))
               for k in ("samples", "rejected")):
        raise DatasetError(f"{where}: samples and rejected must be lists")
    names: set[str] = set()
    for i, sample in enumerate(manifest["samples"]):
        if not isinstance(sample, dict):
            raise DatasetError(f"{where}: samples[{i}] must be an object")
        lacking = [k for k in SAMPLE_KEYS if k not in sample]
        if lacking:
            raise DatasetError(f"{where}: samples[{i}] ({sample.get('name', '?')}) is missing {lacking}")
        if sample["name"] in names:
            raise DatasetError(f"{where}: sample name {sample['name']!r} appears twice")
        names.add(sample["name"])
        files = sample["files"]
        if not isinstance(files, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in files.items()):
            raise DatasetError(f"{where}: samples[{i}] files must map relative paths to sha256 strings")
        for rel in files:
            if Path(rel).is_absolute() or ".." in Path(rel).parts:
                raise DatasetError(f"{where}: sample {sample['name']} lists a path outside the dataset: {rel!r}")
    for i, rej in enumerate(manifest["rejected"]):
        if not isinstance(rej, dict) or not {"center", "reason", "detail"} <= rej.keys():
            raise DatasetError(f"{where}: rejected[{i}] must have center, reason and detail")


def verify(out_dir: Path) -> list[str]:
    """Re-check a dataset folder against its manifest; returns the problems found (empty = OK).

    Every file listed for every sample must exist with the recorded SHA-256, and the sample
    folders must hold no file the manifest does not list (hidden ``.*`` temp files excepted).
    Raises :class:`DatasetError` when the manifest itself is missing or malformed.
    """
    out_dir = Path(out_dir)
    manifest = read_manifest(out_dir)
    problems: list[str] = []
    listed: set[str] = set()
    for sample in manifest["samples"]:
        for rel, digest in sorted(sample["files"].items()):
            listed.add(rel)
            path = out_dir / rel
            if not path.is_file():
                problems.append(f"{rel}: missing")
            elif sha256_file(path) != digest:
                problems.append(f"{rel}: modified (sha256 differs from the manifest)")
    for folder in SAMPLE_DIRS:
        root = out_dir / folder
        if not root.is_dir():
            continue
        for path in sorted(root.rglob("*")):
            rel = path.relative_to(out_dir).as_posix()
            if path.is_file() and not path.name.startswith(".") and rel not in listed:
                problems.append(f"{rel}: not listed in the manifest")
    summary = manifest["summary"]
    if isinstance(summary, dict) and summary.get("accepted", len(manifest["samples"])) != len(manifest["samples"]):
        problems.append(f"summary says {summary.get('accepted')} accepted samples, the manifest lists {len(manifest['samples'])}")
    return problems
