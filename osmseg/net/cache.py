"""The HTTP client's on-disk cache: requests-cache's SQLite backend, made safe to share and to fail.

Four things on top of requests-cache 1.x's ``SQLiteCache``:

* every database access behind one lock (its SQLite backend shares one connection between
  threads and serialises only writes);
* secrets removed from stored redirect history, which requests-cache keeps unredacted;
* errors reported: requests-cache rolls back a failed write (a full disk) and carries on, so a
  response is silently not cached and a later delete dies with ``UnboundLocalError``. Here a
  cache that cannot be read or written is one :class:`~osmseg.errors.CacheError` line that
  names the file and what to do;
* a ``verdicts`` table beside ``responses``: answers that say "nothing here" (a tile of one
  colour, an empty tile, a 404 for a tile), kept apart from imagery. The client never answers a
  request from it while it can ask the server (a verdict may be a passing fault: it is asked
  again by every later run), only under ``--offline``, so an offline rebuild sees what the build
  it repeats saw. Answers that passed as imagery go to ``responses``, and replace any verdict.

Imports: osmseg.errors and osmseg.redact only.
"""

from __future__ import annotations

import errno
import sqlite3
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import requests
from requests_cache.backends.sqlite import SQLiteCache, SQLiteDict
from requests_cache.cache_keys import redact_response
from requests_cache.models.response import CachedResponse

from osmseg.errors import CacheError, first_line
from osmseg.redact import redact


class _StrictSQLiteDict(SQLiteDict):
    """requests-cache's SQLite table, with write errors raised instead of swallowed.

    requests-cache 1.x rolls a failed write back and carries on as if it had worked: with the
    disk full, a response is silently not cached and a later delete dies with an
    ``UnboundLocalError``. Here the transaction is rolled back and the error raised, for
    :class:`LockedSQLiteCache` to turn into one line.
    """

    @contextmanager
    def _acquire_sqlite_lock(self) -> Iterator[None]:
        with self._lock:
            connection = self._connection
            if connection is None:  # requests-cache opens it before any write; never None here
                raise CacheError(f"{self.db_path}: the cache database is closed")
            connection.execute("BEGIN IMMEDIATE")  # waits up to busy_timeout for other writers
            self._active_transaction = True
            try:
                yield
                connection.commit()
            except BaseException:
                connection.rollback()
                raise
            finally:
                self._active_transaction = False


class LockedSQLiteCache(SQLiteCache):
    """requests-cache's SQLite backend with every database access behind one lock.

    It also redacts secrets from redirect history, which requests-cache stores unredacted, and
    reports a database it cannot read or write (a full disk) as one :class:`CacheError` line.
    """

    def __init__(self, db_path: Path, **kwargs: Any) -> None:
        try:
            super().__init__(db_path, **kwargs)
            self.verdicts = SQLiteDict(db_path, table_name="verdicts", lock=self.responses._lock,
                                       serializer=self.responses.serializer, **kwargs)
            for table in (self.responses, self.redirects, self.verdicts):
                table.__class__ = _StrictSQLiteDict  # same state, writes that report their errors
        except (sqlite3.Error, OSError) as exc:
            raise _cache_error(db_path, exc) from None
        self._db_lock = threading.RLock()
        self._path = Path(db_path)

    def get_response(self, key: str, default: Any = None) -> CachedResponse | None:
        with self._db_lock, self._reporting():
            return super().get_response(key, default)

    def delete(self, *keys: str, **kwargs: Any) -> None:
        with self._db_lock, self._reporting():
            super().delete(*keys, **kwargs)

    @contextmanager
    def _reporting(self) -> Iterator[None]:
        try:
            yield
        except (sqlite3.Error, OSError) as exc:
            raise _cache_error(self._path, exc) from None

    def save_response(
        self, response: requests.Response, cache_key: str | None = None, expires: Any = None
    ) -> None:
        ignored = self._settings.ignored_parameters
        cached = redact_response(CachedResponse.from_response(response, expires=expires), ignored)
        for hop in cached.history:
            redact_response(hop, ignored)
            if "Location" in hop.headers:
                hop.headers["Location"] = redact(hop.headers["Location"])
            hop._next = None  # the next request's URL: may hold a key, never needed again
        with self._db_lock, self._reporting():
            key = cache_key or self.create_key(response.request)
            self.responses[key] = cached
            for hop_response in response.history:
                self.redirects[self.create_key(hop_response.request)] = key
            _discard(self.verdicts, key)  # the server has imagery there after all

    def get_verdict(self, key: str) -> CachedResponse | None:
        """The "nothing here" answer kept for ``key`` (see the module doc), or None."""
        with self._db_lock, self._reporting():
            try:
                found = self.verdicts[key]
            except KeyError:
                return None
        return found if isinstance(found, CachedResponse) else None

    def save_verdict(self, response: requests.Response) -> str:
        """Keep ``response``, an answer that says "nothing here", in the verdicts table; its key."""
        ignored = self._settings.ignored_parameters
        cached = redact_response(CachedResponse.from_response(response), ignored)
        cached.history = []  # where it was redirected from is not part of the verdict
        with self._db_lock, self._reporting():
            key = self.create_key(response.request)
            self.verdicts[key] = cached
            return key

    def forget_verdict(self, key: str) -> None:
        """Drop the verdict kept for ``key`` (the server has answered otherwise since)."""
        with self._db_lock, self._reporting():
            _discard(self.verdicts, key)

    def close(self) -> None:
        with self._db_lock:
            self.verdicts.close()  # type: ignore[no-untyped-call]
            super().close()  # type: ignore[no-untyped-call]


def _discard(table: SQLiteDict, key: str) -> None:
    """Delete ``key`` from ``table`` when it is there."""
    try:
        table.__delitem__(key)  # type: ignore[no-untyped-call]
    except KeyError:
        pass


def _cache_error(path: Path | str, exc: BaseException) -> CacheError:
    """One line for a cache database that fails (``database or disk is full``, read-only, corrupt)."""
    reason = first_line(exc)
    full = "full" in reason.lower() or getattr(exc, "errno", None) == errno.ENOSPC
    advice = ("free disk space, or give --cache-dir on a disk with room" if full else
              "check the folder's permissions and free space, or give another --cache-dir")
    return CacheError(f"the HTTP cache {path} cannot be used ({reason}): {advice}, then run the same command again "
                      "(finished samples are kept)")


