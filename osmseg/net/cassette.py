"""Record or replay a build's HTTP traffic as a vcrpy cassette, through a requests adapter.

``osmseg build --record FILE`` / ``--replay FILE`` and the embedded demo use this. The cassette
is vcrpy's YAML format (read and written with vcrpy's own serializer), so cassettes made here
replay under vcrpy and vice versa. Unlike vcrpy's ``use_cassette``, which patches connection
classes process-wide, this is a transport adapter mounted on the one
:class:`~osmseg.net.http.HttpClient` session:

* it is safe under the thread pools that fetch tiles (vcrpy briefly restores the real
  connection classes for the whole process while it builds one, so another thread's request
  can escape a vcrpy replay);
* the responses it returns are ordinary urllib3 responses, so the on-disk requests-cache
  works on top of it (vcrpy's stand-in responses cannot be cached).

Matching: method, scheme, host, path, query (order-free) and body, with secret parameters
removed on both sides, and the port where it can: a replay takes the answer recorded for the
same port, else the first recorded for any port — a cassette recorded with one key, or
against a test server, replays with another or none. A recording only ever answers from what it
recorded for the same port: a server that redirects to the same path on another port is then
asked there, instead of being answered its own redirect again and again. Recordings drop secret parameters and headers,
skip transient answers (429/5xx: the retry that followed is recorded), store bodies decoded,
and are written atomically when the client closes. A path ending in ``.gz`` is read and
written gzip-compressed (deterministically), which keeps an embedded cassette small.
"""

from __future__ import annotations

import gzip
import io
import threading
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal
from urllib.parse import parse_qsl, urlencode, urlsplit, urlunsplit

import requests
from requests.adapters import HTTPAdapter
from urllib3 import HTTPResponse
from urllib3._collections import HTTPHeaderDict

from osmseg.errors import ConfigError, OfflineCacheMiss
from osmseg.output.atomic import atomic_write_bytes
from osmseg.redact import SECRET_HEADERS, SECRET_PARAMS, redact

if TYPE_CHECKING:
    from vcr.request import Request as VcrRequest

#: Statuses worth retrying: rate limits and server-side trouble (the HTTP client retries them;
#: a recording keeps only the answer that finally came).
RETRY_STATUSES = frozenset({429, 500, 502, 503, 504})

Mode = Literal["record", "replay"]
_SECRETS = {p.lower() for p in SECRET_PARAMS}
_DROP_HEADERS = {h.lower() for h in SECRET_HEADERS} | {"content-encoding", "transfer-encoding"}


def _vcr_load(text: str) -> tuple[list[VcrRequest], list[dict[str, Any]]]:
    """vcrpy's parse of a cassette. vcrpy is imported when a cassette is used, not with this
    module: importing it patches in aiohttp and costs a third of a second of every start-up."""
    from vcr.serialize import deserialize
    from vcr.serializers import yamlserializer

    requests_, responses = deserialize(text, yamlserializer)
    return requests_, responses


def read_cassette_text(path: Path) -> str:
    """The YAML text of a cassette file (gunzipped when the name ends in ``.gz``)."""
    data = path.read_bytes()
    return (gzip.decompress(data) if path.suffix == ".gz" else data).decode("utf-8")


def write_cassette_text(path: Path, text: str) -> None:
    """Write cassette YAML atomically; gzip with a fixed timestamp when the name ends in ``.gz``."""
    data = text.encode("utf-8")
    atomic_write_bytes(path, gzip.compress(data, mtime=0) if path.suffix == ".gz" else data)


def clean_url(url: str) -> str:
    """``url`` without secret query parameters (what a cassette stores).

    >>> clean_url("https://t.example/a.png?key=S3CRET&g=1")
    'https://t.example/a.png?g=1'
    """
    parts = urlsplit(url)
    query = [(k, v) for k, v in parse_qsl(parts.query, keep_blank_values=True) if k.lower() not in _SECRETS]
    return urlunsplit((parts.scheme, parts.netloc, parts.path, urlencode(query), parts.fragment))


def clean_body(body: bytes | str | None) -> bytes:
    """A request body with secret form fields removed (bodies that are not forms unchanged)."""
    if body is None:
        return b""
    raw = body.encode() if isinstance(body, str) else bytes(body)
    try:
        fields = parse_qsl(raw.decode(), keep_blank_values=True, strict_parsing=True)
    except (UnicodeDecodeError, ValueError):
        return raw
    if not any(k.lower() in _SECRETS for k, _ in fields):
        return raw
    return urlencode([(k, v) for k, v in fields if k.lower() not in _SECRETS]).encode()


def request_body(request: requests.PreparedRequest) -> bytes | str | None:
    """The body of a prepared request: osmseg sends forms and none, never a stream or a file."""
    body = request.body
    if body is not None and not isinstance(body, (bytes, str)):
        raise TypeError(f"cannot record or replay a streamed request body ({type(body).__name__})")
    return body


def match_key(method: str, url: str, body: bytes | str | None,
              port: bool = False) -> tuple[str, str, str, str, tuple[tuple[str, str], ...], bytes, int | None]:
    """What must agree between a live request and a recorded one (the port only with ``port``).

    >>> match_key("GET", "https://h:8443/p?b=2&a=1&key=x", None)[:5]
    ('GET', 'https', 'h', '/p', (('a', '1'), ('b', '2')))
    >>> match_key("GET", "http://h:8001/p", None)[-1], match_key("GET", "http://h:8001/p", None, port=True)[-1]
    (None, 8001)
    """
    parts = urlsplit(url)
    query = tuple(sorted((k, v) for k, v in parse_qsl(parts.query, keep_blank_values=True) if k.lower() not in _SECRETS))
    try:
        number = (parts.port or {"http": 80, "https": 443}.get(parts.scheme)) if port else None
    except ValueError:  # a port that is not a number, or out of range (a server's broken redirect)
        raise requests.exceptions.InvalidURL(f"invalid port in {redact(url)}") from None
    return (method.upper(), parts.scheme, parts.hostname or "", parts.path, query, clean_body(body), number)


def recorded_response(adapter: HTTPAdapter, request: requests.PreparedRequest, recorded: dict[str, Any]) -> requests.Response:
    """A real requests/urllib3 response carrying a recorded answer (so requests-cache can store it)."""
    body = recorded["body"]["string"]
    body = body.encode() if isinstance(body, str) else (body or b"")
    headers = HTTPHeaderDict()
    for name, values in recorded.get("headers", {}).items():
        if name.lower() not in ("content-encoding", "transfer-encoding", "content-length"):
            for value in values:
                headers.add(name, value)
    headers["Content-Length"] = str(len(body))
    raw = HTTPResponse(
        body=io.BytesIO(body), headers=headers, status=int(recorded["status"]["code"]),
        reason=recorded["status"].get("message"), preload_content=False, decode_content=False,
        request_url=request.url, request_method=request.method,
    )
    return adapter.build_response(request, raw)


class ReplayAdapter(HTTPAdapter):
    """Answers every request from a cassette; never opens a connection."""

    def __init__(self, path: Path) -> None:
        super().__init__()
        self.path = Path(path)
        if not self.path.is_file():
            raise ConfigError(f"replay cassette {self.path} does not exist: record it first with --record {self.path}")
        try:
            loaded = _vcr_load(read_cassette_text(self.path))
        except Exception:  # vcrpy raises ValueError/yaml errors/KeyError on bad files
            raise ConfigError(f"--replay {self.path} is not a cassette (the file --record writes): record it again"
                              ) from None
        requests_, responses = loaded[0], loaded[1]
        #: how many times each recorded URL (secrets removed) was answered
        self.plays: Counter[str] = Counter()
        #: (answer, recorded URL) by the match key with the port, and without it
        self._answers: dict[tuple[Any, ...], tuple[dict[str, Any], str]] = {}
        for req, resp in zip(requests_, responses):
            for key in (match_key(req.method, req.uri, req.body, port=True), match_key(req.method, req.uri, req.body)):
                self._answers.setdefault(key, (resp, clean_url(req.uri)))

    def unplayed(self) -> list[str]:
        """Recorded URLs that no request has asked for yet (tests use it to check coverage)."""
        return sorted(url for url in {url for _, url in self._answers.values()} if not self.plays[url])

    def send(self, request: requests.PreparedRequest, **kwargs: Any) -> requests.Response:  # type: ignore[override]
        assert request.method is not None and request.url is not None
        body = request_body(request)
        found = (self._answers.get(match_key(request.method, request.url, body, port=True))
                 or self._answers.get(match_key(request.method, request.url, body)))
        if found is None:
            raise OfflineCacheMiss(
                f"{request.method} {redact(request.url)} is not in the replay cassette {self.path}: "
                f"record it with --record {self.path} (needs the network), or drop --replay"
            )
        recorded, url = found
        self.plays[url] += 1
        return recorded_response(self, request, recorded)


class RecordAdapter(HTTPAdapter):
    """Sends requests for real and keeps what came back; :meth:`save` writes the cassette.

    A request already recorded is answered from the recording (as vcrpy's ``new_episodes``
    mode does), and an existing cassette is extended, so an interrupted recording can be
    resumed without asking the network twice.
    """

    def __init__(self, path: Path, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.path = Path(path)
        self._lock = threading.Lock()
        self._requests: list[VcrRequest] = []
        self._responses: list[dict[str, Any]] = []
        self._seen: dict[tuple[Any, ...], dict[str, Any]] = {}
        if self.path.is_file() and self.path.stat().st_size:
            try:
                loaded = _vcr_load(read_cassette_text(self.path)) if read_cassette_text(self.path).strip() else ([], [])
            except Exception:  # as in ReplayAdapter: a file that is not a cassette
                raise ConfigError(f"--record {self.path} is a file that is not a cassette: give a new file name, or "
                                  "a cassette to extend") from None
            for req, resp in zip(loaded[0], loaded[1]):
                self._keep(req, resp)

    def _keep(self, req: VcrRequest, resp: dict[str, Any]) -> None:
        key = match_key(req.method, req.uri, req.body, port=True)
        with self._lock:
            if key not in self._seen:
                self._seen[key] = resp
                self._requests.append(req)
                self._responses.append(resp)

    def send(self, request: requests.PreparedRequest, **kwargs: Any) -> requests.Response:  # type: ignore[override]
        assert request.method is not None and request.url is not None
        with self._lock:
            known = self._seen.get(match_key(request.method, request.url, request_body(request), port=True))
        if known is not None:
            return recorded_response(self, request, known)
        response = super().send(request, **kwargs)
        body = response.content  # read it all: a truncated body raises here, and is retried
        if response.status_code not in RETRY_STATUSES:
            headers = {k: [v] for k, v in request.headers.items() if k.lower() not in _DROP_HEADERS}
            from vcr.request import Request as VcrRequest  # see _vcr_load

            req = VcrRequest(request.method, clean_url(request.url), clean_body(request_body(request)) or None, headers)
            resp_headers = {k: [redact(v) if k.lower() == "location" else v]
                            for k, v in response.headers.items() if k.lower() not in _DROP_HEADERS}
            resp_headers["Content-Length"] = [str(len(body))]
            self._keep(req, {
                "status": {"code": response.status_code, "message": response.reason},
                "headers": resp_headers,
                "body": {"string": body},
            })
        return response

    def save(self) -> None:
        """Write the cassette atomically (sorted by URL so recordings diff well)."""
        with self._lock:
            pairs = sorted(zip(self._requests, self._responses), key=lambda p: (p[0].uri, p[0].method))
        from vcr.serialize import serialize  # see _vcr_load
        from vcr.serializers import yamlserializer

        text = serialize({"requests": [p[0] for p in pairs], "responses": [p[1] for p in pairs]}, yamlserializer)
        write_cassette_text(self.path, text)
