"""The processes a build may use: the cores it is given, and the fork server its workers come from.

Kept free of everything but the standard library, so that the command line can start the fork
server before it imports the builder (:mod:`osmseg.cli.launch`): the server then imports
osmseg (about 0.7 s) while the command does the same, instead of after it, and the workers of
``osmseg build`` start that much sooner. :mod:`osmseg.builder.workers` makes its pools from
:func:`worker_context`, the same server.

Why a fork server (``spawn`` where the platform has none): a plain ``fork`` of a process that
has already read a PBF would inherit libosmium's thread pool without its threads, and hang. The
server imports :data:`PRELOAD` once; each worker is then forked from it in milliseconds.

It also says who owns a temporary thing and whether that owner is still there
(:func:`owner`, :func:`owner_gone`): temporary files and folders carry ``HOST-PID`` in their
names, so the next run can sweep what a killed process left (:func:`sweep_owned`) without
touching what a live one (a worker, a shard started at the same time) is still writing. The
command line gives each run its own temporary folder (:func:`use_private_temp_dir`), so what
the standard library, the fork server and the workers put in ``$TMPDIR`` goes with the run, or
with the next run after a ``kill -9``. And a ``SIGTERM`` ends a command as a Ctrl-C does
(:func:`terminate_by_exception`): everything unwinds and removes its temporary files.
Imports: the standard library only.
"""

from __future__ import annotations

import _thread
import math
import multiprocessing
import multiprocessing.context
import multiprocessing.forkserver
import multiprocessing.resource_tracker
import multiprocessing.util
import os
import re
import shutil
import signal
import socket
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import Any

try:
    import fcntl
except ImportError:  # Windows: no private folder (nothing can tell a live run's from a dead one's)
    fcntl = None  # type: ignore[assignment]

__all__ = ["FOREIGN_SECONDS", "INTERRUPTED", "PRELOAD", "TERMINATED", "Terminated", "available_cores", "deferred_termination", "interrupts_deferred", "owner", "owner_gone", "signals_held", "start_fork_server",
           "stop_unless_deferred", "sweep_owned", "terminate_by_exception", "use_private_temp_dir", "worker_context"]

#: A temporary thing left by a process on another machine (a shard of a cluster build on a shared
#: folder) is swept only this long after its last change: no write of osmseg takes that long, and
#: whether that process still runs cannot be asked from here.
FOREIGN_SECONDS = 3600.0
#: What a command stopped by Ctrl-C says (exit 130), and one stopped by SIGTERM (exit 143).
INTERRUPTED = "interrupted: rerun the same command to resume; finished work is kept"
TERMINATED = "terminated (SIGTERM): rerun the same command to resume; finished work is kept"
#: How this run's own temporary folder in ``$TMPDIR`` is named: ``osmseg-run-RANDOM``.
PRIVATE_TEMP_PREFIX = "osmseg-run-"
#: The file in it whose shared lock says its run is alive, and the descriptors this process holds.
_ALIVE = "lock"
_HELD: list[int] = []
#: The socket the fork server listens on, inside the temporary folder (multiprocessing's names),
#: and the longest name a Unix socket may have (Linux: 108 bytes with the final NUL).
_FORK_SERVER_SOCKET = "/pymp-abcdefgh/listener-abcdefgh"
_SOCKET_PATH_MAX = 100

#: Modules the fork server imports once, so that each worker starts without importing them.
PRELOAD = ["osmseg.builder.slots"]


def available_cores() -> int:
    """The cores this process may use: its CPU affinity where the OS has one (a Slurm allocation
    of 4 cores on a 64-core node gives 4), else the machine's count, and no more than a cgroup's
    CPU quota allows (a container given 2 CPUs: ``docker --cpus 2``, a Kubernetes CPU limit).

    >>> available_cores() >= 1
    True
    """
    affinity = getattr(os, "sched_getaffinity", None)
    cores = len(affinity(0)) if affinity is not None else (os.cpu_count() or 1)
    quota = _cgroup_cpu_quota()
    return max(1, min(cores, math.ceil(quota)) if quota else cores)


def _cgroup_cpu_quota() -> float | None:
    """CPUs the cgroup's CFS quota allows (cgroup v2 ``cpu.max``, or v1), or None when unlimited."""
    try:
        quota, period = Path("/sys/fs/cgroup/cpu.max").read_text().split()[:2]
        return None if quota == "max" else int(quota) / int(period)
    except (OSError, ValueError):
        pass
    try:
        quota_us = int(Path("/sys/fs/cgroup/cpu/cpu.cfs_quota_us").read_text())
        period_us = int(Path("/sys/fs/cgroup/cpu/cpu.cfs_period_us").read_text())
        return None if quota_us <= 0 or period_us <= 0 else quota_us / period_us
    except (OSError, ValueError):
        return None


def worker_context() -> multiprocessing.context.BaseContext:
    """The fork server (importing :data:`PRELOAD`) where the platform has one, else spawn."""
    if "forkserver" in multiprocessing.get_all_start_methods():
        context = multiprocessing.get_context("forkserver")
        context.set_forkserver_preload(PRELOAD)
        return context
    return multiprocessing.get_context("spawn")


def start_fork_server() -> bool:
    """Start the workers' fork server now (it imports :data:`PRELOAD` in the background), unless
    it runs already or the platform has none. True when there is one.

    SIGINT is blocked while the server is started, as the standard library does for its
    resource tracker: the server inherits the mask across ``exec``, so a Ctrl-C while it is
    still importing stops the command with one message, not also the server's traceback (its
    workers ignore SIGINT; the build stops them). A Ctrl-C meanwhile stays pending for this
    process and arrives when the mask is lifted: nothing is lost.
    """
    if not isinstance(worker_context(), multiprocessing.context.ForkServerContext):
        return False  # (where there is a fork server, POSIX, there is pthread_sigmask)
    # the resource tracker first: starting it lifts a SIGINT block of the caller's (it blocks and
    # unblocks SIGINT around its own start), and the server's start would start it
    multiprocessing.resource_tracker.ensure_running()
    with _blocked({signal.SIGINT}):
        multiprocessing.forkserver.ensure_running()
    return True


@contextmanager
def _blocked(signals: set[signal.Signals]) -> Iterator[None]:
    """Block ``signals`` for this thread until the block ends, then restore the mask as it was.

    The mask is read before anything changes, so a handler that runs between the two calls (a
    signal that arrived earlier) leaves it as it was instead of blocked for the rest of the run.
    """
    before = signal.pthread_sigmask(signal.SIG_BLOCK, [])  # reads the mask, changes nothing
    try:
        signal.pthread_sigmask(signal.SIG_BLOCK, signals)
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)


def owner() -> str:
    """``HOST-PID`` of this process, as temporary names carry it (host made name-safe). On Linux
    HOST also names the process-id namespace: containers that share a host name (host
    networking) but not their process ids must not judge each other's pids.

    >>> owner().rsplit("-", 1)[1] == str(os.getpid())
    True
    """
    host = re.sub(r"[^A-Za-z0-9_]", "_", socket.gethostname()) or "host"
    try:
        host += f"_{os.stat('/proc/self/ns/pid').st_ino}"
    except OSError:  # not Linux
        pass
    return f"{host}-{os.getpid()}"


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs: exists, and (Linux) is not a zombie, which has ended and only
    waits for its parent to note it (a killed worker whose fork server has not reaped it yet)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    try:
        return "\nState:\tZ" not in Path(f"/proc/{pid}/status").read_text()
    except OSError:  # not Linux, or it ended this instant
        return Path("/proc").is_dir() is False


def owner_gone(name_owner: str, path: Path) -> bool:
    """Whether the process ``HOST-PID`` that named ``path`` will never come back to it.

    One of this machine is gone when its pid is; one of another machine (or one that cannot be
    asked: Windows, where ``os.kill(pid, 0)`` would send a Ctrl-C) once ``path`` has been
    unchanged for :data:`FOREIGN_SECONDS`; a name without an owner always is.

    >>> owner_gone(owner(), Path(".")), owner_gone("", Path("."))
    (False, True)
    """
    host, _, pid = name_owner.rpartition("-")
    if not (host and pid.isdigit()):
        return True
    if host == owner().rsplit("-", 1)[0] and os.name != "nt":
        return not _alive(int(pid))
    try:
        return time.time() - path.stat().st_mtime > FOREIGN_SECONDS
    except OSError:
        return False  # gone already, or not ours to judge


def sweep_owned(folder: Path, prefix: str) -> int:
    """Remove the files and folders ``PREFIX`` + ``HOST-PID-...`` in ``folder`` whose owner is gone
    (:func:`owner_gone`); how many. Those of live processes stay."""
    removed = 0
    try:
        entries = list(Path(folder).glob(f"{glob_escape(prefix)}*"))
    except OSError:
        return 0
    for entry in entries:
        match = re.match(r"(.+-\d+)-", entry.name[len(prefix):])
        if match is None or not owner_gone(match.group(1), entry):
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)
        else:
            try:
                entry.unlink()
            except OSError:
                continue
        removed += 1
    return removed


def glob_escape(text: str) -> str:
    """``text`` with glob's special characters escaped.

    >>> glob_escape("entries-[1]*")
    'entries-[[]1][*]'
    """
    return re.sub(r"([*?\[])", r"[\1]", text)


def use_private_temp_dir() -> Path | None:
    """Give this run its own temporary folder in ``$TMPDIR`` (and first sweep those of runs that
    were killed): ``TMPDIR`` and :mod:`tempfile` point at it from now on, so the folders the
    standard library makes (``pymp-*`` of the fork server), the fork server and the workers'
    own, and GDAL's go inside, and it is removed when this process exits. A ``kill -9`` leaves
    it, and the next run of any osmseg command removes it. For the command line only: a library
    never changes its caller's environment. None (nothing changed) where ``$TMPDIR`` cannot
    take it, or is so long a path that the fork server's socket inside would not fit.

    Whether a folder's run is still there is asked of the kernel, not guessed from a pid: the run
    holds a shared ``flock`` on ``lock`` inside for its whole life (dropped however it ends), and a
    folder is swept only when an exclusive lock on it is free. So runs in other containers or
    machines that share ``$TMPDIR``, however long they last, keep their folder; and the name is
    short (``osmseg-run-XXXXXXXX``), leaving room for the socket's path.
    """
    base = Path(tempfile.gettempdir())
    if fcntl is None or len(str(base / PRIVATE_TEMP_PREFIX)) + 8 + len(_FORK_SERVER_SOCKET) > _SOCKET_PATH_MAX:
        return None
    try:
        _sweep_private_temp_dirs(base)
        private = Path(tempfile.mkdtemp(prefix=PRIVATE_TEMP_PREFIX, dir=base))
        # the lock is taken before the file has its name: a sweep that starts this instant finds a
        # folder without one ("being made", kept), never an unlocked lock file of a live run
        fd = os.open(private / (_ALIVE + ".new"), os.O_RDWR | os.O_CREAT, 0o600)
        fcntl.flock(fd, fcntl.LOCK_SH)  # held until this process ends: its folder is not to be swept
        os.rename(private / (_ALIVE + ".new"), private / _ALIVE)
    except OSError:
        return None
    _HELD.append(fd)
    os.environ["TMPDIR"] = str(private)
    tempfile.tempdir = str(private)
    # at exit after multiprocessing's own clean-up of its folder inside (priority -100), not before it
    multiprocessing.util.Finalize(None, shutil.rmtree, args=(str(private), True), exitpriority=-200)
    return private


def _sweep_private_temp_dirs(base: Path) -> int:
    """Remove the private temporary folders (:func:`use_private_temp_dir`) of runs that have ended
    (their lock is free); a folder without its lock yet is left until it is an hour old."""
    assert fcntl is not None
    removed = 0
    for folder in base.glob(f"{PRIVATE_TEMP_PREFIX}*"):
        try:
            fd = os.open(folder / _ALIVE, os.O_RDWR)
        except FileNotFoundError:  # being made this instant, or not ours: only when long unchanged
            try:
                if folder.is_dir() and time.time() - folder.stat().st_mtime > FOREIGN_SECONDS:
                    shutil.rmtree(folder, ignore_errors=True)
                    removed += 1
            except OSError:
                pass
            continue
        except OSError:  # someone else's (permissions): theirs to sweep
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            continue  # its run is alive
        finally:
            os.close(fd)
        shutil.rmtree(folder, ignore_errors=True)
        removed += 1
    return removed


class Terminated(BaseException):
    """Raised in the main thread by ``SIGTERM`` (see :func:`terminate_by_exception`): a command
    asked to end (``kill``, a batch scheduler's time limit, ``docker stop``) unwinds as it does
    for a Ctrl-C, so temporary files are removed and workers stopped, and says so."""


#: main thread's depth of :func:`deferred_termination` blocks, and the stop a signal left waiting for their end
_deferral: dict[str, Any] = {"depth": 0, "pending": None}


def stop_unless_deferred(stop: Callable[[], BaseException]) -> None:
    """Raise ``stop()`` (from a signal handler) now, or at the end of the open
    :func:`deferred_termination` block when one is open in this process's main thread.

    ``stop`` makes the exception rather than being it: an exception held in a local variable of
    a frame its own traceback passes through is a reference cycle, which keeps every frame it
    unwinds (and what they hold: a training loop's DataLoader workers) alive until the garbage
    collector runs, which may be after the exit handlers that wait for those workers.
    """
    if _deferral["depth"]:
        _deferral["pending"] = _deferral["pending"] or stop
        return
    raise stop()


def _on_sigterm(signum: int, frame: FrameType | None) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # once: a second kill ends the process at once, as asked
    stop_unless_deferred(Terminated)


@contextmanager
def deferred_termination() -> Iterator[None]:
    """Hold a ``SIGTERM`` (as :func:`terminate_by_exception` or a build worker turns it) until the block ends.

    For the few steps that must not be cut in two by the exception: creating a temporary file
    and remembering its name, so the unwinding removes it. Elsewhere than the main thread the
    block changes nothing (signal handlers only ever run there).

    >>> with deferred_termination():
    ...     pass
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _deferral["depth"] += 1
    try:
        yield
    finally:
        _deferral["depth"] -= 1
    if not _deferral["depth"] and _deferral["pending"] is not None:
        stop, _deferral["pending"] = _deferral["pending"], None
        raise stop()


@contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Hold a Ctrl-C (and a SIGTERM the command line turned into an exception) back until the
    block is done, then deliver it to the handler that was there.

    For steps a signal must not cut in two: the builder's submits that start worker processes
    (interrupted between the fork server's fork and the pool noting the new process, the build
    would stop without stopping that worker, which then fails to unpickle its start-up data with a
    traceback), and a checkpoint being written (``torch.save`` cut inside its zip writer raises
    its own error over the interrupt). Off the main thread the block changes nothing.

    >>> with interrupts_deferred():
    ...     pass
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[tuple[int, Any]] = []
    # SIGINT unless ignored; SIGTERM where the command line made it an exception (else it kills at once)
    deferred = [s for s in (signal.SIGINT, signal.SIGTERM)
                if signal.getsignal(s) != signal.SIG_IGN and (s == signal.SIGINT or callable(signal.getsignal(s)))]
    previous = {s: signal.signal(s, lambda signum, frame: caught.append((signum, frame))) for s in deferred}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        if caught:
            handler = previous[signal.Signals(caught[0][0])]
            if callable(handler):
                handler(*caught[0])  # Python's default SIGINT handler raises KeyboardInterrupt
            else:  # SIGINT set to its default action: what Python's own handler would have raised
                raise KeyboardInterrupt


@contextmanager
def signals_held() -> Iterator[None]:
    """Hold Ctrl-C and ``SIGTERM`` back (blocked for this thread) until the block ends, where
    they arrive as they would have.

    For the command line's imports: a Ctrl-C that lands inside a compiled module's initialisation
    (measured: pyproj's Cython ``_sync``, 0.66 s after start) unwinds as usual, the command says it
    was interrupted and exits 130, and then CPython, having seen a ``KeyboardInterrupt`` escape
    that module's code, kills the process with SIGINT on its way out (status -2 to a parent that
    waits for it); elsewhere such an interrupt surfaced as an unrelated ``TypeError`` from a
    half-imported module. A module is imported whole, or not at all, in well under a second. No
    change where signals cannot be blocked, or off the main thread (handlers only run there).

    >>> with signals_held():
    ...     pass
    """
    if not hasattr(signal, "pthread_sigmask") or threading.current_thread() is not threading.main_thread():
        yield
        return
    with _blocked({signal.SIGINT, signal.SIGTERM}):
        yield


def terminate_by_exception() -> None:
    """Turn this process's ``SIGTERM`` into :class:`Terminated` in the main thread (the command line's
    choice: a library leaves its caller's signal handlers alone), and keep a stop from being lost.

    Python runs a signal's handler at whatever line the main thread is on, also inside a
    finalizer (a ``weakref`` callback, a ``__del__``), where an exception is printed as "Exception
    ignored" and dropped: measured, 3 of 40 training runs given a SIGTERM went on to their last
    epoch and exited 0. A stop dropped that way is delivered again, to the next line of ordinary code.
    """
    signal.signal(signal.SIGTERM, _on_sigterm)
    if hasattr(signal, "pthread_sigmask") and threading.current_thread() is threading.main_thread():
        # a stop the parent held blocked across exec (a process that started this one from inside its
        # own blocked section) would never arrive: the command line decides, as the resource tracker does
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    if sys.unraisablehook is not _redeliver_stops:
        _hook["previous"] = sys.unraisablehook
        sys.unraisablehook = _redeliver_stops


_hook: dict[str, Any] = {"previous": sys.__unraisablehook__}


def _redeliver_stops(unraisable: Any) -> None:
    """``sys.unraisablehook``: a :class:`Terminated` or ``KeyboardInterrupt`` a finalizer swallowed
    is raised again at the main thread's next line of ordinary code. A helper thread trips the
    signal: from the main thread ``_thread.interrupt_main`` runs the handler at once, here in the
    hook, where its exception would be dropped again (measured). If the main thread is still in a
    finalizer then, the hook runs again."""
    exc = unraisable.exc_value
    if isinstance(exc, Terminated):
        signal.signal(signal.SIGTERM, _on_sigterm)  # its handler went back to the default when it ran
        signum = signal.SIGTERM
    elif isinstance(exc, KeyboardInterrupt) and callable(signal.getsignal(signal.SIGINT)):
        signum = signal.SIGINT
    else:
        _hook["previous"](unraisable)
        return
    _thread.start_new_thread(_trip_soon, (signum,))  # not threading.Thread: its start() waits, in Python code


def _trip_soon(signum: signal.Signals) -> None:
    """Set ``signum``'s flag for the main thread a moment from now (after the hook has returned)."""
    time.sleep(0.005)
    _thread.interrupt_main(signum)


def quiet_resource_tracker() -> None:
    """Keep the resource tracker's "leaked semaphore objects" warning for itself.

    After a ``kill -9`` of a build the tracker (a process of its own) removes the semaphores the
    build held, as it should, but first warns about them on the terminal the user killed the
    build from. It takes its warning filters from this interpreter's ``-W`` options when it
    starts, so one added here before it starts keeps it quiet; an interrupted or terminated
    build releases its semaphores itself and leaves the tracker nothing to warn about.
    """
    rule = "ignore:resource_tracker:UserWarning"
    if rule not in sys.warnoptions:
        sys.warnoptions.append(rule)
