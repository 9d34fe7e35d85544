"""One build owns a dataset folder for its whole life: an OS lock that its shards share.

Two ``osmseg build`` commands with different options started together into one ``--out``
would otherwise both find the folder free, both record their options, and write each other's
samples: a dataset whose files do not match its manifest, with every command saying it went
well. A :class:`FolderLock` on the build-state folder (``OUT/.osmseg-build``) prevents it:

* ``lock``: every process of the build that holds the folder has a *shared* ``flock`` on it for
  as long as it runs (the build command, each of its workers). Shards of the same build (same
  options: ``--shard K/N`` processes of one array job) share it by design. The kernel drops a
  lock when its process ends, however it ends, so a killed build never leaves the folder taken.
* ``lock.guard``: an exclusive ``flock`` held for the few milliseconds in which a command looks
  at the folder and decides: whether anyone holds it (an exclusive, non-blocking try on
  ``lock``), what options the folder records, and then takes its shared lock. Two commands
  started in the same millisecond decide one after the other.
* ``holders/HOST-PID.json``: who holds the folder (process, host, start, the command without
  its secrets), so the command that is refused can say what holds it. Only names: the lock
  decides; a stale file (its process gone) is ignored and swept.

Where the file system has no locks (some network file systems), a warning says so and the
build goes on as before: the recorded options still refuse a different build that has samples.
Readers of a dataset (:func:`osmseg.output.manifest.read_manifest`: ``verify``, ``train``,
``localize-bench``...) ask :meth:`FolderLock.busy` first, and refuse a folder a build holds:
its files and manifest are still being written. POSIX only (``fcntl``); elsewhere there is
no lock. Imports: :mod:`osmseg.runtime.processes` and the standard library only (the dataset readers
below the builder import it).
"""

from __future__ import annotations

import errno
import json
import logging
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from osmseg.runtime.processes import owner, owner_gone

try:
    import fcntl
except ImportError:  # Windows
    fcntl = None  # type: ignore[assignment]

__all__ = ["STATE_DIR", "FolderLock", "Holder"]

#: The build-state folder inside a dataset folder, which holds the lock.
STATE_DIR = ".osmseg-build"

logger = logging.getLogger(__name__)

#: errno values of a file system that does not do locks (NFS without lockd, some FUSE mounts)
NO_LOCKS = {errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL}


@dataclass(frozen=True)
class Holder:
    """A process that holds a dataset folder, as its ``holders/`` file names it."""

    owner: str  # HOST-PID
    pid: int
    host: str
    started: str  # UTC, ISO 8601 to the second
    command: str  # without secrets

    def describe(self) -> str:
        """One phrase naming the process (its command line is in its ``holders/`` file).

        >>> Holder("h-7", 7, "h", "2026-12-02T15:30:02Z", "osmseg build --seed 3").describe()
        'pid 7 on h since 2026-12-02T15:30:02Z'
        """
        return f"pid {self.pid} on {self.host} since {self.started}"


class FolderLock:
    """The lock on one build-state folder ``root`` (see the module doc). One per process."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self._fd: int | None = None  # the shared lock this process holds
        self._holder: Path | None = None

    @property
    def path(self) -> Path:
        return self.root / "lock"

    @property
    def held(self) -> bool:
        """Whether this process holds the folder."""
        return self._fd is not None

    @contextmanager
    def deciding(self) -> Iterator[bool]:
        """Hold the guard for the block, which decides whether this build may have the folder;
        yields whether other processes hold it now. Creates ``root`` if needed."""
        self.root.mkdir(parents=True, exist_ok=True)
        if fcntl is None:
            yield False
            return
        guard = os.open(self.root / "lock.guard", os.O_RDWR | os.O_CREAT, 0o644)
        try:
            if not _flock(guard, fcntl.LOCK_EX, self.root):
                yield False
                return
            yield self._others_hold()
        finally:
            os.close(guard)  # closing the file drops its lock

    def _others_hold(self) -> bool:
        assert fcntl is not None
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            return _taken(fd)
        except OSError as exc:
            if exc.errno in NO_LOCKS:
                return False
            raise
        finally:
            os.close(fd)

    def hold(self, command: str) -> None:
        """Take this process's shared lock on the folder (inside :meth:`deciding`, or in a worker
        of a build that holds it) and, with ``command``, name this process in ``holders/``."""
        if self._fd is not None:
            return
        if fcntl is not None:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                locked = _flock(fd, fcntl.LOCK_SH, self.root)
            except BaseException:
                os.close(fd)
                raise
            if locked:
                self._fd = fd
                _HELD_HERE.add(self.root.resolve())
            else:
                os.close(fd)
        if command:
            folder = self.root / "holders"
            folder.mkdir(exist_ok=True)
            for stale in folder.glob("*.json"):  # of processes that ended without saying so
                if owner_gone(stale.stem, stale):
                    stale.unlink(missing_ok=True)
            me = owner()
            host, _, pid = me.rpartition("-")
            self._holder = folder / f"{me}.json"
            text = json.dumps({"pid": int(pid), "host": os.uname().nodename if hasattr(os, "uname") else host,
                               "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "command": command})
            tmp = folder / f".{me}.json.{me}.0.tmp"  # renamed: never seen half-written (named as atomic.py names)
            tmp.write_text(text + "\n", encoding="utf-8")
            os.replace(tmp, self._holder)

    def holders(self) -> list[Holder]:
        """The processes that say they hold the folder (their process is still there)."""
        found = []
        for path in sorted((self.root / "holders").glob("*.json")):
            if owner_gone(path.stem, path) or path == self._holder:
                continue
            try:
                data: dict[str, Any] = json.loads(path.read_text())
                found.append(Holder(owner=path.stem, pid=int(data["pid"]), host=str(data["host"]),
                                    started=str(data["started"]), command=str(data["command"])))
            except (OSError, ValueError, KeyError, TypeError):
                continue
        return found

    def describe_holders(self) -> str:
        """What holds the folder, for a message: the first holder and how many more."""
        holders = self.holders()
        if not holders:
            return "another osmseg process"
        more = f" and {len(holders) - 1} more process{'es' if len(holders) > 2 else ''}" if len(holders) > 1 else ""
        return holders[0].describe() + more

    def release(self) -> None:
        """Drop this process's lock and its name (also what a process end does)."""
        if self._holder is not None:
            self._holder.unlink(missing_ok=True)
            self._holder = None
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
            _HELD_HERE.discard(self.root.resolve())

    @classmethod
    def busy(cls, root: Path) -> FolderLock | None:
        """The lock of the build-state folder ``root`` when another process holds it now, else None.

        Changes nothing (a folder never built into is not busy), and looks under the guard, so a
        build deciding at the same moment is not misled by the look. The files are opened for
        writing where that is allowed: NFS and SMB emulate ``flock`` with byte-range locks, and an
        exclusive one needs a file open for writing. A folder this process holds itself (a build
        that reads what it wrote) is not busy."""
        if fcntl is None or Path(root).resolve() in _HELD_HERE:
            return None
        guard = _open_existing(Path(root) / "lock.guard")
        if guard is None:
            return None
        try:
            fcntl.flock(guard, fcntl.LOCK_EX)
            fd = _open_existing(Path(root) / "lock")
            if fd is None:
                return None
            try:
                if _taken(fd):
                    return cls(root)
            finally:
                os.close(fd)
        except OSError as exc:
            if exc.errno not in NO_LOCKS:
                logger.warning("cannot tell whether a build holds %s (%s): reading it anyway", Path(root).parent, exc)
            return None
        finally:
            os.close(guard)
        return None


def _taken(fd: int) -> bool:
    """Whether another open file holds a lock on the file of ``fd`` (tried with an exclusive lock
    that is not waited for; the caller's closing of ``fd`` drops it when it was had)."""
    assert fcntl is not None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    return False


def _open_existing(path: Path) -> int | None:
    """``path`` opened for reading and writing, else for reading (a read-only dataset); None when
    it does not exist or cannot be opened."""
    for flags in (os.O_RDWR, os.O_RDONLY):
        try:
            return os.open(path, flags)
        except OSError as exc:
            if exc.errno not in (errno.EACCES, errno.EROFS, errno.EPERM):  # missing, or unusable
                return None
    return None


#: The build-state folders this process holds (resolved): :meth:`FolderLock.busy` says they are not busy.
_HELD_HERE: set[Path] = set()


_warned_no_locks: set[Path] = set()


def _flock(fd: int, operation: int, root: Path) -> bool:
    """``flock(fd, operation)``; False (with a warning, once per folder) where the file system
    has no locks."""
    assert fcntl is not None
    try:
        fcntl.flock(fd, operation)
        return True
    except OSError as exc:
        if exc.errno not in NO_LOCKS:
            raise
        if root not in _warned_no_locks:
            _warned_no_locks.add(root)
            logger.warning("the file system of %s has no file locks: two builds with different options started "
                           "into it at once would not be stopped; give each build its own --out", root.parent)
        return False
