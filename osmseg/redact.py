"""Keeping API keys out of logs, error messages, cassettes and the HTTP cache.

Keys travel in query parameters (:data:`SECRET_PARAMS`), in request headers
(:data:`SECRET_HEADERS`) or as ``user:password@`` in a URL.  :func:`redact` replaces their
values with ``REDACTED`` in any text; call it before a URL reaches a message, a log or a file.
:func:`command_line` quotes a command with its secrets removed (the manifest records it).
:func:`install_log_redaction` puts the same cleaning on the loggers of urllib3, requests,
requests-cache and vcrpy, which log URLs at debug level, so ``-v`` is safe.

The HTTP client (:mod:`osmseg.net.http`) and the cassette adapters (:mod:`osmseg.net.cassette`)
use these names to keep keys out of the cache and out of recorded fixtures.
"""

from __future__ import annotations

import logging
import re
import shlex
from collections.abc import Sequence

#: Query parameters that carry keys or tokens (Bing, Azure Maps, Mapbox, Esri, MapTiler,
#: Thunderforest, HERE, Jawg, OpenWeatherMap, MapTilesAPI, generic).  Redaction and cassettes
#: match them in any case; the HTTP cache (requests-cache) only as spelt here, hence both
#: ``apikey`` and ``apiKey``.
SECRET_PARAMS = (
    "key", "access_token", "subscription-key", "api_key", "apikey", "token",
    "apiKey", "access-token", "appid", "rapidapi-key",
)
#: Request headers that carry keys (never stored in the cache): requests-cache's own list
#: (``requests_cache.policy.settings.AUTH_HEADERS``, checked by the tests; not imported, as
#: importing requests-cache costs every command a fifth of a second) and Azure's.
SECRET_HEADERS: tuple[str, ...] = ("Authorization", "Proxy-Authorization", "X-API-Key", "X-Auth-Token",
                                   "X-API-Token", "X-Access-Token", "Ocp-Apim-Subscription-Key")

_SECRET_RE = re.compile(
    # the value ends at a URL delimiter, or before punctuation that ends a sentence ("...: HTTP 500")
    r"([?&;](?:" + "|".join(re.escape(p) for p in SECRET_PARAMS) + r")=)[^&#\s'\"<>()]*?(?=[:,;.]*(?:[&#\s'\"<>()]|$))",
    re.IGNORECASE,
)
_USERINFO_RE = re.compile(r"(://[^/@\s:]+):[^/@\s]+@")
# Third-party packages whose loggers may print request URLs.
_THIRD_PARTY_LOGGERS = ("urllib3", "requests", "requests_cache", "vcr")


def redact(url: str) -> str:
    """``url`` (or any text holding URLs) with key/token values replaced by ``REDACTED``.

    >>> redact("https://dev.virtualearth.net/REST/v1/Imagery/Metadata/Aerial?key=s3cr3t&o=json")
    'https://dev.virtualearth.net/REST/v1/Imagery/Metadata/Aerial?key=REDACTED&o=json'
    >>> redact("https://a.tiles.example/1/2/3.png?style=x&access_token=pk.abc")
    'https://a.tiles.example/1/2/3.png?style=x&access_token=REDACTED'
    >>> redact("https://user:hunter2@example.org/tiles?monkey=1")
    'https://user:REDACTED@example.org/tiles?monkey=1'
    """
    return _USERINFO_RE.sub(r"\1:REDACTED@", _SECRET_RE.sub(r"\1REDACTED", url))


class RedactingFilter(logging.Filter):
    """A logging filter that redacts secrets from a record's final message (never drops it)."""

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        cleaned = redact(message)
        if cleaned != message:
            record.msg, record.args = cleaned, ()
        return True


_REDACTING_FILTER = RedactingFilter()


def install_log_redaction(*own_loggers: str) -> None:
    """Attach :class:`RedactingFilter` to ``own_loggers`` and to third-party loggers that log URLs.

    Logger filters see only records logged on that very logger, so the filter goes on every
    already-created logger under urllib3, requests, requests-cache and vcrpy (they create
    their loggers at import).  Idempotent; :mod:`osmseg.net.http` calls it on import (with its
    own logger's name) and again from each ``HttpClient``.  This adds a filter only: handlers,
    levels and propagation are left to the application.
    """
    names = [*own_loggers] + [
        name
        for name in list(logging.root.manager.loggerDict)
        if name.split(".")[0] in _THIRD_PARTY_LOGGERS
    ]
    for name in names:
        named = logging.getLogger(name)
        if _REDACTING_FILTER not in named.filters:
            named.addFilter(_REDACTING_FILTER)


_SECRET_OPTION = re.compile(r"(?i)^--?[\w-]*(key|token|secret|password)[\w-]*$")


def command_line(argv: Sequence[str]) -> str:
    """The command that made the dataset, shell-quoted, with secrets removed.

    Values of options named like ``--*key*``/``--*token*``/``--*secret*``/``--*password*``
    become ``REDACTED``, and every other argument goes through :func:`osmseg.redact.redact`
    (secret URL parameters such as ``key=``/``access_token=``, passwords in URLs).

    >>> command_line(["osmseg", "build", "--bing-key", "abc", "--api-token=xyz", "--seed", "3"])
    'osmseg build --bing-key REDACTED --api-token=REDACTED --seed 3'
    >>> print(command_line(["osmseg", "build", "--imagery", "xyz:https://t.example/{z}/{x}/{y}?key=SECRET"]))
    osmseg build --imagery 'xyz:https://t.example/{z}/{x}/{y}?key=REDACTED'
    """
    out: list[str] = []
    hide_next = False
    for arg in argv:
        if hide_next:
            out.append("REDACTED")
            hide_next = False
            continue
        option, eq, _ = arg.partition("=")
        if _SECRET_OPTION.match(option):
            if eq:
                out.append(f"{option}=REDACTED")
            else:
                out.append(arg)
                hide_next = True
            continue
        out.append(redact(arg))
    return shlex.join(out)
