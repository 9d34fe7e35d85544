"""A scriptable HTTP server on 127.0.0.1 for network fault tests.

The ``http_server`` fixture starts a :class:`ScriptedServer` on a free port and stops it at
teardown.  Each path gets a script: a queue of :class:`Reply` objects served in order, the last
one repeating, or a function that builds a reply from the request.  Every request is recorded
(:class:`Seen`), and the server tracks the most requests it ever had in flight at once.

Use it from a test module (``tests/`` is on ``sys.path`` under pytest's default import mode;
the fixture is available once ``tests/conftest.py`` has ``pytest_plugins = ["servers"]``)::

    from servers import Reply

    def test_retry(http_server):
        http_server.script("/t/1/2/3.png",
                           Reply(503, headers={"Retry-After": "1"}),
                           Reply(200, b"\\x89PNG...", {"Content-Type": "image/png"}))
        url = http_server.url("/t/1/2/3.png")
        ...  # call code under test with url
        assert http_server.count("/t/1/2/3.png") == 2

What a :class:`Reply` can do:

* ``status``, ``body`` (bytes or str), ``headers`` (``Content-Length`` is set for you);
* ``delay``: seconds to wait before answering (client read timeouts);
* ``truncate``: send only that many body bytes while announcing the full length, then close
  the connection (a body cut short in transit);
* for a reply that depends on the request (say the ``bbox`` of an OSM API call), use
  ``http_server.route(path, fn)`` with ``fn(seen: Seen) -> Reply``.

A script key is a path (``/api/0.6/map``) or a path with its exact query
(``/api/0.6/map?bbox=1,2,3,4``); the exact form wins.  Unscripted paths answer 404.

Bounds: delays are capped at :data:`MAX_DELAY` and cut short when the server stops; handler
threads are daemons; ``close()`` stops the accept loop and closes the socket.  A route
handler that raises is answered with 500 and recorded in ``handler_errors``; the fixture then
fails the test at teardown.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any
from urllib.parse import urlsplit

import pytest

#: Longest delay a reply may ask for, in seconds (keeps a broken test from hanging).
MAX_DELAY = 30.0


@dataclass(frozen=True)
class Reply:
    """One scripted answer.

    Attributes:
        status: HTTP status code.
        body: response body (str is UTF-8 encoded).
        headers: extra response headers (``Content-Length`` is added unless given).
        delay: seconds to wait before sending anything.
        truncate: if set, send only this many body bytes (with the full Content-Length),
            then close the connection.
    """

    status: int = 200
    body: bytes | str = b""
    headers: Mapping[str, str] = field(default_factory=dict)
    delay: float = 0.0
    truncate: int | None = None

    @property
    def data(self) -> bytes:
        """The body as bytes."""
        return self.body.encode() if isinstance(self.body, str) else self.body


@dataclass(frozen=True)
class Seen:
    """One request the server received.

    Attributes:
        method: ``GET``, ``POST``, ...
        path: the path without the query.
        query: the raw query string ("" when none).
        headers: request headers (last value wins for repeated names).
        body: request body bytes.
        arrived: ``time.monotonic()`` when the request line and headers had been read.
    """

    method: str
    path: str
    query: str
    headers: dict[str, str]
    body: bytes
    arrived: float

    @property
    def target(self) -> str:
        """Path plus query, as sent."""
        return f"{self.path}?{self.query}" if self.query else self.path


Handler = Callable[[Seen], Reply]


class ScriptedServer:
    """A threaded HTTP/1.1 server on 127.0.0.1 that answers from per-path scripts."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._scripts: dict[str, deque[Reply] | Handler] = {}
        self._seen: list[Seen] = []
        self._in_flight = 0
        self._max_in_flight = 0
        self._stopping = threading.Event()
        #: exceptions raised by route handlers (answered with 500; the fixture fails on them)
        self.handler_errors: list[Exception] = []
        self._httpd = _Server(("127.0.0.1", 0), _RequestHandler)
        self._httpd.owner = self
        self.port: int = self._httpd.server_address[1]
        self._thread = threading.Thread(
            target=self._httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True
        )
        self._thread.start()

    # -- scripting ----------------------------------------------------------------------------

    def url(self, path: str = "/") -> str:
        """Absolute URL of ``path`` on this server."""
        return f"http://127.0.0.1:{self.port}{path}"

    def script(self, key: str, *replies: Reply) -> None:
        """Serve ``replies`` in order for ``key`` (path or path?query); the last one repeats."""
        if not replies:
            raise ValueError("script() needs at least one Reply")
        with self._lock:
            self._scripts[key] = deque(replies)

    def route(self, key: str, handler: Handler) -> None:
        """Answer ``key`` (path or path?query) with ``handler(seen)`` for every request."""
        with self._lock:
            self._scripts[key] = handler

    def reset(self) -> None:
        """Forget scripts, recorded requests and the in-flight maximum."""
        with self._lock:
            self._scripts.clear()
            self._seen.clear()
            self._max_in_flight = self._in_flight

    # -- inspection ---------------------------------------------------------------------------

    def requests(self, path: str | None = None) -> list[Seen]:
        """Requests received so far, optionally only those for ``path`` (query ignored)."""
        with self._lock:
            return [s for s in self._seen if path is None or s.path == path]

    def count(self, path: str | None = None) -> int:
        """How many requests were received (for ``path``, query ignored)."""
        return len(self.requests(path))

    @property
    def max_in_flight(self) -> int:
        """The most requests that were being handled at the same moment."""
        with self._lock:
            return self._max_in_flight

    # -- lifecycle ----------------------------------------------------------------------------

    def close(self) -> None:
        """Stop serving (interrupting delays) and release the port."""
        self._stopping.set()
        self._httpd.shutdown()
        self._httpd.server_close()
        self._thread.join(timeout=5)

    def __enter__(self) -> ScriptedServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- used by the request handler ----------------------------------------------------------

    def _begin(self, seen: Seen) -> Reply | Handler:
        """Record ``seen`` as in flight; the reply for it, or the route handler to call."""
        with self._lock:
            self._seen.append(seen)
            self._in_flight += 1
            self._max_in_flight = max(self._max_in_flight, self._in_flight)
            script = self._scripts.get(seen.target, self._scripts.get(seen.path))
            if script is None:
                return Reply(404, f"no script for {seen.path}\n")
            if isinstance(script, deque):
                return script.popleft() if len(script) > 1 else script[0]
            return script  # called outside the lock

    def _end(self) -> None:
        with self._lock:
            self._in_flight -= 1

    def _sleep(self, seconds: float) -> None:
        self._stopping.wait(min(max(seconds, 0.0), MAX_DELAY))


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    block_on_close = False
    owner: ScriptedServer

    def handle_error(self, request: Any, client_address: Any) -> None:
        """Clients hanging up (timeouts, truncation tests) are expected: stay quiet."""


class _RequestHandler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    server: _Server

    def log_message(self, format: str, *args: Any) -> None:
        """No access log on stderr."""

    def _handle(self) -> None:
        owner = self.server.owner
        parts = urlsplit(self.path)
        length = int(self.headers.get("Content-Length") or 0)
        body = self.rfile.read(length) if length else b""
        seen = Seen(
            method=self.command,
            path=parts.path,
            query=parts.query,
            headers={k: v for k, v in self.headers.items()},
            body=body,
            arrived=time.monotonic(),
        )
        scripted = owner._begin(seen)
        ended = False
        try:
            if isinstance(scripted, Reply):
                reply = scripted
            else:
                try:
                    reply = scripted(seen)
                except Exception as exc:
                    owner.handler_errors.append(exc)
                    reply = Reply(500, f"route handler failed: {exc!r}\n")
            owner._sleep(reply.delay)
            # out of flight before the reply leaves: a client that has read it may send its next
            # request before this thread runs again, and must not be counted twice
            owner._end()
            ended = True
            self._send(reply)
        finally:
            if not ended:
                owner._end()

    def _send(self, reply: Reply) -> None:
        data = reply.data
        self.send_response(reply.status)
        headers = dict(reply.headers)
        if not any(k.lower() == "content-length" for k in headers):
            headers["Content-Length"] = str(len(data))
        for name, value in headers.items():
            self.send_header(name, value)
        if reply.truncate is not None:
            self.send_header("Connection", "close")
            self.close_connection = True
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(data if reply.truncate is None else data[: reply.truncate])
        self.wfile.flush()

    do_GET = do_POST = do_PUT = do_DELETE = do_HEAD = _handle


@pytest.fixture
def http_server() -> Iterator[ScriptedServer]:
    """A running :class:`ScriptedServer`, stopped after the test."""
    server = ScriptedServer()
    try:
        yield server
    finally:
        server.close()
    assert not server.handler_errors, f"a route handler raised: {server.handler_errors[0]!r}"
