"""Atomic, deterministic file writes.

Every output file is written to a hidden temporary file in the same folder and then moved
over its final name with :func:`os.replace`, which is atomic on POSIX and Windows. A build
killed at any moment (Ctrl-C, ``kill -9``) therefore leaves either the old file, the new
file or a stray ``.NAME.*.tmp`` (which :func:`make_zip <osmseg.output.package.make_zip>` and
the dataset readers ignore, since it starts with a dot), never a half-written file under
the real name.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import re
import sys
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from osmseg.runtime.processes import FOREIGN_SECONDS, deferred_termination, owner, owner_gone


def sha256_bytes(data: bytes) -> str:
    """Hex SHA-256 of ``data``.

    >>> sha256_bytes(b"")[:16]
    'e3b0c44298fc1c14'
    """
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: Path, chunk: int = 1 << 20) -> str:
    """Hex SHA-256 of a file's bytes, read in chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            digest.update(block)
    return digest.hexdigest()


#: (kept for callers of earlier releases) see :data:`osmseg.runtime.processes.FOREIGN_SECONDS`
FOREIGN_TEMP_SECONDS = FOREIGN_SECONDS


def _owner() -> str:
    """``HOST-PID`` of this process (:func:`osmseg.runtime.processes.owner`).

    >>> _owner().rsplit("-", 1)[1] == str(os.getpid())
    True
    """
    return owner()


#: the temporary files :func:`atomic_path` blocks of this process are writing now
_WRITING: set[Path] = set()
_WRITING_LOCK = threading.Lock()


def temp_path_for(path: Path) -> Path:
    """A fresh hidden temporary file beside ``path`` (created empty; the caller replaces or removes it).

    Named ``.NAME.HOST-PID.RANDOM.tmp``: :func:`sweep_temp_files` can then tell the litter of a
    killed writer from the file another live process (a worker, a concurrent shard) is writing.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{_owner()}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    return Path(tmp)


def remove_own_temp_files() -> int:
    """Remove the temporary files this process's :func:`atomic_path` blocks are writing; how many.

    For a process about to end at once (``os._exit``: a build worker whose build was killed): its
    files would otherwise outlive it, and a sweep that ran while it was still alive (the resumed
    build's, started at once) has left them, as a live writer's.

    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> try:
    ...     with atomic_path(folder / "a.png") as tmp:
    ...         removed = remove_own_temp_files()
    ... except FileNotFoundError:  # its file is gone: os._exit would have followed
    ...     pass
    >>> removed, sorted(p.name for p in folder.iterdir())
    (1, [])
    """
    with _WRITING_LOCK:
        writing = list(_WRITING)
        _WRITING.clear()
    for tmp in writing:
        tmp.unlink(missing_ok=True)
    return len(writing)


def sweep_temp_files(folder: Path, named_only: bool = False) -> int:
    """Remove the ``.NAME.*.tmp`` files in ``folder`` that no live writer will finish; how many.

    A file of this machine goes when its writing process is gone (a build killed mid-write); one
    named by another machine only once unchanged for :data:`FOREIGN_TEMP_SECONDS`
    (:func:`osmseg.runtime.processes.owner_gone`). Files being written by a live process (a worker of
    this build, another shard started at the same time on the same folder) are left alone. A
    name without an owner (osmseg's older form) goes too, unless ``named_only``: a folder that is
    not osmseg's alone (the output folder itself, which may be the user's) keeps every file that
    osmseg did not name.
    """
    removed = 0
    for tmp in Path(folder).glob(".*.tmp"):
        parts = tmp.name[1:-len(".tmp")].rsplit(".", 2)
        named = len(parts) == 3 and re.fullmatch(r"[A-Za-z0-9_]+-\d+", parts[1]) is not None
        if (named or not named_only) and owner_gone(parts[1] if named else "", tmp):
            tmp.unlink(missing_ok=True)
            removed += 1
    return removed


@contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """A temporary file beside ``path`` for the block to write; moved over ``path`` when it succeeds.

    When the block raises, the temporary file is removed and ``path`` is untouched. The file
    gets mode 0644 (mkstemp would leave 0600, and reading the process umask is not
    thread-safe), so a dataset is readable by its group. For writers that need a file name
    (osmium, zipfile); :func:`atomic_write_bytes` is the one-call form for bytes.

    >>> import tempfile
    >>> target = Path(tempfile.mkdtemp()) / "a.txt"
    >>> with atomic_path(target) as tmp:
    ...     _ = tmp.write_text("done")
    >>> target.read_text(), sorted(p.name for p in target.parent.iterdir())
    ('done', ['a.txt'])
    """
    path = Path(path)
    tmp: Path | None = None
    try:
        with deferred_termination():  # a SIGTERM between creating the file and naming it here would leave it
            tmp = temp_path_for(path)
            with _WRITING_LOCK:
                _WRITING.add(tmp)
        yield tmp
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        raise
    finally:
        if tmp is not None:
            with _WRITING_LOCK:
                _WRITING.discard(tmp)


def atomic_write_bytes(path: Path, data: bytes, durable: bool = True) -> Path:
    """Write ``data`` to ``path`` atomically (temp file in the same folder, fsync, os.replace).

    Creates missing parent folders; the file gets mode 0644 (see :func:`atomic_path`).
    ``durable=False`` skips the fsync, for writers of many small files that make them durable
    in one step afterwards (``os.sync()``; see :func:`osmseg.output.stac.write_stac`): a killed
    process still leaves the old file or the new one, but after a power loss before that step
    the file may be old, empty or missing.
    """
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            if durable:
                f.flush()
                os.fsync(f.fileno())
    return path


def atomic_write_text(path: Path, text: str, durable: bool = True) -> Path:
    """Write UTF-8 ``text`` with ``\\n`` line endings to ``path`` atomically (``durable``: as
    :func:`atomic_write_bytes`)."""
    return atomic_write_bytes(path, text.encode("utf-8"), durable=durable)


def sync_file_system(folder: Path) -> bool:
    """Make every write to ``folder``'s file system durable at once; False where that cannot be
    asked (then callers fsync file by file).

    Linux: ``syncfs`` on that file system only, so a shared machine's other disks (other jobs'
    dirty data) are not flushed with it; elsewhere with POSIX ``sync``, every file system.
    """
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            fd = os.open(folder, os.O_RDONLY)
            try:
                if libc.syncfs(fd) == 0:
                    return True
            finally:
                os.close(fd)
        except (OSError, AttributeError):
            pass
    sync = getattr(os, "sync", None)
    if sync is None:
        return False
    sync()
    return True

