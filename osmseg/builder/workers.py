"""Build a dataset's slots on several processes: every core busy, the bytes of one process.

A slot's outcome depends only on the seed, the slot number and the data (:mod:`osmseg.builder.state`),
never on which process builds it or when, so :class:`SlotRunner` hands slots to worker
processes in slot order and the dataset is byte-identical whatever ``--workers`` is; a build
interrupted at any moment resumes from its state folder like a single-process one, and
``--shard K/N`` still splits it exactly (each shard may run its own workers).

How the workers are made and kept in line:

* **Processes from a fork server** (``spawn`` where there is none;
  :func:`osmseg.runtime.processes.worker_context`): a plain ``fork`` of a process that has already
  read a PBF would inherit libosmium's thread pool without its threads, and hang. The fork
  server imports osmseg once; each worker then starts in milliseconds. ``osmseg build``
  starts the server before it imports the builder (:mod:`osmseg.cli.launch`).
* **One pipeline per worker**, opened once (:func:`osmseg.builder.slots.open_pipeline`): its own HTTP
  client, imagery provider (a local GeoTIFF stays open) and OSM source, on the region file the
  parent cut before starting them.
* **Polite HTTP across workers**: the workers' clients share their per-host limits and
  ``Retry-After`` pauses through lock files in a temporary folder (:mod:`osmseg.net.gates`),
  so two workers are still one client to the OSM API.
* **Logging**: a worker's records go to the parent, which hands each to its own logger of the
  same name, so the caller's handlers and filters (the CLI's ``-q``/``-v``) apply as in one
  process. The parent's logging is never configured here; a worker only forwards.
* **Stopping**: workers ignore SIGINT (Ctrl-C reaches the whole process group); the parent
  drops what is queued and stops the workers (SIGTERM: the slot being built unwinds and removes
  its temporary files; a worker still busy after a moment is killed; every write is atomic).
  A worker also ends when the build process ends in any other way (``kill -9``:
  :func:`_die_with_build`), so no worker is left writing behind a rerun's back.

Imports: osmseg core below it (slots, state, net, processes).
"""

from __future__ import annotations

import bisect
import logging
import logging.handlers
import multiprocessing
import multiprocessing.util
import os
import select
import signal
import tempfile
import threading
import time
from collections.abc import Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from queue import Empty
from types import TracebackType
from typing import Any

import cv2

from osmseg.builder.config import BuildConfig
from osmseg.builder.records import SlotOutcome
from osmseg.builder.slots import BuildContext, http_config, open_pipeline, run_slot
from osmseg.builder.state import BuildState
from osmseg.errors import DatasetError
from osmseg.grid import LngLatBBox
from osmseg.net.http import HttpClient
from osmseg.osm.base import RegionSource
from osmseg.output.atomic import remove_own_temp_files
from osmseg.output.overview import OVERVIEW_SAMPLES
from osmseg.runtime.processes import interrupts_deferred, stop_unless_deferred, worker_context

__all__ = ["FirstSamples", "SlotRunner", "WorkerSetup"]

logger = logging.getLogger(__name__)

#: Slots queued per worker beyond the one it builds: enough to keep it busy, few enough that
#: an interrupted build has little queued work to drop and memory does not grow with the build.
QUEUED_PER_WORKER = 2
#: Seconds a stopping worker gets to unwind before it is killed.
STOP_SECONDS = 3.0
#: GDAL block cache of a worker in MB, unless GDAL_CACHEMAX says otherwise.
WORKER_GDAL_CACHE_MB = 256


@dataclass(frozen=True)
class WorkerSetup:
    """What a worker needs to build slots: the build, its environment (keys travel through the
    pool's pipe, never a file), the region boxes the parent prepared, the shared gate folder and
    where to send log records."""

    config: BuildConfig
    env: dict[str, str]
    regions: tuple[LngLatBBox, ...]
    gate_dir: Path | None
    log_queue: Any
    log_level: int
    parent: int  # the build's process id: workers end with it


class _Worker:
    """The state of one worker process: its pipeline and the build state it records into, or
    why it could not open them (raised by its first task, so it reaches the build as it is)."""

    ctx: BuildContext
    failure: BaseException | None = None


_WORKER = _Worker()


def _die_with_build(pid: int) -> None:
    """End this worker the moment the build process ``pid`` ends, however it ends (``kill -9``).

    A worker is a child of the fork server, not of the build, and it holds a copy of every pipe
    end the pool gave it, so neither a parent-death signal nor an end-of-file would reach it: a
    killed build would leave its workers blocked forever. A thread waits on a pidfd of the build
    (Linux), or polls it elsewhere, and exits the process when the build is gone. Every write of
    a worker is atomic, so stopping it anywhere loses nothing but the slot in progress; the
    temporary files it was writing go with it (a resumed build may have swept the folder while
    this worker still lived, and kept them as a live writer's).
    """
    if os.name == "nt":  # os.kill(pid, 0) would send the build a Ctrl-C there; spawn's pipes end workers
        return

    def watch() -> None:
        try:
            fd = os.pidfd_open(pid)
        except (AttributeError, OSError):
            fd = None
        if fd is not None:
            select.select([fd], [], [])  # readable once the process has ended
        else:
            while True:
                time.sleep(0.5)
                try:
                    os.kill(pid, 0)
                except ProcessLookupError:
                    break
                except PermissionError:  # the pid was reused by someone else's process
                    break
        remove_own_temp_files()  # the build that resumes may have swept already, while this worker lived
        os._exit(1)

    threading.Thread(target=watch, name="osmseg-watch-build", daemon=True).start()


def _start_worker(setup: WorkerSetup) -> None:
    """Pool initializer: forward logging, then open this process's pipeline once."""
    _die_with_build(setup.parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides when to stop, and says so by SIGTERM
    # stopped while opening its sources (Ctrl-C as a build starts), a worker has written nothing:
    # it ends at once and quietly, not with an "Exception in initializer" traceback in the build's log
    signal.signal(signal.SIGTERM, _end_now)
    root = logging.getLogger()
    for handler in list(root.handlers):
        root.removeHandler(handler)
    root.addHandler(logging.handlers.QueueHandler(setup.log_queue))
    root.setLevel(setup.log_level)
    # the build's environment, not the fork server's (started earlier, maybe before a notebook set
    # GDAL_*, AWS_* or PROJ_* variables): the libraries read it from os.environ
    os.environ.update(setup.env)
    # GDAL's block cache is 5 % of the machine's memory per process unless told: with a worker per
    # core that is a third of it in caches that random samples barely reuse
    os.environ.setdefault("GDAL_CACHEMAX", str(WORKER_GDAL_CACHE_MB))
    # a worker per core: OpenCV's own threads (warping imagery) would only compete with the others
    cv2.setNumThreads(1)
    try:
        client = HttpClient(http_config(setup.config, setup.gate_dir))
        multiprocessing.util.Finalize(client, client.close, exitpriority=10)  # atexit does not run in workers
        pipe = open_pipeline(setup.config, client, setup.env)
        if setup.regions and isinstance(pipe.osm, RegionSource):
            pipe.osm.prepare(list(setup.regions))  # the parent cut it: this only finds the region file
        state = BuildState(setup.config.out_dir)
        state.join(setup.config.identity())  # the folder stays held while a worker may still write
    except Exception as exc:  # an initializer's error would only say "a worker process died"
        _WORKER.failure = exc
        return
    finally:
        signal.signal(signal.SIGTERM, _on_terminate)  # from here on a slot may be writing: unwind it
    _WORKER.ctx = BuildContext(setup.config, pipe, state)


class _Stop(SystemExit):
    """Raised in a worker by SIGTERM: the build is stopping (Ctrl-C, an error elsewhere)."""


def _on_terminate(signum: int, frame: object) -> None:
    stop_unless_deferred(_stop)  # not between creating a temporary file and knowing its name


def _stop() -> _Stop:
    return _Stop(1)


def _end_now(signum: int, frame: object) -> None:
    os._exit(1)


def _build_slot(slot: int, keep_thumbnails: bool) -> SlotOutcome:
    """Pool task: build one slot in this worker.

    Stopped by SIGTERM, the slot's code unwinds (every file it was writing under a temporary name
    is removed) and the worker ends at once, before the pool could hand it another slot.
    """
    if _WORKER.failure is not None:
        raise _WORKER.failure
    try:
        return run_slot(_WORKER.ctx, slot, keep_thumbnails)
    except _Stop:
        os._exit(1)


class _LogForwarder:
    """Hands the records workers put on ``queue`` to the parent's loggers of the same names.

    A thread of its own (not ``logging.handlers.QueueListener``): stopping a listener puts a
    sentinel on the queue, which needs the queue's write lock, and a worker killed while it
    wrote a record (Ctrl-C) may have died holding that lock: the build would hang on exit. This
    thread only reads, with a timeout, and after a kill it is not waited for at all (it is a
    daemon; a record cut in half by the kill may leave it blocked, harmlessly).
    """

    def __init__(self, queue: Any) -> None:
        self.queue = queue
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._run, name="osmseg-worker-logs", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while True:
            try:
                record = self.queue.get(timeout=0.1)
            except Empty:
                if self.stopping.is_set():
                    return
                continue
            except (EOFError, OSError):  # the queue was closed under us
                return
            logging.getLogger(record.name).handle(record)

    def stop(self, drain: bool) -> None:
        """Stop; with ``drain`` (the workers ended normally) after forwarding every record left."""
        self.stopping.set()
        if drain:
            self.thread.join(timeout=10)


class FirstSamples:
    """Which slots may hold one of the first ``OVERVIEW_SAMPLES`` accepted samples (the ones the
    overview sheet shows), from the slots known to be accepted so far. Conservative: a slot is
    only ruled out once that many lower slots are known to be accepted.

    >>> first = FirstSamples(2)
    >>> first.accepted(3); first.accepted(5)
    >>> first.may_show(4), first.may_show(6)
    (True, False)
    """

    def __init__(self, shown: int = OVERVIEW_SAMPLES) -> None:
        self.shown = shown
        self._lowest: list[int] = []

    def accepted(self, slot: int) -> None:
        bisect.insort(self._lowest, slot)
        del self._lowest[self.shown:]

    def may_show(self, slot: int) -> bool:
        return bisect.bisect_left(self._lowest, slot) < self.shown


class SlotRunner:
    """Builds slots in this process (one worker) or on a pool of worker processes.

    Use as a context manager; :meth:`run` yields each slot's outcome as it finishes::

        with SlotRunner(BuildContext(config, pipe, state), env, workers=4, regions=()) as runner:
            for outcome in runner.run(todo, first_samples):
                ...
    """

    def __init__(self, ctx: BuildContext, env: dict[str, str], workers: int,
                 regions: tuple[LngLatBBox, ...]) -> None:
        self.ctx, self.env = ctx, env
        self.workers = max(1, int(workers))
        self.regions = regions
        self._stack = ExitStack()
        self._pool: ProcessPoolExecutor | None = None
        self._logs: _LogForwarder | None = None

    def __enter__(self) -> SlotRunner:
        if self.workers > 1:
            self._start_pool()
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        clean = kind is None
        try:
            if self._pool is not None:
                if clean:
                    self._pool.shutdown(wait=True)
                else:  # an error or Ctrl-C: drop queued slots and stop the workers now
                    _kill(self._pool)
        finally:
            if self._logs is not None:
                self._logs.stop(drain=clean)
            self._stack.close()

    def _start_pool(self) -> None:
        context = worker_context()
        queue = context.Queue()
        self._logs = _LogForwarder(queue)
        gate_dir = Path(self._stack.enter_context(tempfile.TemporaryDirectory(prefix="osmseg-hosts-")))
        setup = WorkerSetup(config=self.ctx.config, env=self.env, regions=self.regions, gate_dir=gate_dir,
                            log_queue=queue, log_level=logging.getLogger().getEffectiveLevel(), parent=os.getpid())
        self._pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=context, initializer=_start_worker,
                                         initargs=(setup,))

    def run(self, slots: list[int], first: FirstSamples) -> Iterator[SlotOutcome]:
        """Build ``slots`` (in slot order; outcomes come as they finish). ``first`` says which
        slots keep thumbnails for the overview, and learns of each accepted sample."""
        if self._pool is None:
            for slot in slots:
                outcome = run_slot(self.ctx, slot, first.may_show(slot))
                if outcome.status == "accepted":
                    first.accepted(slot)
                yield outcome
            return
        yield from self._run_pool(self._pool, slots, first)

    def _run_pool(self, pool: ProcessPoolExecutor, slots: list[int], first: FirstSamples) -> Iterator[SlotOutcome]:
        try:
            yield from self._feed(pool, slots, first)
        except BrokenProcessPool:
            raise DatasetError("a worker process died (killed, or out of memory?): run the same command again to "
                               "resume, with fewer --workers if memory is short") from None

    def _feed(self, pool: ProcessPoolExecutor, slots: list[int], first: FirstSamples) -> Iterator[SlotOutcome]:
        """Keep each worker busy with a few slots queued (in slot order); yield outcomes as they come."""
        pending: set[Future[SlotOutcome]] = set()
        queue = iter(slots)
        limit = self.workers * (1 + QUEUED_PER_WORKER)
        def submit(s: int) -> Future[SlotOutcome]:
            return pool.submit(_build_slot, s, first.may_show(s))

        with interrupts_deferred():  # the first submits start the worker processes
            for slot in queue:
                pending.add(submit(slot))
                if len(pending) >= limit:
                    break
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                outcome = future.result()
                if outcome.status == "accepted":
                    first.accepted(outcome.slot)
                yield outcome
            for slot in queue:
                pending.add(submit(slot))
                if len(pending) >= limit:
                    break


def _kill(pool: ProcessPoolExecutor) -> None:
    """Stop a pool at once: drop queued tasks, ask the workers to stop (SIGTERM: a slot being built
    unwinds and removes its temporary files), kill those still there after a moment, reap them."""
    processes = list((getattr(pool, "_processes", None) or {}).values())  # before shutdown forgets them
    manager = getattr(pool, "_executor_manager_thread", None)  # so does it this thread
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        if process.is_alive():
            process.terminate()
    deadline = time.monotonic() + STOP_SECONDS
    for process in processes:
        process.join(timeout=max(0.0, deadline - time.monotonic()))
        if process.is_alive():  # deep in a library call that does not return to Python soon
            process.kill()
            process.join(timeout=10)
    pool.shutdown(wait=True)
    if manager is not None:  # ended, its wakeup pipe closed: else the interpreter's exit may write to that pipe
        manager.join(timeout=10)  # as the thread closes it, "Bad file descriptor" (CPython gh-109370, 3.11)
