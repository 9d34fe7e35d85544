"""The one HTTP client of osmseg: cache, retries, politeness and key hygiene in one place.

Every remote call (Bing, XYZ tiles, the OSM API, Overpass) goes through :class:`HttpClient`:

* **One session** with an identifying ``User-Agent`` and connect/read timeouts.
* **On-disk cache** (requests-cache, SQLite at ``cache_dir/http.sqlite``): each write is one
  SQLite transaction, so ``kill -9`` never leaves a half-written entry.  2xx answers are kept
  forever (tiles and a fixed OSM query are stable; delete the folder to refresh); server
  ``Cache-Control`` is ignored.  An answer is stored only once it has passed every check of
  its caller (:meth:`HttpClient.fetch`'s ``parse``: a tile decoded at the provider's tile
  size, OSM XML that parses): a wrong answer is never written, so no kill between the write
  and the check can leave it to be replayed forever.  A non-2xx answer is cached only if the caller listed it in
  ``ok_statuses``: the caller declared it valid (a tile server's 404 for "no tile here"), and
  an ``--offline`` rebuild must see the same answer.
* **"Nothing here" is a verdict, not an answer** (:meth:`HttpClient.fetch`'s ``absent``): a
  tile of one colour, an empty tile or a tile's 404 may be a passing fault (a loaded server's
  blank picture, a CDN edge out of sync) as well as the provider's "no imagery here". Such an
  answer is asked again, :data:`ABSENT_ASKS` answers in all, ``backoff`` apart, before the
  caller gets it; it is then kept apart from the cached answers (the cache's ``verdicts``
  table, :mod:`osmseg.net.cache`), replayed only ``--offline``, and asked again by every later
  run (within one client's life it is taken once), so a dataset never depends on one unlucky
  answer.
* **Retries** with exponential backoff on 429/500/502/503/504, connection errors, timeouts,
  truncated bodies and (:meth:`HttpClient.fetch`) 200 answers whose body the caller cannot
  use, honouring ``Retry-After`` (seconds or HTTP date) up to ``max_retry_after``;
  a ``Retry-After`` pauses the whole host.  Hand-written, not ``urllib3.util.Retry``: urllib3
  cannot see failures after it hands the response to requests (a body cut short, a read
  timeout mid-body), and it does not cap ``Retry-After``.
* **Per-host concurrency limits** (a bounded semaphore per host name): the OSM API gets at most
  two requests at a time however many threads call the client; with ``gate_dir``, however
  many processes (a build's workers) share that folder (:mod:`osmseg.net.gates`).
* **Offline**: answers from the cache only; a miss is :class:`~osmseg.errors.OfflineCacheMiss`.
* **Secrets** (:data:`osmseg.redact.SECRET_PARAMS`) never reach logs, error messages or
  the cache (its keys ignore them, stored URLs say ``REDACTED``).  Use
  :func:`osmseg.redact.redact` before printing any URL.  The loggers of urllib3,
  requests-cache and vcrpy get a redacting filter, so ``-v`` is safe.

Thread safety: share one client across a ``ThreadPoolExecutor``.  requests' connection pool is
thread-safe; requests-cache's SQLite backend shares one connection between threads and only
serialises writes, so every cache read and write here goes behind one lock (a read takes well
under a millisecond; network time is not serialised).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Collection, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar
from urllib.parse import urlsplit

import requests
from requests.adapters import HTTPAdapter

from osmseg.errors import (
    AuthError,
    ConfigError,
    CorruptResponse,
    HTTPStatusError,
    NetworkError,
    OfflineCacheMiss,
    OsmsegError,
    RetriesExhausted,
    first_line,
)
from osmseg.net.cassette import RETRY_STATUSES, RecordAdapter, ReplayAdapter
from osmseg.net.config import ABSENT_ASKS, CACHE_FILE, DEFAULT_HOST_LIMITS, DEFAULT_USER_AGENT, HttpConfig
from osmseg.net.failures import (
    BAD_URL_EXCEPTIONS,
    NO_CONNECTION,
    STOPPING,
    HostGate,
    describe_failure,
    given_up,
    retry_after,
    status_hint,
)
from osmseg.net.gates import SharedHostGate, shared_gates_supported
from osmseg.redact import SECRET_HEADERS, SECRET_PARAMS, install_log_redaction, redact

__all__ = ["ABSENT_ASKS", "CACHE_FILE", "DEFAULT_HOST_LIMITS", "DEFAULT_USER_AGENT", "HttpClient", "HttpConfig"]

logger = logging.getLogger(__name__)
T = TypeVar("T")

install_log_redaction(__name__)


class HttpClient:
    """GET/POST with cache, retries, per-host limits and offline mode; see the module doc.

    Use one client per build, as a context manager, shared by all threads::

        with HttpClient(HttpConfig(cache_dir=out / "cache")) as http:
            png = http.get(tile_url).content
    """

    def __init__(self, config: HttpConfig | None = None) -> None:
        self.config = config if config is not None else HttpConfig()
        install_log_redaction(__name__)
        self._made: requests.Session | None = None  # made at the first request (see _session)
        self._make_lock = threading.Lock()
        if self.config.cassette is not None:
            self._session  # noqa: B018  (a cassette that cannot be read is said now, before any work)
        self._gates: dict[str, HostGate | SharedHostGate] = {}
        self._gates_lock = threading.Lock()
        self._answered: set[str] = set()  # hosts that have answered (any HTTP status) in this client's life
        self._warned: set[str] = set()  # hosts whose retries were already said at WARNING
        # "nothing here" verdicts taken in this client's life (asked ABSENT_ASKS times once, not per sample)
        self._verdicts: dict[tuple[str, str, str], requests.Response] = {}

    # -- public API ---------------------------------------------------------------------------

    @property
    def cache_path(self) -> Path | None:
        """The SQLite cache file, or None when caching is off."""
        cache_dir = self.config.cache_dir
        return None if cache_dir is None else Path(cache_dir) / CACHE_FILE

    def get(
        self,
        url: str,
        *,
        params: Mapping[str, Any] | None = None,
        headers: Mapping[str, str] | None = None,
        ok_statuses: Collection[int] = (),
    ) -> requests.Response:
        """Fetch ``url``; a fully read response for 2xx and ``ok_statuses``, else an error.

        Raises:
            ServiceUnavailable: still 429/5xx after ``retries`` more attempts.
            RetriesExhausted: no answer (timeouts, dropped connections) after the retries.
            HTTPStatusError: another error status (``AuthError`` for 401/403).
            OfflineCacheMiss: offline and not cached.
            ConfigError: the URL is malformed.
        """
        response, _ = self._request("GET", url, params=params, headers=headers, ok_statuses=ok_statuses)
        return response

    def post(
        self,
        url: str,
        *,
        data: Mapping[str, Any] | str | bytes | None = None,
        headers: Mapping[str, str] | None = None,
        ok_statuses: Collection[int] = (),
    ) -> requests.Response:
        """POST ``data`` (a form dict or a raw body) to ``url``; same contract as :meth:`get`.

        POSTs are cached too, keyed by their body: an Overpass query for a box is as stable
        as a tile.
        """
        response, _ = self._request("POST", url, data=data, headers=headers, ok_statuses=ok_statuses)
        return response

    def fetch(
        self,
        url: str,
        parse: Callable[[requests.Response], T],
        *,
        method: str = "GET",
        params: Mapping[str, Any] | None = None,
        data: Mapping[str, Any] | str | bytes | None = None,
        headers: Mapping[str, str] | None = None,
        ok_statuses: Collection[int] = (),
        corrupt: tuple[type[Exception], ...] = (CorruptResponse,),
        absent: Callable[[T | None], bool] | None = None,
    ) -> tuple[requests.Response, T | None]:
        """Fetch ``url`` and ``parse`` its 2xx answer; an unusable body is fetched again.

        Real servers and proxies sometimes answer 200 with a broken body: a PNG cut short by a
        cache, an HTML error page instead of a tile, OSM XML that stops mid-element. When
        ``parse`` raises one of ``corrupt``, the answer is forgotten (never replayed from the
        cache) and the request is retried with the same backoff and bound as a 5xx; after the
        last retry :class:`~osmseg.errors.RetriesExhausted` says what was wrong. Returns the
        response and the parsed value (None for a non-2xx status listed in ``ok_statuses``).

        ``absent`` says of a parsed value (None for an ``ok_statuses`` answer) whether it means
        "nothing here": such an answer is a verdict, asked :data:`ABSENT_ASKS` times before it is
        returned, never stored with the answers, replayed only offline (see the module doc).
        """
        if absent is None:
            return self._request(method, url, params=params, data=data, headers=headers, ok_statuses=ok_statuses,
                                 parse=parse, corrupt=corrupt)
        return self._verdict(method, url, parse, absent, params=params, data=data, headers=headers,
                             ok_statuses=ok_statuses, corrupt=corrupt)

    def forget(self, response: requests.Response) -> None:
        """Drop ``response`` from the cache: a 200 the caller could not use must not be replayed.

        Malformed OSM XML, an HTML error page served as a tile, an Overpass time-out remark:
        all arrive as 200 and are cached like good answers; forgetting them makes the rerun
        (after the server is fixed) ask again instead of failing the same way.
        """
        key = getattr(response, "cache_key", None)
        cache = getattr(self._session, "cache", None)  # a CachedSession's
        if key and cache is not None:
            cache.delete(key)

    @contextmanager
    def usable(self, response: requests.Response) -> Iterator[None]:
        """Wrap the caller's check of ``response``: if the check raises, forget the answer."""
        try:
            yield
        except Exception:
            self.forget(response)
            raise

    @property
    def transport(self) -> HTTPAdapter:
        """The transport adapter every request goes through (a cassette adapter under --record/--replay)."""
        self._session  # noqa: B018  (made on first use)
        return self._adapter

    def close(self) -> None:
        """Close connections and the cache database; write the cassette when recording."""
        if self._made is None and self.config.cassette is None:
            return  # nothing was asked: nothing to close
        save = getattr(self.transport, "save", None)
        if save is not None:
            save()
        self._session.close()

    def __enter__(self) -> HttpClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- internals ----------------------------------------------------------------------------

    @property
    def _session(self) -> requests.Session:
        """The session, made (and the cache database opened) at first use: a build from local files
        never opens the cache, which several processes on a shared disk would otherwise all lock."""
        if self._made is None:
            with self._make_lock:
                if self._made is None:
                    self._made = self._make_session()
        return self._made

    def _make_session(self) -> requests.Session:
        cfg = self.config
        session: requests.Session
        if cfg.cache_dir is not None:
            # imported here: requests-cache (with vcrpy) is half a second of every command's and every
            # build worker's start-up, and a build from local files never needs it
            from requests_cache import NEVER_EXPIRE, CachedSession

            from osmseg.net.cache import LockedSQLiteCache

            Path(cfg.cache_dir).mkdir(parents=True, exist_ok=True)
            backend = LockedSQLiteCache(Path(cfg.cache_dir) / CACHE_FILE, busy_timeout=30_000)
            session = CachedSession(
                backend=backend,
                expire_after=NEVER_EXPIRE,
                cache_control=False,
                allowable_codes=tuple(range(200, 300)),
                allowable_methods=("GET", "POST"),
                ignored_parameters=(*SECRET_PARAMS, *SECRET_HEADERS),
                match_headers=False,
                only_if_cached=cfg.offline,
                read_only=True,  # answers are stored by _store, once they have passed the caller's checks
            )
        else:
            session = requests.Session()
        pool = max(10, cfg.default_host_limit, *cfg.host_limits.values())
        adapter: HTTPAdapter
        if cfg.cassette is not None:
            if cfg.cassette_mode == "replay":
                adapter = ReplayAdapter(cfg.cassette)
            else:
                adapter = RecordAdapter(cfg.cassette, pool_connections=pool, pool_maxsize=pool, max_retries=0)
        else:
            adapter = HTTPAdapter(pool_connections=pool, pool_maxsize=pool, max_retries=0)
        self._adapter = adapter
        session.mount("http://", adapter)
        session.mount("https://", adapter)
        session.headers["User-Agent"] = cfg.user_agent
        return session

    def _gate(self, host: str) -> HostGate | SharedHostGate:
        with self._gates_lock:
            gate = self._gates.get(host)
            if gate is None:
                limit = self.config.host_limits.get(host, self.config.default_host_limit)
                shared = self.config.gate_dir is not None and shared_gates_supported()
                gate = self._gates[host] = (SharedHostGate(Path(str(self.config.gate_dir)), host, limit) if shared
                                            else HostGate(limit))
            return gate

    def _request(
        self,
        method: str,
        url: str,
        *,
        params: Mapping[str, Any] | None = None,
        data: Mapping[str, Any] | str | bytes | None = None,
        headers: Mapping[str, str] | None = None,
        ok_statuses: Collection[int] = (),
        parse: Callable[[requests.Response], Any] | None = None,
        corrupt: tuple[type[Exception], ...] = (),
        keep: Callable[[Any], bool] | None = None,
    ) -> tuple[requests.Response, Any]:
        """Ask until answered (retries, backoff, pauses); store an answer that passed ``parse`` and,
        when given, ``keep`` (a verdict of "nothing here" is not stored: :meth:`_verdict`)."""
        cfg = self.config
        full_url = self._full_url(url, params)
        shown = redact(full_url)
        if cfg.offline and cfg.cache_dir is None:
            raise OfflineCacheMiss(
                f"{method} {shown}: --offline needs an HTTP cache folder and none was given: "
                "set the cache folder, or drop --offline"
            )
        host = urlsplit(full_url).hostname or ""
        gate = self._gate(host)
        attempts = cfg.retries + 1
        problem, last_status = "", None
        for attempt in range(attempts):
            gate.wait()
            if STOPPING.is_set():
                raise RetriesExhausted(f"{method} {shown}: stopped (the command is ending)")
            wait = min(cfg.backoff * 2**attempt, cfg.max_retry_after)
            outcome = self._send(method, full_url, shown, gate, data=data, headers=headers)
            if isinstance(outcome, str):
                problem, last_status = outcome, None
                if attempt >= 1 and host not in self._answered and outcome.startswith(NO_CONNECTION):
                    # a host that has never answered and cannot be reached twice: no network, a wrong
                    # host name or port. Say so now rather than after minutes of backoff per sample.
                    raise NetworkError(
                        f"{method} {shown}: no connection to {host} ({outcome}): check the network connection "
                        "and the URL, or build from the cache with --offline"
                    )
            elif self._accept(method, shown, outcome, ok_statuses):
                self._answered.add(host)
                if parse is None or not 200 <= outcome.status_code < 300:
                    if keep is None or keep(None):
                        self._store(outcome)
                    return outcome, None
                try:
                    parsed = parse(outcome)
                    if keep is None or keep(parsed):
                        self._store(outcome)  # only now: nothing unchecked is ever cached
                    return outcome, parsed
                except corrupt as exc:  # a 200 with a body nobody can use: like a 5xx, not the end
                    if cfg.offline:  # the cache is all there is: keep it, and say what to do
                        raise RetriesExhausted(f"{method} {shown}: the cached answer is unusable "
                                               f"({first_line(exc)}): run once without --offline to fetch "
                                               "it again") from None
                    self.forget(outcome)
                    problem, last_status = f"unusable answer: {first_line(exc)}", None
                except OsmsegError:  # the caller refuses the answer itself: never replay it from the cache
                    if not cfg.offline:
                        self.forget(outcome)
                    raise
                # anything else (a full disk while storing what was parsed) is not the answer's fault:
                # it propagates (and the answer, not yet checked to the end, is not cached)
            else:  # a status worth retrying
                self._answered.add(host)
                problem, last_status = f"HTTP {outcome.status_code}", outcome.status_code
                asked = retry_after(outcome)
                if asked is not None:
                    wait = min(asked, cfg.max_retry_after)
                    gate.pause(wait)
            if attempt + 1 < attempts:
                self._say_retry(method, shown, host, problem, attempt, wait)
                if STOPPING.wait(wait):  # the process is stopping: no more attempts
                    raise RetriesExhausted(f"{method} {shown}: stopped (the command is ending)")
        raise given_up(f"{method} {shown}", attempts, problem, last_status)

    def _verdict(
        self,
        method: str,
        url: str,
        parse: Callable[[requests.Response], T],
        absent: Callable[[T | None], bool],
        **request: Any,
    ) -> tuple[requests.Response, T | None]:
        """:meth:`fetch` of an answer that may be a verdict of "nothing here" (``absent``): asked
        until the server answers otherwise or :data:`ABSENT_ASKS` answers agree, then kept in the
        cache's verdicts table. Offline, the answers come from the cache, the verdict last."""
        def present(value: Any) -> bool:
            return not absent(value)

        if self.config.offline:
            try:
                return self._request(method, url, parse=parse, **request)
            except OfflineCacheMiss:
                kept = self._kept_verdict(method, url, request)
                if kept is None:
                    raise
                return kept, parse(kept) if 200 <= kept.status_code < 300 else None
        taken = (method, self._full_url(url, request.get("params")), repr(request.get("data")))
        if taken in self._verdicts:  # this client (this run, this process) has taken it already
            response = self._verdicts[taken]
            return response, parse(response) if 200 <= response.status_code < 300 else None
        asked, forgotten = 0, False
        while True:
            response, parsed = self._request(method, url, parse=parse, keep=present, **request)
            if present(parsed):  # stored by _request, in place of any verdict kept before
                return response, parsed
            if getattr(response, "from_cache", False) and not forgotten:  # kept as imagery by an older osmseg:
                self.forget(response)                                      # ask the server instead
                forgotten = True
                continue
            asked += 1
            if asked >= ABSENT_ASKS:
                break
            logger.debug("%s %s: nothing here (answer %d of %d); asking again", method, redact(response.url or url),
                         asked, ABSENT_ASKS)
            if STOPPING.wait(min(self.config.backoff * 2 ** (asked - 1), self.config.max_retry_after)):
                raise RetriesExhausted(f"{method} {redact(url)}: stopped (the command is ending)")
        cache = self._cache
        if cache is not None:
            cache.save_verdict(response)
        self._verdicts[taken] = response
        return response, parsed

    @property
    def _cache(self) -> Any:
        """The cache backend (:class:`osmseg.net.cache.LockedSQLiteCache`), or None without a cache."""
        return getattr(self._session, "cache", None)

    def _kept_verdict(self, method: str, url: str, request: Mapping[str, Any]) -> requests.Response | None:
        """The verdict the cache keeps for this request (offline), or None."""
        cache = self._cache
        if cache is None:
            return None
        prepared = self._session.prepare_request(requests.Request(
            method, self._full_url(url, request.get("params")), data=request.get("data"),
            headers=dict(request.get("headers") or {})))
        kept: requests.Response | None = cache.get_verdict(cache.create_key(prepared))
        return kept

    def _say_retry(self, method: str, shown: str, host: str, problem: str, attempt: int, wait: float) -> None:
        """Log a retry: the first of a host at WARNING (a user sees why a build slows down), the
        rest at INFO (-v): a flaky server must not flood a log."""
        first = host not in self._warned
        self._warned.add(host)
        logger.log(logging.WARNING if first else logging.INFO,
                   "%s %s: %s; retry %d/%d in %.1f s%s",
                   *(method, shown, problem, attempt + 1, self.config.retries, wait,
                     " (further retries of this host: -v)" if first else ""))

    def _send(
        self,
        method: str,
        url: str,
        shown: str,
        gate: HostGate | SharedHostGate,
        *,
        data: Mapping[str, Any] | str | bytes | None,
        headers: Mapping[str, str] | None,
    ) -> requests.Response | str:
        """One attempt: the response, or a phrase saying why it is worth another try."""
        timeout = self.config.timeout
        try:
            with gate.slots:
                gate.wait()  # a pause may have begun while this request waited for its slot
                return self._session.request(
                    method,
                    url,
                    data=data,
                    headers=dict(headers) if headers else None,
                    timeout=(timeout, timeout),
                )
        except requests.exceptions.RequestException as exc:
            if isinstance(exc, BAD_URL_EXCEPTIONS) and urlsplit(url).scheme.lower() not in ("http", "https"):
                raise ConfigError(f"{method} {shown}: not a valid http(s) URL") from None
            # everything else requests can raise (a redirect loop or a redirect to an unusable URL, a broken
            # header, a TLS failure as well as dropped connections) is this request's failure, never the
            # build's: another attempt, then RetriesExhausted for the caller (a build fails that sample's
            # attempt and goes on; a host that never answered stops the build at once, in _request)
            return self._redirected_from(url, getattr(exc, "request", None)) + describe_failure(exc, timeout)
        except ValueError as exc:
            if isinstance(exc, OsmsegError):
                raise
            # the URL asked was checked before it was sent (_full_url): requests' ValueError for a
            # Location it cannot even parse ("Invalid IPv6 URL", a port that is not a number)
            self._answered.add(urlsplit(url).hostname or "")
            return "redirected to an unusable URL"

    def _redirected_from(self, url: str, hop: Any) -> str:
        """When the request that failed was a redirect's (to another host), the host asked first
        did answer (with the redirect): it counts as answered, and the phrase names the other host."""
        hop_url = getattr(hop, "url", None)
        hop_host = urlsplit(hop_url).hostname if isinstance(hop_url, str) else None
        host = urlsplit(url).hostname or ""
        if not hop_host or hop_host == host:
            return ""
        self._answered.add(host)
        return f"redirected to {hop_host}: "

    def _accept(
        self, method: str, shown: str, response: requests.Response, ok_statuses: Collection[int]
    ) -> bool:
        """True to hand ``response`` to the caller, False to retry; raises for the rest."""
        from_cache = bool(getattr(response, "from_cache", False))
        # requests-cache answers an offline miss with a made-up "504 Not Cached" that has no
        # cache key; a real hit always has one.
        cache_key: object = getattr(response, "cache_key", None)
        if self.config.offline and not (from_cache and cache_key):
            raise OfflineCacheMiss(
                f"{method} {shown} is not in the HTTP cache ({self.cache_path}) and --offline "
                "was given: run once online to fill the cache, or drop --offline"
            )
        status = response.status_code
        logger.debug("%s %s -> %s%s", method, shown, status, " (cache)" if from_cache else "")
        if 200 <= status < 300:
            return True
        if status in ok_statuses:
            return True  # stored by the caller of _accept, as a 2xx is
        if status in (401, 403):
            raise AuthError(
                f"{method} {shown} was refused (HTTP {status}): {status_hint(status)}", status
            )
        if status not in RETRY_STATUSES:
            reason = f" {response.reason}" if response.reason else ""
            raise HTTPStatusError(
                f"{method} {shown} failed with HTTP {status}{reason}: {status_hint(status)}",
                status,
            )
        return False

    @staticmethod
    def _full_url(url: str, params: Mapping[str, Any] | None) -> str:
        """``url`` with ``params`` encoded in, as requests would send it."""
        prepared = requests.models.PreparedRequest()
        try:
            prepared.prepare_url(url, dict(params) if params else None)
        except BAD_URL_EXCEPTIONS:
            raise ConfigError(f"not a valid http(s) URL: {redact(url)}") from None
        return str(prepared.url)

    def _store(self, response: requests.Response) -> None:
        """Write an answer that passed its caller's checks to the cache (not one read from it)."""
        cache = getattr(self._session, "cache", None)  # a CachedSession's
        if cache is not None and not self.config.offline and not getattr(response, "from_cache", False):
            cache.save_response(response)
