"""Atomic, deterministic file writes.

Every output file is written to a hidden temporary file in the same folder and then moved
over its final name with :func:`os.replace`, which is atomic on POSIX and Windows. A build
killed at any moment (Ctrl-C, ``kill -9``) therefore leaves either the old file, the new
file or a stray ``.NAME.*.tmp`` (which :func:`make_zip <osmseg.output.package.make_zip>` and
the dataset readers ignore, since it starts with a dot), never a half-written file under
the real name.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


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


def temp_path_for(path: Path) -> Path:
    """A fresh hidden temporary file beside ``path`` (created empty; the caller replaces or removes it)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    return Path(tmp)


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
    tmp = temp_path_for(path)
    try:
        yield tmp
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (temp file in the same folder, fsync, os.replace).

    Creates missing parent folders; the file gets mode 0644 (see :func:`atomic_path`).
    """
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
    return path


def atomic_write_text(path: Path, text: str) -> Path:
    """Write UTF-8 ``text`` with ``\\n`` line endings to ``path`` atomically."""
    return atomic_write_bytes(path, text.encode("utf-8"))
