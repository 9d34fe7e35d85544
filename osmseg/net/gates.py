"""Per-host politeness shared by every process of a build: lock files for slots, a file for pauses.

A build on several worker processes must stay one polite client: the OSM API allows two
requests at a time *from us*, not two per process, and a ``Retry-After`` answered to one
process must hold the others back too. :class:`SharedHostGate` has the interface of
:class:`osmseg.net.failures.HostGate` (``slots``, ``pause``, ``wait``) but keeps its state in a
folder every process of the build is given:

* ``HOST.N.lock`` (``N`` < the host's limit): a request in flight holds an exclusive
  ``flock`` on one of them. Locks belong to an open file, so two threads of one process
  never share one, and the kernel drops a lock when its process dies (a killed worker never
  leaves a slot taken).
* ``HOST.pause``: the wall-clock time before which nobody may send to the host, replaced
  atomically (readers never see half a number) under ``HOST.pause.lock``.

Local folders only: ``flock`` is exact on a local file system; give each machine of a cluster
its own folder (the builder uses a temporary one per build). POSIX only (``fcntl``); where it
is missing, :func:`shared_gates_supported` is False and callers keep per-process gates.
Imports: the standard library and :mod:`osmseg.net.failures` (its stop event).
"""

from __future__ import annotations

import os
import re
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from osmseg.net.failures import STOPPING

try:
    import fcntl
except ImportError:  # Windows
    fcntl = None  # type: ignore[assignment]

__all__ = ["SharedHostGate", "shared_gates_supported"]

#: Seconds between tries while every slot of a host is taken (a request takes far longer).
POLL = 0.005
POLL_MAX = 0.05


def shared_gates_supported() -> bool:
    """True where file locks can share gates between processes (POSIX)."""
    return fcntl is not None


def _file_name(host: str) -> str:
    """A file-name-safe form of a host name.

    >>> _file_name("api.openstreetmap.org"), _file_name("[::1]")
    ('api.openstreetmap.org', '___1_')
    """
    return re.sub(r"[^A-Za-z0-9.-]", "_", host) or "_"


class SharedHostGate:
    """At most ``limit`` requests to ``host`` in flight across every process using ``folder``,
    and one ``Retry-After`` pause for all of them."""

    def __init__(self, folder: Path, host: str, limit: int) -> None:
        if fcntl is None:
            raise OSError("shared host gates need fcntl (POSIX)")
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        stem = _file_name(host)
        self.limit = int(limit)
        self._slot_paths = [self.folder / f"{stem}.{i}.lock" for i in range(self.limit)]
        self._pause_path = self.folder / f"{stem}.pause"
        self._pause_lock = self.folder / f"{stem}.pause.lock"
        self._start = os.getpid() % self.limit  # processes start their search at different slots

    @property
    @contextmanager
    def slots(self) -> Iterator[None]:
        """Hold one of the host's slots for the block (waits while all are taken)."""
        fd = self._acquire()
        try:
            yield
        finally:
            os.close(fd)  # closing the file releases its lock

    def _acquire(self) -> int:
        assert fcntl is not None
        delay = POLL
        start = (self._start + threading.get_ident()) % self.limit
        while True:
            for k in range(self.limit):
                fd = os.open(self._slot_paths[(start + k) % self.limit], os.O_RDWR | os.O_CREAT, 0o644)
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    return fd
                except BlockingIOError:
                    os.close(fd)
                except BaseException:
                    os.close(fd)
                    raise
            time.sleep(delay)
            delay = min(POLL_MAX, delay * 2)

    def pause(self, seconds: float) -> None:
        """Ask every process's callers of this host to wait ``seconds`` from now before sending."""
        assert fcntl is not None
        until = time.time() + seconds
        fd = os.open(self._pause_lock, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            if until > self._not_before():
                tmp = self._pause_path.with_name(f".{self._pause_path.name}.{os.getpid()}.{threading.get_ident()}")
                tmp.write_text(repr(until))
                os.replace(tmp, self._pause_path)
        finally:
            os.close(fd)

    def _not_before(self) -> float:
        try:
            return float(self._pause_path.read_text())
        except (OSError, ValueError):
            return 0.0

    def wait(self) -> None:
        """Sleep until the host's pause (if any) is over (or the process is stopping)."""
        while not STOPPING.is_set():
            delay = self._not_before() - time.time()
            if delay <= 0:
                return
            STOPPING.wait(min(delay, 1.0))  # a longer pause set meanwhile is seen within a second
