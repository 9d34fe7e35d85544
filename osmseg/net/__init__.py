"""HTTP for every remote source: one client with retries, per-host limits, a disk cache and
recorded replays.

:class:`~osmseg.net.http.HttpClient` (retries with backoff and ``Retry-After``, throttling per
host, one-line errors) over :mod:`osmseg.net.cache` (a requests-cache SQLite cache that
survives several processes and a full disk) and :mod:`osmseg.net.cassette` (record and replay
HTTP in vcrpy's cassette format, secrets filtered out). Imports: osmseg core (errors, redact)
only; the OSM and imagery sources import this package, never the reverse.
"""
