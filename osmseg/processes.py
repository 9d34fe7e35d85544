"""The processes a build may use: the cores it is given, and the fork server its workers come from.

Kept free of everything but the standard library, so that the command line can start the fork
server before it imports the builder (:mod:`osmseg.cli.launch`): the server then imports
osmseg (about 0.7 s) while the command does the same, instead of after it, and the workers of
``osmseg build`` start that much sooner. :mod:`osmseg.workers` makes its pools from
:func:`worker_context`, the same server.

Why a fork server (``spawn`` where the platform has none): a plain ``fork`` of a process that
has already read a PBF would inherit libosmium's thread pool without its threads, and hang. The
server imports :data:`PRELOAD` once; each worker is then forked from it in milliseconds.
Imports: the standard library only.
"""

from __future__ import annotations

import math
import multiprocessing
import multiprocessing.context
import multiprocessing.forkserver
import multiprocessing.resource_tracker
import os
import signal
from pathlib import Path

__all__ = ["PRELOAD", "available_cores", "start_fork_server", "worker_context"]

#: Modules the fork server imports once, so that each worker starts without importing them.
PRELOAD = ["osmseg.slots"]


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
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        multiprocessing.forkserver.ensure_running()
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    return True
