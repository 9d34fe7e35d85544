"""Errors raised by osmseg.

As in rasterio, there is one root, :class:`OsmsegError`, and each subclass also
inherits the builtin exception it resembles, so callers may catch either.  Every
message is one line that says what to change.  The CLI turns these into a one-line
message on stderr and exit status 1 (2 for usage errors). The packages above the core
subclass :class:`OsmsegError` for their own errors (``training.errors.CheckpointError``).
"""

from __future__ import annotations


def first_line(exc: BaseException, limit: int = 300) -> str:
    """The first line of an exception's message (its type name if it has none), at most ``limit``
    characters: how a library's long or multi-line error goes into one of ours.

    >>> first_line(ValueError("bad value\\nmore detail")), first_line(KeyError())
    ('bad value', 'KeyError')
    """
    text = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    return text if len(text) <= limit else text[: limit - 1] + "…"


class OsmsegError(Exception):
    """Root of all osmseg errors."""


class ConfigError(OsmsegError, ValueError):
    """A setting, option or data-manifest entry is invalid."""


class UnknownPlaceError(ConfigError, KeyError):
    """A city/area name that is not among the presets."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class ClassTableError(ConfigError):
    """A class table (data_manifests/classes*.toml) is malformed."""


class ClassTablesDiffer(ConfigError):
    """Labels of one class table and a model (or masks) of another that cannot be compared: the
    ids of one read as the other's would count one class's pixels as another's (exit 2)."""


class NetworkError(OsmsegError, IOError):
    """A remote service could not be reached or kept failing after retries."""


class HTTPStatusError(NetworkError):
    """A remote service answered with an HTTP error status."""

    def __init__(self, message: str, status: int | None = None) -> None:
        super().__init__(message)
        self.status = status

    def __reduce__(self) -> tuple[type, tuple[str, int | None]]:
        # raised in a build's worker process and re-raised in the build's own: keep the status
        return type(self), (str(self.args[0]) if self.args else "", self.status)


class RetriesExhausted(NetworkError):
    """A service kept failing in a way that may heal (429/5xx, timeouts, dropped connections,
    answers with an unusable body) through all retries. The builder fails only that sample's
    attempt with this message and goes on; the same command later retries it."""


class ServiceUnavailable(HTTPStatusError, RetriesExhausted):
    """A service kept answering 429/500/502/503/504 through all retries."""


class CorruptResponse(OsmsegError, ValueError):
    """An answer's body is not usable (a broken image, malformed OSM XML): raised by the check a
    caller gives :meth:`osmseg.net.http.HttpClient.fetch`, which retries like a 5xx."""


class AuthError(HTTPStatusError):
    """A key or token was refused (HTTP 401/403 or a provider's own refusal)."""


class OfflineCacheMiss(NetworkError):
    """``--offline`` was given and the request is not in the cache."""


class CacheError(OsmsegError, IOError):
    """The on-disk HTTP cache cannot be read or written (a full disk, a read-only folder)."""


class ImageryError(OsmsegError, IOError):
    """Imagery could not be read, decoded or reprojected."""


class UnusableImagery(ConfigError, ImageryError):
    """An imagery file named by an option cannot serve (no CRS, 16-bit, not a raster): a usage
    error (exit 2) that is also an :class:`ImageryError` for callers that catch those."""


class OSMDataError(OsmsegError, ValueError):
    """OpenStreetMap data is malformed or could not be read."""


class OSMLimitError(OSMDataError):
    """A service refused a box as too large (area or node limit): split it."""


class DatasetError(OsmsegError, IOError):
    """An output or input dataset folder is inconsistent."""


class DatasetBusy(OsmsegError):
    """A dataset folder that a build holds now (its files are still being written). Not a
    :class:`DatasetError`: readers that fall back on a dataset they cannot use must not fall back
    on one that is only busy, but say so."""
