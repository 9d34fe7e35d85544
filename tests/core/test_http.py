"""HTTP client and record/replay tests against a scripted server on 127.0.0.1 (no internet).

Backoff is tiny here so the file runs in a few seconds; waits that a server asks for
(Retry-After) are checked from the server's request timestamps with tolerant bounds.
"""

from __future__ import annotations

import email.utils
import gzip
import itertools
import logging
import os
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
import yaml
from servers import Reply, ScriptedServer, Seen

from osmseg.errors import (
    AuthError,
    ConfigError,
    CorruptResponse,
    HTTPStatusError,
    NetworkError,
    OfflineCacheMiss,
    RetriesExhausted,
)
from osmseg.net.http import CACHE_FILE, DEFAULT_USER_AGENT, HttpClient, HttpConfig
from osmseg.redact import SECRET_HEADERS, redact

SECRET = "s3cr3t-K3Y-0123456789"
FAST = {"backoff": 0.01, "timeout": 5.0}
GZIP = {"Content-Encoding": "gzip", "Content-Type": "application/xml"}


@pytest.fixture
def http_server() -> Iterator[ScriptedServer]:
    """The scripted 127.0.0.1 server (same as servers.http_server, without plugin loading)."""
    with ScriptedServer() as server:
        yield server
    assert not server.handler_errors


def client(cache_dir: Path | None = None, **overrides: object) -> HttpClient:
    """A client with fast retries (overrides win)."""
    return HttpClient(HttpConfig(cache_dir=cache_dir, **{**FAST, **overrides}))  # type: ignore[arg-type]


def gaps(server: ScriptedServer, path: str) -> list[float]:
    """Seconds between consecutive requests for ``path``."""
    times = [seen.arrived for seen in server.requests(path)]
    return [b - a for a, b in itertools.pairwise(times)]


def one_line(exc: BaseException) -> str:
    text = str(exc)
    assert "\n" not in text and text
    return text


def files_bytes(folder: Path) -> bytes:
    """All bytes of all files under ``folder`` (cache db, journals, cassettes)."""
    return b"".join(p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file())


# -- redaction and configuration -----------------------------------------------------------------


def test_redact_removes_every_secret_parameter() -> None:
    url = (
        "https://h.example/x?key=A1&access_token=B2&subscription-key=C3&api_key=D4"
        "&token=E5&apikey=F6&zoom=3&monkey=7"
    )
    cleaned = redact(url)
    for value in ("A1", "B2", "C3", "D4", "E5", "F6"):
        assert value not in cleaned
    assert "zoom=3" in cleaned and "monkey=7" in cleaned
    assert redact("https://h.example/a/b.png") == "https://h.example/a/b.png"


@pytest.mark.parametrize(
    "bad", [{"timeout": 0}, {"retries": -1}, {"default_host_limit": 0}, {"host_limits": {"a": 0}}]
)
def test_bad_config_is_a_config_error(bad: dict[str, object]) -> None:
    with pytest.raises(ConfigError):
        HttpConfig(**bad)  # type: ignore[arg-type]


def test_malformed_url_is_a_config_error() -> None:
    with client() as http, pytest.raises(ConfigError) as err:
        http.get(f"not a url?key={SECRET}")
    assert SECRET not in one_line(err.value)


def test_identifying_user_agent(http_server: ScriptedServer) -> None:
    http_server.script("/ua", Reply(200, "ok"))
    with client() as http:
        http.get(http_server.url("/ua"))
    agent = http_server.requests("/ua")[0].headers["User-Agent"]
    assert agent == DEFAULT_USER_AGENT and agent.startswith("osmseg/")


# -- retries ------------------------------------------------------------------------------------


def test_429_retry_after_seconds_is_honoured(http_server: ScriptedServer) -> None:
    http_server.script("/rl", Reply(429, headers={"Retry-After": "1"}), Reply(200, "ok"))
    with client() as http:
        assert http.get(http_server.url("/rl")).content == b"ok"
    assert http_server.count("/rl") == 2
    assert gaps(http_server, "/rl")[0] >= 0.9  # waited as asked, not the 0.01 s backoff


def test_503_retry_after_http_date_is_honoured(http_server: ScriptedServer) -> None:
    when = email.utils.formatdate(time.time() + 2, usegmt=True)  # 1-2 s ahead (whole seconds)
    http_server.script("/d", Reply(503, headers={"Retry-After": when}), Reply(200, "ok"))
    with client() as http:
        assert http.get(http_server.url("/d")).content == b"ok"
    assert gaps(http_server, "/d")[0] >= 0.7


def test_retry_after_is_capped(http_server: ScriptedServer) -> None:
    http_server.script("/cap", Reply(429, headers={"Retry-After": "3600"}), Reply(200, "ok"))
    with client(max_retry_after=0.2) as http:
        assert http.get(http_server.url("/cap")).content == b"ok"
    assert 0.15 <= gaps(http_server, "/cap")[0] < 30


def test_500s_then_success(http_server: ScriptedServer) -> None:
    http_server.script("/f", Reply(500), Reply(502), Reply(504), Reply(200, "fine"))
    with client() as http:
        assert http.get(http_server.url("/f")).content == b"fine"
    assert http_server.count("/f") == 4


def test_permanent_500_gives_up_with_one_line(http_server: ScriptedServer) -> None:
    http_server.script("/down", Reply(500, "boom"))
    with client(retries=2) as http, pytest.raises(HTTPStatusError) as err:
        http.get(http_server.url("/down"), params={"key": SECRET})
    assert isinstance(err.value, NetworkError) and err.value.status == 500
    message = one_line(err.value)
    assert "/down?key=REDACTED" in message and "3 attempts" in message and SECRET not in message
    assert http_server.count("/down") == 3


def test_timeout_then_success(http_server: ScriptedServer) -> None:
    http_server.script("/slow", Reply(200, "late", delay=1.5), Reply(200, "ok"))
    with client(timeout=0.3) as http:
        assert http.get(http_server.url("/slow")).content == b"ok"
    assert http_server.count("/slow") == 2


def test_timeouts_exhausted_is_network_error(http_server: ScriptedServer) -> None:
    http_server.script("/never", Reply(200, "late", delay=1.5))
    with client(timeout=0.2, retries=1) as http, pytest.raises(NetworkError) as err:
        http.get(http_server.url("/never"))
    assert not isinstance(err.value, HTTPStatusError)
    assert "no data within 0.2 s" in one_line(err.value)


def test_truncated_body_then_success(http_server: ScriptedServer) -> None:
    body = bytes(range(256)) * 8
    http_server.script("/cut", Reply(200, body, truncate=100), Reply(200, body))
    with client() as http:
        assert http.get(http_server.url("/cut")).content == body
    assert http_server.count("/cut") == 2


def test_truncated_body_always_is_network_error(
    http_server: ScriptedServer, tmp_path: Path
) -> None:
    http_server.script("/cut", Reply(200, b"x" * 1000, truncate=10))
    with client(tmp_path, retries=2) as http, pytest.raises(NetworkError) as err:
        http.get(http_server.url("/cut"))
    assert "truncated" in one_line(err.value)
    assert http_server.count("/cut") == 3
    with client(tmp_path, offline=True) as http, pytest.raises(OfflineCacheMiss):
        http.get(http_server.url("/cut"))  # nothing half-written was cached


def test_404_is_not_retried(http_server: ScriptedServer) -> None:
    http_server.script("/missing", Reply(404, "nope"))
    with client() as http, pytest.raises(HTTPStatusError) as err:
        http.get(http_server.url("/missing"))
    assert err.value.status == 404 and not isinstance(err.value, AuthError)
    assert "HTTP 404" in one_line(err.value)
    assert http_server.count("/missing") == 1


@pytest.mark.parametrize("status", [401, 403])
def test_refused_key_is_auth_error(http_server: ScriptedServer, status: int) -> None:
    http_server.script("/auth", Reply(status))
    with client() as http, pytest.raises(AuthError) as err:
        http.get(http_server.url("/auth"), params={"key": SECRET})
    message = one_line(err.value)
    assert err.value.status == status and SECRET not in message and "key" in message
    assert http_server.count("/auth") == 1


def test_ok_statuses_are_returned_and_cached(http_server: ScriptedServer, tmp_path: Path) -> None:
    http_server.script("/notile", Reply(404, "no tile"))
    with client(tmp_path) as http:
        first = http.get(http_server.url("/notile"), ok_statuses={404})
        second = http.get(http_server.url("/notile"), ok_statuses={404})
    assert first.status_code == second.status_code == 404 and second.content == b"no tile"
    assert http_server.count("/notile") == 1
    with client(tmp_path, offline=True) as http:
        assert http.get(http_server.url("/notile"), ok_statuses={404}).status_code == 404


# -- cache and offline --------------------------------------------------------------------------


def test_cache_hit_does_not_reach_the_server(http_server: ScriptedServer, tmp_path: Path) -> None:
    http_server.script("/tile", Reply(200, b"\x89PNG tile"))
    url = http_server.url("/tile")
    with client(tmp_path) as http:
        assert http.get(url, params={"key": SECRET}).content == b"\x89PNG tile"
    with client(tmp_path) as http:  # a new process would see the same file
        again = http.get(url, params={"key": "another-key"})  # keys are not part of the cache key
    assert again.content == b"\x89PNG tile" and getattr(again, "from_cache", False)
    assert http_server.count("/tile") == 1
    assert (tmp_path / CACHE_FILE).is_file()


def test_errors_are_not_cached(http_server: ScriptedServer, tmp_path: Path) -> None:
    http_server.script("/e", Reply(404))
    with client(tmp_path) as http:
        for _ in range(2):
            with pytest.raises(HTTPStatusError):
                http.get(http_server.url("/e"))
    assert http_server.count("/e") == 2


def test_post_is_cached_by_body(http_server: ScriptedServer, tmp_path: Path) -> None:
    http_server.route("/interpreter", lambda seen: Reply(200, b"answer:" + seen.body))
    url = http_server.url("/interpreter")
    with client(tmp_path) as http:
        a = http.post(url, data={"data": "box A"}).content
        b = http.post(url, data={"data": "box B"}).content
        a_again = http.post(url, data={"data": "box A"})
    assert a != b and a_again.content == a and getattr(a_again, "from_cache", False)
    assert http_server.count("/interpreter") == 2


def test_offline_hit_and_miss(http_server: ScriptedServer, tmp_path: Path) -> None:
    http_server.script("/a", Reply(200, "cached bytes"))
    http_server.script("/b", Reply(200, "never fetched"))
    with client(tmp_path) as http:
        http.get(http_server.url("/a"))
    with client(tmp_path, offline=True) as http:
        assert http.get(http_server.url("/a")).content == b"cached bytes"
        with pytest.raises(OfflineCacheMiss) as err:
            http.get(http_server.url("/b"), params={"key": SECRET})
    message = one_line(err.value)
    assert "/b?key=REDACTED" in message and "--offline" in message and "online" in message
    assert SECRET not in message
    assert http_server.count("/a") == 1 and http_server.count("/b") == 0


def test_offline_without_cache_dir(http_server: ScriptedServer) -> None:
    with client(offline=True) as http, pytest.raises(OfflineCacheMiss):
        http.get(http_server.url("/x"))
    assert http_server.count() == 0


def test_key_never_in_cache_logs_or_errors(
    http_server: ScriptedServer, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.DEBUG)
    http_server.script("/meta", Reply(200, '{"resourceSets": []}'))
    http_server.script("/hop", Reply(302, headers={"Location": f"/meta?key={SECRET}"}))
    http_server.script("/flaky", Reply(503), Reply(200, "ok"))
    http_server.script("/denied", Reply(401))
    messages = []
    with client(tmp_path) as http:
        http.get(http_server.url("/meta"), params={"key": SECRET, "o": "json"})
        http.get(http_server.url("/hop"), params={"key": SECRET})  # redirect keeps the key
        http.get(http_server.url("/flaky"), params={"access_token": SECRET})
        http.post(http_server.url("/meta"), data={"key": SECRET, "q": "x"})
        http.get(http_server.url("/meta"), headers={"Authorization": f"Bearer {SECRET}"})
        with pytest.raises(AuthError) as err:
            http.get(http_server.url("/denied"), params={"subscription-key": SECRET})
        messages.append(str(err.value))
    assert any(SECRET in seen.target for seen in http_server.requests())  # it was sent...
    assert "REDACTED" in caplog.text and "/meta" in caplog.text
    assert SECRET not in caplog.text  # ...but never logged,
    assert SECRET.encode() not in files_bytes(tmp_path)  # never stored,
    assert all(SECRET not in m for m in messages)  # never shown.


def test_cache_survives_kill_9(http_server: ScriptedServer, tmp_path: Path) -> None:
    """A process killed while filling the cache leaves only whole, readable entries."""
    body = bytes(range(256)) * 64  # 16 KiB per entry
    http_server.route("/k", lambda seen: Reply(200, body + seen.query.encode()))
    script = (
        "import sys; from pathlib import Path; from osmseg.net.http import HttpClient, HttpConfig\n"
        "http = HttpClient(HttpConfig(cache_dir=Path(sys.argv[1])))\n"
        "for i in range(100000): http.get(sys.argv[2], params={'i': i})\n"
    )
    child = subprocess.Popen([sys.executable, "-c", script, str(tmp_path), http_server.url("/k")])
    try:
        deadline = time.monotonic() + 30
        while http_server.count("/k") < 20 and time.monotonic() < deadline and child.poll() is None:
            time.sleep(0.01)
    finally:
        os.kill(child.pid, signal.SIGKILL)
        child.wait(timeout=10)
    fetched = http_server.count("/k")
    assert fetched >= 20
    hits = 0
    with client(tmp_path, offline=True) as http:
        for i in range(fetched + 1):
            try:
                response = http.get(http_server.url("/k"), params={"i": i})
            except OfflineCacheMiss:
                continue
            assert response.content == body + f"i={i}".encode()
            hits += 1
    assert hits >= fetched - 2  # at most the entries in flight at the kill are missing


# -- concurrency --------------------------------------------------------------------------------


def test_per_host_limit_holds_under_a_thread_pool(http_server: ScriptedServer) -> None:
    http_server.script("/osm", Reply(200, "<osm/>", delay=0.1))
    with client(host_limits={"127.0.0.1": 2}) as http, ThreadPoolExecutor(8) as pool:
        bodies = list(pool.map(lambda i: http.get(http_server.url("/osm")).content, range(8)))
    assert bodies == [b"<osm/>"] * 8
    assert http_server.max_in_flight == 2


def test_default_host_limit_allows_more(http_server: ScriptedServer) -> None:
    """The counter can see more than two at once, so the test above can fail."""
    http_server.script("/osm", Reply(200, "<osm/>", delay=0.3))
    with client(host_limits={}, default_host_limit=8) as http, ThreadPoolExecutor(8) as pool:
        list(pool.map(lambda i: http.get(http_server.url("/osm")), range(8)))
    assert http_server.max_in_flight > 2


def test_cache_is_safe_under_threads(http_server: ScriptedServer, tmp_path: Path) -> None:
    http_server.route("/p", lambda seen: Reply(200, f"page {seen.query}"))
    url = http_server.url("/p")
    expected = [f"page n={i % 10}".encode() for i in range(200)]

    def fetch(i: int) -> bytes:
        return http.get(url, params={"n": i % 10}).content

    with client(tmp_path, default_host_limit=8) as http, ThreadPoolExecutor(8) as pool:
        assert list(pool.map(fetch, range(200))) == expected  # map re-raises thread errors
        fetched = http_server.count("/p")
        assert list(pool.map(fetch, range(200))) == expected
    assert http_server.count("/p") == fetched  # the second round came from the cache


def test_retry_after_pauses_the_whole_host(http_server: ScriptedServer) -> None:
    """While one request waits out a Retry-After, others to the same host wait too."""
    http_server.script("/first", Reply(429, headers={"Retry-After": "1"}), Reply(200, "ok"))
    http_server.script("/other", Reply(200, "ok"))
    with client() as http:
        worker = threading.Thread(target=http.get, args=(http_server.url("/first"),))
        worker.start()
        deadline = time.monotonic() + 5
        while http_server.count("/first") < 1 and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.3)  # the 429 has been answered and the pause set
        http.get(http_server.url("/other"))
        worker.join(timeout=10)
    first_429 = http_server.requests("/first")[0].arrived
    other: Seen = http_server.requests("/other")[0]
    assert other.arrived - first_429 >= 0.8


def test_an_answer_is_cached_only_once_it_has_passed_the_callers_check(tmp_path: Path) -> None:
    """Between the answer and its check, a kill must not leave an unchecked answer in the cache: the
    check runs while the cache (read by sqlite3 itself) holds nothing, and a refused answer is never
    written at all."""
    db = tmp_path / "cache" / CACHE_FILE

    def stored() -> int:
        with sqlite3.connect(db) as connection:
            return int(connection.execute("SELECT COUNT(*) FROM responses").fetchone()[0])

    during: list[int] = []

    def check(response: object) -> bytes:
        during.append(stored())
        content = response.content  # type: ignore[attr-defined]
        if content == b"bad":
            raise CorruptResponse("not a tile")
        return content

    with ScriptedServer() as server:
        server.script("/good.png", Reply(200, b"good"))
        server.script("/bad-then-good.png", Reply(200, b"bad"), Reply(200, b"good"))
        with client(tmp_path / "cache", backoff=0) as http:
            assert http.fetch(server.url("/good.png"), check)[1] == b"good"
            assert during == [0] and stored() == 1
            assert http.fetch(server.url("/bad-then-good.png"), check)[1] == b"good"
            assert during == [0, 1, 1] and stored() == 2


# -- record / replay ----------------------------------------------------------------------------


def test_record_then_replay_gives_identical_bytes(tmp_path: Path) -> None:
    tile = bytes(range(256)) * 4
    path = tmp_path / "build.yaml"
    with ScriptedServer() as server:
        server.script("/tiles/1/0/0.png", Reply(200, tile, {"Content-Type": "image/png"}))
        server.script("/meta", Reply(503), Reply(200, '{"ok": true}'))  # transient, then good
        server.script("/hop", Reply(302, headers={"Location": f"/tiles/1/0/0.png?key={SECRET}"}))
        server.script("/gz", Reply(200, gzip.compress(b"<osm>zipped</osm>"), GZIP))
        server.route("/interpreter", lambda seen: Reply(200, b"osm for " + seen.body))
        with client(cassette=path, cassette_mode="record") as http:
            recorded = [
                http.get(server.url("/tiles/1/0/0.png"), params={"key": SECRET}).content,
                http.get(server.url("/meta"), params={"access_token": SECRET}).content,
                http.get(server.url("/hop"), params={"key": SECRET}).content,
                http.get(server.url("/gz")).content,
                http.post(server.url("/interpreter"), data="box A").content,
                http.post(server.url("/interpreter"), data="box B").content,
            ]
        url = server.url  # the server is gone before replay
        # the redirect target was already recorded (keys do not count), so it was replayed
        assert server.count("/tiles/1/0/0.png") == 1 and SECRET in server.requests()[0].target
    text = path.read_bytes()
    assert SECRET.encode() not in text
    assert b"<osm>zipped</osm>" in text  # stored decoded, readable
    statuses = [i["response"]["status"]["code"] for i in yaml.safe_load(text)["interactions"]]
    assert 503 not in statuses and statuses.count(302) == 1  # transient answer not kept
    with client(cassette=path, cassette_mode="replay") as http:
        replayed = [
            http.get(url("/tiles/1/0/0.png"), params={"key": "another-key"}).content,
            http.get(url("/meta")).content,  # key dropped before matching
            http.get(url("/hop"), params={"key": "another-key"}).content,
            http.get(url("/gz")).content,
            http.post(url("/interpreter"), data="box A").content,
            http.post(url("/interpreter"), data="box B").content,
        ]
    assert replayed == recorded
    assert recorded[0] == recorded[2] == tile and recorded[3] == b"<osm>zipped</osm>"
    assert recorded[4] != recorded[5]


def test_replay_miss_is_one_line_offline_error(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    with ScriptedServer() as server:
        server.script("/a", Reply(200, "a"))
        with client(cassette=path, cassette_mode="record") as http:
            http.get(server.url("/a"))
        miss = server.url("/not-recorded")
    with client(cassette=path, cassette_mode="replay") as http, pytest.raises(OfflineCacheMiss) as err:
        http.get(miss, params={"key": SECRET})
    message = one_line(err.value)
    assert "/not-recorded?key=REDACTED" in message and str(path) in message
    assert SECRET not in message


@pytest.mark.parametrize("mode", ["live", "record"])
@pytest.mark.parametrize("location", ["http://[::1/t.png", "http://127.0.0.1:99999/t.png", "http://127.0.0.1:abc/t.png"])
def test_a_redirect_to_a_url_that_cannot_be_parsed_is_a_failure_of_that_request(
        tmp_path: Path, location: str, mode: str) -> None:
    """requests raises a bare ValueError (or InvalidURL) for such a Location: one RetriesExhausted
    naming the URL asked, never a traceback, with or without --record."""
    cassette = {"cassette": tmp_path / "c.yaml", "cassette_mode": "record"} if mode == "record" else {}
    with ScriptedServer() as server:
        server.script("/t.png", Reply(302, headers={"Location": location}))
        with client(backoff=0, retries=1, **cassette) as http, pytest.raises(RetriesExhausted) as err:
            http.get(server.url("/t.png"))
    assert "redirected to an unusable URL" in one_line(err.value) and "/t.png" in one_line(err.value)


def test_a_redirect_to_a_host_that_cannot_be_reached_names_that_host_and_fails_only_the_request() -> None:
    """The host asked first answered (with the redirect): not 'no connection to' it, which would stop
    a whole build as if the network were down."""
    with ScriptedServer() as server:
        server.script("/t.png", Reply(302, headers={"Location": "http://localhost:1/t.png"}))
        with client(backoff=0, retries=1) as http, pytest.raises(RetriesExhausted) as err:
            http.get(server.url("/t.png"))
    message = one_line(err.value)
    assert "redirected to localhost: connection failed" in message and "no connection to" not in message, message


def test_record_follows_a_redirect_to_the_same_path_on_another_port(tmp_path: Path) -> None:
    """Recordings match without the port (a cassette replays against another test server); a
    recording must still not answer a redirect's target with the redirect itself, forever."""
    path = tmp_path / "moved.yaml"
    with ScriptedServer() as old, ScriptedServer() as new:
        old.script("/tiles/1/0/0.png", Reply(301, headers={"Location": new.url("/tiles/1/0/0.png")}))
        new.script("/tiles/1/0/0.png", Reply(200, b"the tile", {"Content-Type": "image/png"}))
        with client(cassette=path, cassette_mode="record") as http:
            assert http.get(old.url("/tiles/1/0/0.png")).content == b"the tile"
        assert (old.count("/tiles/1/0/0.png"), new.count("/tiles/1/0/0.png")) == (1, 1)
        recorded_url = old.url("/tiles/1/0/0.png")
    with client(cassette=path, cassette_mode="replay") as http:  # both servers are gone
        assert http.get(recorded_url).content == b"the tile"


def test_replay_of_missing_cassette_is_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as err:
        client(cassette=tmp_path / "nope.yaml", cassette_mode="replay")
    assert "--record" in one_line(err.value)


def test_record_and_replay_from_a_thread_pool(tmp_path: Path) -> None:
    """No request escapes a recording made from threads, and the replay is complete."""
    path = tmp_path / "threads.yaml"
    with ScriptedServer() as server:
        server.route("/t", lambda seen: Reply(200, f"tile {seen.query[:3]}" * 50, delay=0.01))
        url = server.url("/t")

        def fetch(i: int) -> bytes:
            return http.get(url, params={"i": i % 10, "key": SECRET}).content

        with (
            client(default_host_limit=8, cassette=path, cassette_mode="record") as http,
            ThreadPoolExecutor(8) as pool,
        ):
            recorded = list(pool.map(fetch, range(40)))
        # every distinct URL recorded once (requests racing for the same URL may both go out)
        assert 10 <= server.count("/t") < 40
    assert len(yaml.safe_load(path.read_text())["interactions"]) == 10
    with (
        client(default_host_limit=8, cassette=path, cassette_mode="replay") as http,
        ThreadPoolExecutor(8) as pool,
    ):
        assert list(pool.map(fetch, range(40))) == recorded
    assert SECRET.encode() not in path.read_bytes()


def test_cassettes_are_vcrpy_cassettes_both_ways(tmp_path: Path) -> None:
    """What osmseg records, vcrpy replays; and a replayed answer can be cached and served offline."""
    path = tmp_path / "rec.yaml.gz"
    with ScriptedServer() as server:
        server.script("/a", Reply(200, b"alpha", {"Content-Type": "text/plain"}))
        with client(cassette=path, cassette_mode="record") as http:
            live = http.get(server.url("/a"), params={"key": SECRET}).content
        url = server.url("/a")
    assert gzip.decompress(path.read_bytes()).count(b"alpha") == 1
    plain = tmp_path / "rec.yaml"
    plain.write_bytes(gzip.decompress(path.read_bytes()))
    import requests
    import vcr

    with vcr.VCR(record_mode="none", match_on=("method", "host", "path")).use_cassette(str(plain)):
        assert requests.get(url).content == live
    # replay through the on-disk cache, then offline from the cache alone
    with client(tmp_path / "cache", cassette=path, cassette_mode="replay") as http:
        assert http.get(url).content == live
    with client(tmp_path / "cache", offline=True) as http:
        assert http.get(url).content == live


# -- answers whose body cannot be used ------------------------------------------------------------


def _ints(response: object) -> list[int]:
    """A tiny 'parser': the body must be comma-separated integers, else the answer is corrupt."""
    try:
        return [int(v) for v in response.content.decode().split(",")]  # type: ignore[attr-defined]
    except ValueError:
        raise CorruptResponse("not a list of integers") from None


def test_a_corrupt_200_is_fetched_again_and_never_cached(http_server: ScriptedServer, tmp_path: Path) -> None:
    http_server.script("/data", Reply(200, "1,2,<html>"), Reply(200, "1,2,3"))
    with client(tmp_path) as c:
        response, value = c.fetch(http_server.url("/data"), _ints)
        assert value == [1, 2, 3] and http_server.count("/data") == 2
    with client(tmp_path, offline=True) as c:  # what the cache holds is the good answer
        assert c.fetch(http_server.url("/data"), _ints)[1] == [1, 2, 3]


def test_a_body_that_stays_corrupt_ends_in_one_line_after_the_retries(http_server: ScriptedServer,
                                                                        tmp_path: Path) -> None:
    http_server.script("/data", Reply(200, "<html>oops</html>"))
    with client(tmp_path, retries=3) as c, pytest.raises(RetriesExhausted) as exc:
        c.fetch(http_server.url("/data"), _ints)
    assert http_server.count("/data") == 4
    assert "4 unusable answers in a row" in one_line(exc) and "not a list of integers" in str(exc.value)
    with client(tmp_path, offline=True) as c, pytest.raises(OfflineCacheMiss):
        c.fetch(http_server.url("/data"), _ints)  # nothing broken was kept


def test_an_answer_the_caller_refuses_for_good_is_not_retried_nor_cached(http_server: ScriptedServer,
                                                                         tmp_path: Path) -> None:
    http_server.script("/data", Reply(200, "1,2"))

    def refuse(response: object) -> None:
        raise ConfigError("the box is too large")

    with client(tmp_path) as c, pytest.raises(ConfigError):
        c.fetch(http_server.url("/data"), refuse)
    assert http_server.count("/data") == 1
    with client(tmp_path, offline=True) as c, pytest.raises(OfflineCacheMiss):
        c.get(http_server.url("/data"))


def test_offline_a_cached_answer_that_is_unusable_is_kept_and_said(http_server: ScriptedServer,
                                                                    tmp_path: Path) -> None:
    http_server.script("/data", Reply(200, "<html>cached by an old version</html>"))
    with client(tmp_path) as c:
        c.get(http_server.url("/data"))  # a plain GET caches whatever came
    with client(tmp_path, offline=True) as c, pytest.raises(RetriesExhausted) as exc:
        c.fetch(http_server.url("/data"), _ints)
    assert "cached answer is unusable" in one_line(exc) and "without --offline" in one_line(exc)
    with client(tmp_path, offline=True) as c:  # still there: offline, nothing is deleted
        assert c.get(http_server.url("/data")).status_code == 200


def test_a_host_that_cannot_be_reached_at_all_fails_at_once(tmp_path: Path,
                                                            caplog: pytest.LogCaptureFixture) -> None:
    """No network, a wrong host or port: two refused connections, not minutes of backoff."""
    import socket

    with socket.socket() as probe:  # a port nobody listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    caplog.set_level(logging.INFO, logger="osmseg.net")
    with client(tmp_path, retries=5, backoff=0.5) as c, pytest.raises(NetworkError) as exc:
        c.get(f"http://127.0.0.1:{port}/t/1/2/3.png")
    retries = [r.getMessage() for r in caplog.records if "retry" in r.getMessage()]
    assert len(retries) == 1, retries  # one 0.5 s backoff, not 0.5 + 1 + 2 + 4 + 8
    assert not isinstance(exc.value, RetriesExhausted)  # the whole build stops: every sample would fail
    assert "no connection to 127.0.0.1" in one_line(exc) and "--offline" in one_line(exc)


def test_secret_headers_cover_requests_caches_own_list():
    """osmseg.redact keeps a copy of requests-cache's AUTH_HEADERS (importing requests-cache costs
    every start-up): a header requests-cache adds must be added there too."""
    from requests_cache.policy.settings import AUTH_HEADERS

    assert {h.lower() for h in AUTH_HEADERS} <= {h.lower() for h in SECRET_HEADERS}


def test_a_build_from_local_files_never_imports_the_http_cache_or_vcrpy():
    """The command line starts without requests-cache and vcrpy (half a second of every start-up
    and of every build worker's); they come with the first cached request or cassette."""
    code = ("import sys, osmseg.cli.main, osmseg.builder.slots, osmseg.builder.workers; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('requests_cache', 'vcr', 'aiohttp')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
