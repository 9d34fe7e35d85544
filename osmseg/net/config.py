"""How :class:`osmseg.net.http.HttpClient` talks to the network: :class:`HttpConfig` and its defaults.

Imports: osmseg (its version) and osmseg.errors only.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from osmseg import __version__
from osmseg.errors import ConfigError

__all__ = ["ABSENT_ASKS", "CACHE_FILE", "DEFAULT_HOST_LIMITS", "DEFAULT_USER_AGENT", "HttpConfig"]

#: Default per-host limits: the OSM API and Overpass ask clients for at most two slots.
DEFAULT_HOST_LIMITS: Mapping[str, int] = {"api.openstreetmap.org": 2, "overpass-api.de": 2}
#: Answers a "nothing here" verdict needs (:meth:`HttpClient.fetch`'s ``absent``): the first and two
#: more. A server that sends a blank tile for 5 % of requests by chance says it three times in a
#: row for 1 in 8,000 tiles; a provider with no imagery says it every time.
ABSENT_ASKS = 3
#: Name of the cache file inside ``HttpConfig.cache_dir``.
CACHE_FILE = "http.sqlite"
DEFAULT_USER_AGENT = f"osmseg/{__version__} (+https://github.com/osmseg/osmseg)"


@dataclass(frozen=True)
class HttpConfig:
    """How :class:`HttpClient` talks to the network.

    Attributes:
        cache_dir: folder of the on-disk cache (``http.sqlite`` inside); None = no cache.
        offline: answer only from the cache; a miss raises ``OfflineCacheMiss``.
        timeout: seconds allowed for connecting and, separately, between bytes read.
        retries: extra attempts after the first on 429/5xx/timeouts/truncated bodies.
        backoff: first wait between attempts in seconds; doubles each time.
        max_retry_after: cap in seconds for a server's ``Retry-After``.
        host_limits: concurrent requests allowed per host name.
        default_host_limit: concurrent requests for hosts not in ``host_limits``.
        user_agent: sent with every request (services ask clients to identify themselves).
        cassette: a vcrpy cassette file to replay every request from (no network), or to
            record every request into (``cassette_mode="record"``); see osmseg.net.cassette.
        cassette_mode: ``"replay"`` or ``"record"``.
        gate_dir: a folder shared by several processes (a build's workers): the per-host
            limits and ``Retry-After`` pauses then hold across all of them
            (:mod:`osmseg.net.gates`); None keeps them per client.
    """

    cache_dir: Path | None = None
    offline: bool = False
    timeout: float = 30.0
    retries: int = 5
    backoff: float = 0.5
    max_retry_after: float = 300.0
    host_limits: dict[str, int] = field(default_factory=lambda: dict(DEFAULT_HOST_LIMITS))
    default_host_limit: int = 6
    user_agent: str = DEFAULT_USER_AGENT
    cassette: Path | None = None
    cassette_mode: str = "replay"
    gate_dir: Path | None = None

    def __post_init__(self) -> None:
        if self.cassette_mode not in ("replay", "record"):
            raise ConfigError(f"cassette_mode must be 'replay' or 'record', got {self.cassette_mode!r}")
        if self.timeout <= 0:
            raise ConfigError(f"HTTP timeout must be > 0 seconds, got {self.timeout}")
        if self.retries < 0 or self.backoff < 0 or self.max_retry_after < 0:
            raise ConfigError("HTTP retries, backoff and max_retry_after must be >= 0")
        limits = [self.default_host_limit, *self.host_limits.values()]
        if min(limits) < 1:
            raise ConfigError(f"per-host HTTP limits must be >= 1, got {limits}")
