"""How HTTP failures are told apart, waited for and described, for :class:`osmseg.net.http.HttpClient`.

Which exceptions are worth another attempt (:data:`RETRY_EXCEPTIONS`) and which say the URL
itself is wrong; how long a server asks us to wait (:func:`retry_after`, seconds or an HTTP
date); a short, secret-free phrase for a failure (:func:`describe_failure`) and what the user
can do about an HTTP status (:func:`status_hint`); the error of a request that retries did not
get answered (:func:`given_up`); and the per-host gate that limits
concurrency and holds every caller of a host during a ``Retry-After`` (:class:`HostGate`).
Imports: requests, urllib3 and osmseg.errors only.
"""

from __future__ import annotations

import re
import threading
import time

import requests
from urllib3.exceptions import InvalidHeader
from urllib3.util import Retry

from osmseg.errors import OsmsegError, RetriesExhausted, ServiceUnavailable

__all__ = ["BAD_URL_EXCEPTIONS", "NO_CONNECTION", "RETRY_EXCEPTIONS", "STOPPING", "HostGate", "describe_failure",
           "given_up", "retry_after", "status_hint", "stop_requests"]

#: Set once this process is stopping (Ctrl-C, SIGTERM): every wait between attempts and every
#: ``Retry-After`` pause ends at once, so threads fetching tiles do not keep a stopping command
#: alive for minutes (a pause may be 300 s).
STOPPING = threading.Event()


def stop_requests() -> None:
    """End every wait of this process's HTTP clients now, and let no request start again: for a
    process that is stopping (the build's unwinding of a Ctrl-C or SIGTERM)."""
    STOPPING.set()

# Exceptions worth another attempt.  SSL errors are ConnectionErrors too but do not heal.
RETRY_EXCEPTIONS = (
    requests.exceptions.ConnectionError,  # refused, reset, DNS, and truncated bodies
    requests.exceptions.Timeout,
    requests.exceptions.ChunkedEncodingError,
    requests.exceptions.ContentDecodingError,
)
#: how :func:`describe_failure` names failures to connect at all (as opposed to a broken answer)
NO_CONNECTION = ("connection failed", "no connection within")

BAD_URL_EXCEPTIONS = (
    requests.exceptions.MissingSchema,
    requests.exceptions.InvalidSchema,
    requests.exceptions.InvalidURL,
)


class HostGate:
    """Concurrency slots for one host plus a shared "not before" time set by Retry-After."""

    def __init__(self, limit: int) -> None:
        self.slots = threading.BoundedSemaphore(limit)
        self._lock = threading.Lock()
        self._not_before = 0.0

    def pause(self, seconds: float) -> None:
        """Ask every caller of this host to wait ``seconds`` from now before sending."""
        with self._lock:
            self._not_before = max(self._not_before, time.monotonic() + seconds)

    def wait(self) -> None:
        """Sleep until the host's pause (if any) is over (or the process is stopping)."""
        while not STOPPING.is_set():
            with self._lock:
                delay = self._not_before - time.monotonic()
            if delay <= 0:
                return
            STOPPING.wait(delay)


def retry_after(response: requests.Response) -> float | None:
    """Seconds the server asks us to wait (``Retry-After`` as seconds or HTTP date), if any."""
    value = response.headers.get("Retry-After")
    if not value:
        return None
    try:
        return max(0.0, float(Retry().parse_retry_after(value)))
    except InvalidHeader:
        return None


def describe_failure(exc: BaseException, timeout: float) -> str:
    """A short, secret-free phrase for a transport failure: any exception of requests that is not
    the caller's URL's own fault (a redirect loop, a redirect to an unusable URL, a broken header
    or TLS handshake as well as timeouts and dropped connections).

    >>> describe_failure(requests.exceptions.TooManyRedirects("Exceeded 30 redirects."), 30)
    'redirect loop (more than 30 redirects)'
    """
    if isinstance(exc, requests.exceptions.TooManyRedirects):
        return "redirect loop (more than 30 redirects)"
    if isinstance(exc, requests.exceptions.SSLError):
        return "connection failed (TLS/certificate check failed: check the host name and the system's CA certificates)"
    if isinstance(exc, BAD_URL_EXCEPTIONS):  # the URL asked was checked before it was sent: a redirect's
        return "redirected to an unusable URL"
    if isinstance(exc, requests.exceptions.InvalidHeader):
        return "malformed HTTP header in the answer"
    if not isinstance(exc, RETRY_EXCEPTIONS):
        return f"request failed ({type(exc).__name__})"
    if isinstance(exc, requests.exceptions.ConnectTimeout):
        return f"no connection within {timeout:g} s"
    if isinstance(exc, requests.exceptions.Timeout):
        return f"no data within {timeout:g} s"
    if isinstance(exc, requests.exceptions.ChunkedEncodingError):
        return "connection dropped mid-response (truncated body)"
    if isinstance(exc, requests.exceptions.ContentDecodingError):
        return "undecodable (corrupt compressed) body"
    text = str(exc)
    if "IncompleteRead" in text or "Connection broken" in text:
        return "connection dropped mid-response (truncated body)"
    if "RemoteDisconnected" in text or "Connection aborted" in text or "Connection reset" in text:
        return "connection dropped before the answer"  # the host was reached: not a connection failure
    match = re.search(r"\[Errno -?\d+\] ([^'\")\]]+)", text)
    return f"connection failed ({match.group(1).strip()})" if match else "connection failed"


HINTS = {
    401: "check the API key or token (its environment variable) and its permissions",
    404: "check the URL or tile template",
    429: "the service keeps rate-limiting: wait, then run the same command again",
    500: "the service keeps failing: run the same command again later",
}


def status_hint(status: int) -> str:
    """What the user can do about an HTTP error status."""
    key = 401 if status == 403 else min(status, 500)
    return HINTS.get(key, "check the request (URL, parameters, key)")


def given_up(request: str, attempts: int, problem: str, last_status: int | None) -> OsmsegError:
    """The error of a ``request`` (method and shown URL) that ``attempts`` attempts did not get answered:
    the last HTTP status that was worth retrying, unusable answers, or the last connection problem."""
    if last_status is not None:
        return ServiceUnavailable(
            f"{request} failed with HTTP {last_status} after {attempts} attempts: {status_hint(last_status)}",
            last_status,
        )
    if problem.startswith("unusable answer"):
        return RetriesExhausted(f"{request}: {attempts} unusable answers in a row, the last: {problem[17:]}")
    return RetriesExhausted(
        f"{request} failed after {attempts} attempts ({problem}): check the network "
        "connection, or run the same command again later (finished work is kept)"
    )
