"""Record and replay a whole build's HTTP traffic as a vcrpy cassette.

``osmseg build --record CASSETTE`` wraps the build in ``cassette(path, "record")``;
``--replay CASSETTE`` (and the embedded demo, which replays a cassette shipped in the package)
wraps it in ``cassette(path, "replay")``, which never touches the network.

Choices, and why:

* Secret query parameters (:data:`osmseg.net.http.SECRET_PARAMS`), form fields and key headers
  are dropped from what is recorded, and ``Location`` headers are redacted, so a cassette never
  holds a key and can be committed.  Matching drops them from the live request too, so a
  cassette recorded with one key replays with another (or none).
* Requests match on method, scheme, host, path, query and body.  Not the port, so traffic
  recorded against a test server on a random port replays; the body, so two Overpass POSTs
  for different boxes are told apart.
* Transient answers (429/5xx) are not recorded: the retry that followed is, and replay then
  gives the good answer at once.  Repeated identical requests replay the same answer.
* Bodies are stored decoded (``decode_compressed_response``) so cassettes are readable.
* The cassette file is written atomically (temp file, then ``os.replace``).
* A request missing from the cassette is a one-line :class:`~osmseg.errors.OfflineCacheMiss`
  naming the redacted URL, not vcrpy's multi-paragraph message.

Using it:

* vcrpy patches connection classes while the cassette is active, and a connection opened
  before is not intercepted: create the :class:`~osmseg.net.http.HttpClient` inside the block.
* Record with the HTTP cache off (or empty): an answer served from the cache never reaches the
  network, so it would be missing from the cassette.
* Threads: for each real request vcrpy briefly puts the real connection classes back,
  process-wide, so a request another thread starts at that moment escapes the recording.
  While a cassette records, :func:`request_guard` therefore makes ``HttpClient`` send one
  request at a time (replay needs no guard: it never sends).  Record and replay from an
  8-thread pool are tested in tests/test_http.py.
"""

from __future__ import annotations

import os
import tempfile
import threading
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager, nullcontext
from pathlib import Path
from typing import Any, Literal

import vcr
from vcr.cassette import Cassette
from vcr.errors import CannotOverwriteExistingCassetteException
from vcr.persisters.filesystem import CassetteNotFoundError, FilesystemPersister
from vcr.serialize import deserialize, serialize

from osmseg.errors import ConfigError, OfflineCacheMiss
from osmseg.net.http import (
    RETRY_STATUSES,
    SECRET_HEADERS,
    SECRET_PARAMS,
    install_log_redaction,
    redact,
)

Mode = Literal["record", "replay"]

#: Request attributes that must agree for a recorded answer to be replayed.
MATCH_ON: tuple[str, ...] = ("method", "scheme", "host", "path", "query", "body")


# vcrpy's patching is process-wide, so the guard that goes with it is too.
_record_lock = threading.Lock()
_state_lock = threading.Lock()
_recording = 0  # cassettes recording right now


def request_guard() -> AbstractContextManager[object]:
    """What to hold around one real HTTP request: a process lock while recording, else nothing."""
    return _record_lock if _recording else nullcontext()


def _set_recording(delta: int) -> None:
    global _recording
    with _state_lock:
        _recording += delta


class AtomicPersister(FilesystemPersister):  # type: ignore[misc]  # untyped base
    """vcrpy's file persister, but UTF-8 always and a crash mid-save leaves the old file."""

    @classmethod
    def load_cassette(cls, cassette_path: Any, serializer: Any) -> Any:
        path = Path(cassette_path)
        data = path.read_text(encoding="utf-8") if path.is_file() else ""
        if not data.strip():
            raise CassetteNotFoundError()  # vcrpy then starts an empty cassette
        return deserialize(data, serializer)

    @staticmethod
    def save_cassette(cassette_path: Any, cassette_dict: dict[str, Any], serializer: Any) -> None:
        data = serialize(cassette_dict, serializer)
        path = Path(cassette_path)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                f.write(data)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise


def _keep_response(response: dict[str, Any]) -> dict[str, Any] | None:
    """Drop transient answers from recordings; redact keys in redirect targets."""
    if response["status"]["code"] in RETRY_STATUSES:
        return None
    headers = response.get("headers", {})
    for name in list(headers):
        if name.lower() == "location":
            headers[name] = [redact(value) for value in headers[name]]
    return response


def miss_error(exc: CannotOverwriteExistingCassetteException) -> OfflineCacheMiss:
    """The one-line osmseg error for a request that is not in a replay cassette."""
    request = exc.failed_request
    what = f"{request.method} {redact(request.uri)}" if request is not None else "a request"
    path = getattr(exc.cassette, "_path", "the cassette")
    return OfflineCacheMiss(
        f"{what} is not in the replay cassette {path}: record it with --record {path} "
        "(needs the network), or drop --replay"
    )


def _recorder(mode: Mode) -> vcr.VCR:
    recorder = vcr.VCR(
        record_mode="none" if mode == "replay" else "new_episodes",
        match_on=MATCH_ON,
        filter_query_parameters=SECRET_PARAMS,
        filter_post_data_parameters=SECRET_PARAMS,
        filter_headers=SECRET_HEADERS,
        before_record_response=_keep_response,
        decode_compressed_response=True,
    )
    recorder.register_persister(AtomicPersister)
    return recorder


@contextmanager
def cassette(path: Path, mode: Mode) -> Iterator[Cassette]:
    """Record all HTTP traffic into, or replay it from, the cassette at ``path``.

    ``record`` adds new requests to an existing cassette (and answers the ones it already
    holds from it), so an interrupted recording can be resumed.  ``replay`` never uses the
    network; a request that is not in the cassette raises ``OfflineCacheMiss``.

    Raises:
        ConfigError: ``mode`` is unknown, or ``replay`` and the file does not exist.
        OfflineCacheMiss: in replay, a request not in the cassette.
    """
    path = Path(path)
    if mode not in ("record", "replay"):
        raise ConfigError(f"cassette mode must be 'record' or 'replay', got {mode!r}")
    if mode == "replay" and not path.is_file():
        raise ConfigError(
            f"replay cassette {path} does not exist: record it first with --record {path}"
        )
    recorder = _recorder(mode)
    install_log_redaction()  # vcrpy's loggers exist now
    recording = 1 if mode == "record" else 0
    _set_recording(recording)
    try:
        with recorder.use_cassette(str(path), allow_playback_repeats=True) as active:
            yield active
    except CannotOverwriteExistingCassetteException as exc:
        raise miss_error(exc) from None
    finally:
        _set_recording(-recording)
