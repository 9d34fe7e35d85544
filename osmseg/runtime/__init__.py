"""How osmseg's long work runs, apart from what it computes: the run plumbing of the core.

:mod:`~osmseg.runtime.processes` (the fork server, worker processes, signals turned into
exceptions and deferred around the steps they must not cut), :mod:`~osmseg.runtime.folderlock`
(one command owns an output folder at a time), :mod:`~osmseg.runtime.shard` (``K/N``: one
process's share of an array job) and :mod:`~osmseg.runtime.progress` (the callbacks through
which long functions report progress; only the command line draws it).

Imports: the standard library, third-party packages and :mod:`osmseg.errors` (no other osmseg module).
"""
