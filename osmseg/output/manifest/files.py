"""The manifest on disk: ``manifest.json`` read (:func:`read_manifest`, typed and checked), written
(:func:`write_manifest`: deterministic, atomic, a sample at a time) and a dataset folder
re-verified against it (:func:`verify`), so a user can tell that a copy is complete and unmodified.

The text is always that of one ``json.dumps(manifest.to_json(), sort_keys=True, indent=2,
ensure_ascii=False)`` plus a newline, but never whole in memory: a build's finaliser passes lazy
sequences of entries, read from disk as they are written. Imports: osmseg core below it
(classes, errors, output.atomic, runtime.folderlock).
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Sequence
from pathlib import Path

from osmseg.classes import ClassTable, load_class_table
from osmseg.errors import DatasetBusy, DatasetError, OsmsegError
from osmseg.output.atomic import atomic_path, sha256_file
from osmseg.output.manifest.dataset import DatasetManifest
from osmseg.output.manifest.samples import RejectionRecord, SampleRecord
from osmseg.output.manifest.values import Json
from osmseg.runtime.folderlock import STATE_DIR, FolderLock

__all__ = ["MANIFEST_NAME", "SAMPLE_DIRS", "dataset_class_table", "manifest_chunks", "manifest_path", "manifest_text",
           "read_manifest", "refuse_busy", "verify", "write_manifest"]

MANIFEST_NAME = "manifest.json"
#: Folders holding per-sample files (each file listed in the manifest).
SAMPLE_DIRS = ("images", "segmented", "labels", "geo")


def manifest_text(manifest: DatasetManifest) -> str:
    """The manifest as deterministic JSON text (sorted keys, indent 2, UTF-8, trailing newline)."""
    return "".join(manifest_chunks(manifest))


def _dumps(value: Json, level: int) -> str:
    """``value`` as JSON with indent 2, for a place ``level`` deep in the manifest."""
    try:
        text = json.dumps(value, sort_keys=True, indent=2, ensure_ascii=False, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise DatasetError(f"manifest is not JSON-serialisable ({exc}); pass plain str/int/float/list/dict values") from None
    return text.replace("\n", "\n" + "  " * level)  # JSON strings hold no raw newline: only layout lines


def manifest_chunks(manifest: DatasetManifest) -> Iterable[str]:
    """The text of :func:`manifest_text` in pieces, a sample or rejection at a time.

    ``samples`` and ``rejected`` may be any sequences of records, also lazy ones that read each
    entry as it is iterated (a build's finaliser passes such): the whole text is never in memory,
    and its bytes are exactly those of one ``json.dumps(manifest.to_json(), sort_keys=True,
    indent=2, ensure_ascii=False)``.
    """
    head = manifest.head_json()
    lists: dict[str, Sequence[SampleRecord | RejectionRecord]] = {
        "samples": manifest.samples, "rejected": manifest.rejected}
    yield "{"
    for n, key in enumerate(sorted([*head, *lists])):
        yield ("," if n else "") + "\n  " + _dumps(key, 1) + ": "
        if key in lists:
            empty = True
            for i, entry in enumerate(lists[key]):
                yield ("[" if i == 0 else ",") + "\n    " + _dumps(entry.to_json(), 2)
                empty = False
            yield "[]" if empty else "\n  ]"
        else:
            yield _dumps(head[key], 1)
    yield "\n}\n"


def write_manifest(out_dir: Path, manifest: DatasetManifest) -> Path:
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


def dataset_class_table(manifest: DatasetManifest, root: Path) -> ClassTable:
    """The class table of a dataset: the one it was built with, tag rules and all, when that file is
    at hand (a shipped name such as ``classes13.toml``, or a path as the build was given it, read
    from the current folder or the dataset's) and still names the classes the manifest records;
    else the recorded one, which names and colours the classes but cannot draw OSM (no rules).
    """
    recorded = manifest.classes
    source = manifest.classes_source
    if source is None:
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


def read_manifest(path: Path) -> DatasetManifest:
    """Read and check a manifest (a dataset folder or the manifest file itself), typed.

    Reads format versions 1 and 2 and refuses any other in one line (see
    :mod:`osmseg.output.manifest.dataset`). Refuses a dataset that a build holds now
    (:mod:`osmseg.runtime.folderlock`): its files and manifest are still being written, and what
    would be read may not be what the build ends with.
    """
    file = manifest_path(path)
    _refuse_busy_folder(file.parent)
    try:
        data = json.loads(file.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DatasetError(f"{file} not found; give a dataset folder made by 'osmseg build'") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DatasetError(f"{file} is not valid JSON ({exc}); rebuild the dataset or restore the file") from None
    return DatasetManifest.from_json(data, where=str(file))


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
    for sample in manifest.samples:
        for rel, digest in sorted(sample.files.items()):
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
    accepted, count = manifest.summary.accepted, len(manifest.samples)
    if accepted is not None and accepted != count:
        problems.append(f"summary says {accepted} accepted samples, the manifest lists {count}")
    return problems
