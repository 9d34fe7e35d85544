"""The training package's own errors; each is an :class:`osmseg.errors.OsmsegError`, so a
command reports it as one line and exit code 1, like the core's. Imports: osmseg.errors.
"""

from __future__ import annotations

from osmseg.errors import OsmsegError

__all__ = ["CheckpointError"]


class CheckpointError(OsmsegError, ValueError):
    """A checkpoint file is missing, corrupt, or not an osmseg checkpoint."""
