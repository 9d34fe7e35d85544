"""``osmseg build`` through the real CLI against a misbehaving server on 127.0.0.1.

A :class:`~servers.ScriptedServer` plays two services at once:

* the OSM API 0.6 ``map`` call (``--osm api:http://127.0.0.1:PORT/api/0.6``): every box is
  answered with the whole of ``tests/data/tinycity/tinycity.osm`` (the builder clips to the
  box itself); ``relation/ID/full`` is unscripted and answers 404, which the API source
  treats as "relation gone";
* an XYZ tile server (``--imagery xyz:http://127.0.0.1:PORT/tiles/{z}/{x}/{y}.png?key=...``):
  a 7x7 block of z18 tiles painted by :func:`osmseg.demo.render.render_aerial` from
  tinycity's own labels, so every sample passes the label and contrast filters.

:class:`Services` injects faults per path (429 + Retry-After, 5xx, bodies cut short, 404
"no tile", malformed XML, an HTML page instead of a tile) and the tests check what a user
would: the build either finishes with output byte-identical to a build that saw no fault,
or stops with one ``Error:`` line, keeps what it finished, and the same command finishes it.

The server's clock is pinned (:data:`SERVER_DATE`): the OSM API source records the HTTP
``Date`` of its answer as the data's timestamp, and two builds made seconds apart must
still be comparable byte for byte.

Nothing here is generated ahead of time: the tiles are rendered once per module (~2 s).
"""

from __future__ import annotations

import io
import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
import zlib
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, NamedTuple
from xml.etree import ElementTree

import mercantile
import numpy as np
import pytest
import rasterio
import servers
from click.testing import CliRunner, Result
from conftest import TEST_DATA
from PIL import Image
from servers import Reply, ScriptedServer, Seen

from osmseg.classes import load_class_table
from osmseg.cli.main import cli
from osmseg.demo.render import render_aerial
from osmseg.grid import TILE_SIZE, sample_grid
from osmseg.osm.features import read_features
from osmseg.rasterize import rasterize

TINYCITY = TEST_DATA / "tinycity" / "tinycity.osm"
LON, LAT, ZOOM = 24.94, 60.17, 18
#: tiles served around tinycity's centre tile: every centre within --radius-km 0.08 of it lies
#: in that tile or a neighbour, so every 5x5 sample grid fits in a 7x7 block
BLOCK = 7
MAP = "/api/0.6/map"
SECRET = "osmseg-test-secret-Zq7xK2vN"
SERVER_DATE = "Wed, 01 Jan 2025 12:00:00 GMT"
SAMPLE_DIRS = ("images", "labels", "segmented", "geo")
#: an <osm> document cut off mid-element, served with a correct Content-Length
BROKEN_XML = TINYCITY.read_bytes()[:4000]

#: a fault for the n-th request (1-based) of one path: a Reply to send instead, or None
Fault = Callable[[int], Reply | None]


# -- the fake services ---------------------------------------------------------------------------


def tile_path(tile: mercantile.Tile) -> str:
    return f"/tiles/{tile.z}/{tile.x}/{tile.y}.png"


def render_tiles() -> dict[str, bytes]:
    """PNG bytes of a BLOCK x BLOCK block of z18 tiles painted from tinycity's labels, by path."""
    table = load_class_table("classes13.toml")
    grid = sample_grid(LON, LAT, ZOOM, size=BLOCK)
    labels = rasterize(read_features([TINYCITY], grid, table), grid, table)
    rgb = render_aerial(labels, seed=3)
    tiles = {}
    for index, tile in enumerate(grid.tiles):
        col, row = grid.tile_offset(index)
        buf = io.BytesIO()
        Image.fromarray(rgb[row:row + TILE_SIZE, col:col + TILE_SIZE]).save(buf, "PNG", compress_level=1)
        tiles[tile_path(tile)] = buf.getvalue()
    return tiles


class Services:
    """The OSM API map call and the tile block on a :class:`ScriptedServer`, with faults.

    ``fault(path, fn)`` makes the n-th request of ``path`` (counted from the last
    :meth:`reset`) answer ``fn(n)`` when that is a Reply, and the good answer otherwise.
    """

    def __init__(self, server: ScriptedServer, tiles: dict[str, bytes], osm: bytes) -> None:
        self.server = server
        self.good = {path: Reply(200, data, {"Content-Type": "image/png"}) for path, data in tiles.items()}
        self.good[MAP] = Reply(200, osm, {"Content-Type": "text/xml; charset=utf-8"})
        self._lock = threading.Lock()
        self.faults: dict[str, Fault] = {}
        self.seen: Counter[str] = Counter()
        self.reset()

    def reset(self) -> None:
        """No faults; the server's record of requests and our counts start from zero."""
        self.server.reset()  # forgets the routes too: route again
        for path in self.good:
            self.server.route(path, self._answer)
        with self._lock:
            self.faults.clear()
            self.seen.clear()

    def fault(self, path: str, fn: Fault) -> None:
        with self._lock:
            self.faults[path] = fn

    def _answer(self, seen: Seen) -> Reply:
        with self._lock:
            self.seen[seen.path] += 1
            fn, n = self.faults.get(seen.path), self.seen[seen.path]
        return (fn(n) if fn is not None else None) or self.good[seen.path]


class Clean(NamedTuple):
    """The files (by relative path) and manifest of a 2-sample build that saw no fault."""

    files: dict[str, bytes]
    manifest: dict[str, Any]

    def tiles(self, index: int) -> list[str]:
        """Tile paths of sample ``index``."""
        return sample_tiles(self.manifest, index)

    def tile_only_in_second(self) -> str:
        """A tile of the second sample that the first does not use (fails only slot 1)."""
        only = [t for t in self.tiles(1) if t not in self.tiles(0)]
        assert only, "the two clean samples share all their tiles; pick another seed"
        return only[0]


@pytest.fixture(scope="module")
def pinned_clock() -> Iterator[None]:
    """Every answer of a scripted server carries the same HTTP Date."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(servers._RequestHandler, "date_time_string", lambda self, timestamp=None: SERVER_DATE)
        yield


@pytest.fixture(scope="module")
def tiles() -> dict[str, bytes]:
    return render_tiles()


@pytest.fixture(scope="module")
def module_services(pinned_clock: None, tiles: dict[str, bytes]) -> Iterator[Services]:
    with ScriptedServer() as server:
        yield Services(server, tiles, TINYCITY.read_bytes())
    assert not server.handler_errors, server.handler_errors


@pytest.fixture(scope="module")
def clean(module_services: Services, tmp_path_factory: pytest.TempPathFactory) -> Clean:
    """The reference: a 2-sample build on the module's server with no fault."""
    module_services.reset()
    root = tmp_path_factory.mktemp("clean")
    result = run_cli(*build_args(module_services.server, root / "ds", root / "cache"))
    assert result.exit_code == 0, result.output
    manifest = json.loads((root / "ds" / "manifest.json").read_text())
    assert manifest["summary"]["accepted"] == 2 and manifest["rejected"] == []
    return Clean(tree_bytes(root / "ds"), manifest)


@pytest.fixture
def services(module_services: Services, clean: Clean) -> Services:
    """The module's services (after the reference build), with no faults and fresh counts."""
    module_services.reset()
    return module_services


# -- running and checking builds -----------------------------------------------------------------


def build_args(server: ScriptedServer, out: Path, cache: Path, *extra: str, samples: int = 2) -> list[str]:
    """A two-sample build from ``server``; retries 0.01 s apart (which requests are made is what these tests
    check; the client's waits, 0.5 s doubling by default, are tests/core/test_http.py's)."""
    imagery = "xyz:" + server.url("/tiles/") + "{z}/{x}/{y}.png?key={env:TILE_KEY}"
    return ["build", "--lat", str(LAT), "--lon", str(LON), "--radius-km", "0.08", "--samples", str(samples),
            "--seed", "1", "--imagery", imagery, "--osm", "api:" + server.url("/api/0.6"),
            "--out", str(out), "--cache-dir", str(cache), "--retry-delay", "0.01", *extra]


def run_cli(*args: str) -> Result:
    """``osmseg -q ARGS`` in-process with TILE_KEY set; an exception becomes the result."""
    return CliRunner().invoke(cli, ["-q", *args], env={"TILE_KEY": SECRET})


def tree_bytes(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` except the resumable-state folder, by relative path."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and ".osmseg-build" not in p.parts}


def sample_tiles(manifest: dict[str, Any], index: int) -> list[str]:
    return [tile_path(mercantile.Tile(t["x"], t["y"], t["z"])) for t in manifest["samples"][index]["tiles"]]


def assert_one_error_line(result: Result, *words: str) -> str:
    """Exit 1, nothing on stdout, one stderr line starting ``Error:`` holding ``words``; the line."""
    assert result.exit_code == 1, result.output
    assert isinstance(result.exception, SystemExit), repr(result.exception)
    assert result.stdout == ""
    message = result.stderr.strip()
    assert message.startswith("Error:") and "\n" not in message, message
    assert "Traceback" not in result.output
    for word in words:
        assert word in message, message
    return message


def assert_nothing_half_written(out: Path) -> list[str]:
    """Sample files are exactly those of finished accepted attempts, and all decode; their names."""
    accepted = {}
    for record in (out / ".osmseg-build" / "attempts").glob("*.json"):
        attempt = json.loads(record.read_text())
        if attempt["status"] == "accepted":
            accepted[attempt["sample"]["name"]] = attempt["sample"]["files"]
    # glob("*") includes hidden names: a stray ".NAME.xxxx.tmp" would show up here
    on_disk = sorted(str(p.relative_to(out)) for d in SAMPLE_DIRS if (out / d).is_dir() for p in (out / d).glob("*"))
    assert on_disk == sorted(f for files in accepted.values() for f in files)
    for rel in on_disk:
        if rel.endswith(".tif"):
            with rasterio.open(out / rel) as geo:
                assert geo.read(1).shape == (1280, 1280)
        elif rel.endswith(".qml"):  # the label GeoTIFF's QGIS style
            assert ElementTree.parse(out / rel).getroot().tag == "qgis"
        else:
            with Image.open(out / rel) as image:
                image.load()
                assert image.size == (1280, 1280)
    return sorted(accepted)


# -- the tests -----------------------------------------------------------------------------------


def test_rate_limits_server_errors_and_cut_bodies_are_retried_to_identical_output(
        services: Services, clean: Clean, tmp_path: Path) -> None:
    first, second = clean.tiles(0), clean.tiles(1)
    services.fault(MAP, lambda n: Reply(429, "slow down\n", {"Retry-After": "1"}) if n == 1 else None)
    services.fault(first[0], lambda n: Reply(500, "oops\n") if n <= 2 else None)  # exponential backoff
    services.fault(second[-1], lambda n: Reply(502, "bad gateway\n") if n == 1 else None)
    body = services.good[first[12]].data
    services.fault(first[12], lambda n: Reply(200, body, {"Content-Type": "image/png"}, truncate=len(body) // 3)
                   if n == 1 else None)

    # one process: the two samples share 20 of their 25 tiles, and with two workers whether the other
    # sample asks for a tile between its cut answer and that answer's retry is up to the scheduler
    result = run_cli(*build_args(services.server, tmp_path / "ds", tmp_path / "cache", "--workers", "1"))

    assert result.exit_code == 0, result.output
    assert tree_bytes(tmp_path / "ds") == clean.files
    assert services.seen[MAP] == 3  # the 429, then one map call per sample
    assert (services.seen[first[0]], services.seen[first[12]], services.seen[second[-1]]) == (3, 2, 2)
    map_calls = services.server.requests(MAP)
    refused = map_calls[0]  # (another worker's map call may come between it and its retry)
    retry = next(call for call in map_calls[1:] if call.query == refused.query)
    assert retry.arrived - refused.arrived >= 0.95  # Retry-After: 1 was honoured


def test_a_tile_that_times_out_once_is_fetched_again(services: Services, clean: Clean, tmp_path: Path) -> None:
    tile = clean.tiles(0)[6]
    good = services.good[tile]
    services.fault(tile, lambda n: Reply(good.status, good.body, good.headers, delay=3) if n == 1 else None)

    result = run_cli(*build_args(services.server, tmp_path / "ds", tmp_path / "cache", "--timeout", "0.5"))

    assert result.exit_code == 0, result.output
    assert services.seen[tile] == 2
    assert tree_bytes(tmp_path / "ds") == clean.files


def test_a_missing_tile_rejects_the_attempt_and_the_slot_tries_another_centre(
        services: Services, clean: Clean, tmp_path: Path) -> None:
    hole = clean.tiles(0)[0]  # north-west corner of slot 0's first centre (accepted in the clean build)
    services.fault(hole, lambda n: Reply(404, "no such tile\n"))

    result = run_cli(*build_args(services.server, tmp_path / "ds", tmp_path / "cache", samples=1))

    assert result.exit_code == 0, result.output
    built = json.loads((tmp_path / "ds" / "manifest.json").read_text())
    rejected = built["rejected"]
    assert rejected, "the attempt with a missing tile was accepted"
    assert {r["reason"] for r in rejected} == {"placeholder_imagery"}
    assert (rejected[0]["slot"], rejected[0]["attempt"]) == (0, 0)
    assert rejected[0]["center"] == clean.manifest["samples"][0]["center"]
    assert built["summary"]["rejected_by_reason"] == {"placeholder_imagery": len(rejected)}
    sample = built["samples"][0]
    assert hole not in sample_tiles(built, 0) and sample["center"] != rejected[0]["center"]
    image = np.asarray(Image.open(tmp_path / "ds" / "images" / f"{sample['name']}.png"))
    blank = [(image[r:r + 256, c:c + 256] == 0).all() for r in range(0, 1280, 256) for c in range(0, 1280, 256)]
    assert not any(blank)


def test_osm_xml_that_stays_malformed_fails_that_sample_only_and_a_rerun_finishes(
        services: Services, clean: Clean, tmp_path: Path) -> None:
    services.fault(MAP, lambda n: Reply(200, BROKEN_XML, {"Content-Type": "text/xml"}) if n > 1 else None)
    out, cache = tmp_path / "ds", tmp_path / "cache"
    # one process, so that "the second map call" is slot 1's (two workers may ask in either order)
    args = build_args(services.server, out, cache, "--workers", "1", "--retries", "2")

    failed = run_cli(*args)

    message = assert_one_error_line(failed, "OSM API", "map?bbox=", "not valid OSM data", "1 of 2 samples")
    assert "run the same command again" in message  # says what to do
    assert services.seen[MAP] == 1 + 3  # the good first answer, then the broken one and its --retries 2
    assert assert_nothing_half_written(out) == [clean.manifest["samples"][0]["name"]]
    assert not (out / "manifest.json").exists()
    reasons = [json.loads(p.read_text()) for p in (out / ".osmseg-build" / "failures").glob("*.json")]
    assert [(r["slot"], r["attempt"]) for r in reasons] == [(1, 0)] and "not valid OSM data" in reasons[0]["reason"]

    # the API is fixed: the same command finishes (the bad answer was not kept in the cache)
    services.reset()
    rerun = run_cli(*args)
    assert rerun.exit_code == 0, rerun.output
    assert tree_bytes(out) == clean.files
    assert services.seen[MAP] == 1  # only the unfinished slot asked again


@pytest.mark.parametrize("what", ["osm-xml", "tile-html"])
def test_a_rerun_after_a_bad_answer_asks_the_fixed_server_again(
        what: str, services: Services, clean: Clean, tmp_path: Path) -> None:
    if what == "osm-xml":
        services.fault(MAP, lambda n: Reply(200, BROKEN_XML, {"Content-Type": "text/xml"}) if n > 1 else None)
    else:
        page = "<html><body>Service temporarily unavailable</body></html>"
        services.fault(clean.tile_only_in_second(), lambda n: Reply(200, page, {"Content-Type": "text/html"}))
    args = build_args(services.server, tmp_path / "ds", tmp_path / "cache")
    assert_one_error_line(run_cli(*args))

    services.reset()  # the server is fixed; the cache is left as it is
    rerun = run_cli(*args)
    assert rerun.exit_code == 0, rerun.output
    assert tree_bytes(tmp_path / "ds") == clean.files


def test_a_tile_that_keeps_failing_fails_its_sample_only_and_a_rerun_finishes(
        services: Services, clean: Clean, tmp_path: Path) -> None:
    tile = clean.tile_only_in_second()
    # Retry-After: 0 lets the client use up its retries without sleeping through the backoff
    services.fault(tile, lambda n: Reply(500, "down\n", {"Retry-After": "0"}))
    out = tmp_path / "ds"
    args = build_args(services.server, out, tmp_path / "cache")

    failed = run_cli(*args)

    assert_one_error_line(failed, "HTTP 500", tile, "again", "1 of 2 samples could not be fetched")
    assert services.seen[tile] == 6  # the first try and 5 retries
    assert assert_nothing_half_written(out) == [clean.manifest["samples"][0]["name"]]
    assert not (out / "manifest.json").exists()

    services.reset()  # the tile server is fixed
    rerun = run_cli(*args)
    assert rerun.exit_code == 0, rerun.output
    assert tree_bytes(out) == clean.files


def test_a_tile_in_a_redirect_loop_fails_its_sample_only_and_a_rerun_finishes(
        services: Services, clean: Clean, tmp_path: Path) -> None:
    """A server that redirects a tile to itself forever: requests gives up after 30 redirects with an
    exception that is an OSError; it must end in that sample's failure record, not the build."""
    tile = clean.tile_only_in_second()
    loop = Reply(301, headers={"Location": services.server.url(tile) + f"?key={SECRET}"})
    services.fault(tile, lambda n: loop)
    out = tmp_path / "ds"
    args = build_args(services.server, out, tmp_path / "cache")

    failed = run_cli(*args)

    message = assert_one_error_line(failed, "redirect loop", tile, "1 of 2 samples could not be fetched", "again")
    assert SECRET not in message and "key=REDACTED" in message
    assert services.seen[tile] == 6 * 31  # the first try and 5 retries, each followed through 30 redirects
    records = list((out / ".osmseg-build" / "failures").glob("*.json"))
    assert len(records) == 1 and "redirect loop" in json.loads(records[0].read_text())["reason"]
    assert SECRET not in records[0].read_text()
    assert assert_nothing_half_written(out) == [clean.manifest["samples"][0]["name"]]

    services.reset()  # the tile server is fixed
    rerun = run_cli(*args)
    assert rerun.exit_code == 0, rerun.output
    assert tree_bytes(out) == clean.files


def test_the_key_is_sent_but_never_written_or_logged(
        services: Services, clean: Clean, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    monkeypatch.setenv("TILE_KEY", SECRET)
    caplog.set_level(logging.DEBUG)
    tile = clean.tiles(0)[0]
    services.fault(tile, lambda n: Reply(500, "oops\n", {"Retry-After": "0"}) if n == 1 else None)
    out, cache = tmp_path / "ds", tmp_path / "cache"

    # -vvv: debug logs of osmseg and urllib3, which log every URL
    result = CliRunner().invoke(cli, ["-vvv", *build_args(services.server, out, cache, samples=1)])

    assert result.exit_code == 0, result.output
    tile_requests = [s for s in services.server.requests() if s.path.startswith("/tiles/")]
    assert len(tile_requests) == 26 and all(f"key={SECRET}" in s.query for s in tile_requests)
    retries = [r.getMessage() for r in caplog.records if "retry 1/5" in r.getMessage()]
    assert len(retries) == 1 and f"{tile}?key=REDACTED" in retries[0]  # the URL was logged, redacted
    assert SECRET not in caplog.text
    assert all(SECRET not in r.getMessage() for r in caplog.records)
    assert SECRET not in result.output and SECRET not in result.stderr
    files = [p for root in (out, cache) for p in root.rglob("*") if p.is_file()]
    assert {"http.sqlite", "manifest.json", "DATASHEET.md"} <= {p.name for p in files}
    leaks = [str(p) for p in files if SECRET.encode() in p.read_bytes()]
    assert leaks == []


def test_offline_rebuilds_from_the_cache_alone(pinned_clock: None, tiles: dict[str, bytes], tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    with ScriptedServer() as server:
        Services(server, tiles, TINYCITY.read_bytes())
        online = run_cli(*build_args(server, tmp_path / "online", cache, samples=1))
        assert online.exit_code == 0, online.output
    # the server is closed: any request now fails (connection refused)

    offline = run_cli(*build_args(server, tmp_path / "offline", cache, "--offline", samples=1))
    assert offline.exit_code == 0, offline.output
    assert tree_bytes(tmp_path / "offline") == tree_bytes(tmp_path / "online")

    empty = run_cli(*build_args(server, tmp_path / "nothing", tmp_path / "empty-cache", "--offline", samples=1))
    assert_one_error_line(empty, "--offline")


def test_ctrl_c_stops_cleanly_and_the_same_command_resumes(services: Services, clean: Clean, tmp_path: Path) -> None:
    for path, good in services.good.items():  # slow tiles: a sample takes a while, time to press Ctrl-C
        if path != MAP:
            services.fault(path, lambda n, good=good: Reply(good.status, good.body, good.headers, delay=0.1))
    out = tmp_path / "ds"
    # one process: the interrupt lands while slot 1 is being built (tests/core/test_build_workers.py stops workers)
    args = build_args(services.server, out, tmp_path / "cache", "--workers", "1")
    # a background job of a non-interactive shell (CI, `make test &`) inherits SIGINT ignored, and
    # Python then never turns it into KeyboardInterrupt: give the build the terminal's default
    proc = subprocess.Popen([sys.executable, "-m", "osmseg", "-q", *args], env={**os.environ, "TILE_KEY": SECRET},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    first_slot = out / ".osmseg-build" / "slots" / "00000.json"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and proc.poll() is None and not first_slot.exists():
        time.sleep(0.01)
    assert proc.poll() is None, f"build exited early: {proc.communicate()[1].decode()[-500:]}"
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=30)

    assert proc.returncode == 130, stderr.decode()
    assert stderr.decode().strip().startswith("interrupted: rerun the same command to resume")
    assert "Traceback" not in stderr.decode() and stdout == b""
    assert not (out / "manifest.json").exists(), "the build finished before it could be interrupted"
    assert assert_nothing_half_written(out) == [clean.manifest["samples"][0]["name"]]

    services.reset()
    rerun = run_cli(*args)
    assert rerun.exit_code == 0, rerun.output
    assert tree_bytes(out) == clean.files


# -- tiles that are answered but wrong ------------------------------------------------------------


def png(size: int, colour: tuple[int, int, int] | None = None) -> bytes:
    """A valid PNG of ``size`` px: noise, or one ``colour``."""
    pixels = (np.full((size, size, 3), colour, np.uint8) if colour is not None
              else np.random.default_rng(size).integers(0, 256, (size, size, 3), dtype=np.uint8))
    buf = io.BytesIO()
    Image.fromarray(pixels).save(buf, "PNG")
    return buf.getvalue()


def uniform_tiles(image: Path) -> list[tuple[int, int]]:
    """The 256 px tile blocks of a sample image that are of one colour (read with PIL and numpy)."""
    with Image.open(image) as im:
        rgb = np.asarray(im.convert("RGB"))
    found = []
    for row in range(0, rgb.shape[0], TILE_SIZE):
        for col in range(0, rgb.shape[1], TILE_SIZE):
            block = rgb[row:row + TILE_SIZE, col:col + TILE_SIZE].reshape(-1, 3)
            if (block.max(axis=0) == block.min(axis=0)).all():
                found.append((row // TILE_SIZE, col // TILE_SIZE))
    return found


def test_a_tile_of_the_wrong_size_is_fetched_again_and_never_kept(
        services: Services, clean: Clean, tmp_path: Path) -> None:
    """A 200 with a valid 128 px PNG (a thumbnail, another pyramid's tile) is as wrong as a broken
    body: fetched again, never stretched into a sample, never cached for a rebuild to replay."""
    first, second = clean.tiles(0), clean.tiles(1)
    thumbnail = Reply(200, png(128), {"Content-Type": "image/png"})
    services.fault(first[3], lambda n: thumbnail if n == 1 else None)
    services.fault(second[7], lambda n: thumbnail if n <= 2 else None)
    # one worker: the two samples share tiles, and two workers may both ask for one before it is cached
    args = build_args(services.server, tmp_path / "ds", tmp_path / "cache", "--workers", "1")

    result = run_cli(*args)

    assert result.exit_code == 0, result.output
    assert services.seen[first[3]] == 2 and services.seen[second[7]] == 3  # asked again after each
    assert tree_bytes(tmp_path / "ds") == clean.files
    # what the cache holds is what passed: a rebuild from it alone gives the same bytes
    offline = run_cli(*build_args(services.server, tmp_path / "again", tmp_path / "cache", "--offline"))
    assert offline.exit_code == 0, offline.output
    assert tree_bytes(tmp_path / "again") == clean.files


def test_a_tile_that_stays_the_wrong_size_fails_its_sample_and_says_why(
        services: Services, clean: Clean, tmp_path: Path) -> None:
    tile = clean.tile_only_in_second()
    services.fault(tile, lambda n: Reply(200, png(128), {"Content-Type": "image/png"}))
    failed = run_cli(*build_args(services.server, tmp_path / "ds", tmp_path / "cache"))
    assert_one_error_line(failed, tile, "is 128x128 px where this provider's tiles are 256x256 px",
                          "1 of 2 samples could not be fetched")


def test_a_server_of_512_px_tiles_is_a_usage_error_until_declared(services: Services, tmp_path: Path) -> None:
    """Tiles of twice the size everywhere: the declaration is wrong, which no retry mends; declared,
    the build goes through."""
    for path, good in list(services.good.items()):
        if path != MAP:
            buf = io.BytesIO()
            Image.open(io.BytesIO(good.data)).resize((512, 512), Image.Resampling.NEAREST).save(buf, "PNG")
            big = Reply(200, buf.getvalue(), {"Content-Type": "image/png"})
            services.fault(path, lambda n, big=big: big)
    refused = run_cli(*build_args(services.server, tmp_path / "ds", tmp_path / "cache"))
    assert refused.exit_code == 2, refused.output
    assert "is 512x512 px where this provider's tiles are 256x256 px" in refused.stderr
    assert "declare it with --tile-size 512" in refused.stderr and "Traceback" not in refused.output
    declared = run_cli(*build_args(services.server, tmp_path / "ds", tmp_path / "cache", "--tile-size", "512"))
    assert declared.exit_code == 0, declared.output
    manifest = json.loads((tmp_path / "ds" / "manifest.json").read_text())
    assert manifest["summary"]["accepted"] == 2 and "--tile-size 512" in manifest["command"]


def test_an_empty_answer_of_another_size_is_a_tile_without_imagery(
        services: Services, clean: Clean, tmp_path: Path) -> None:
    """A 1x1 transparent PNG is some servers' "no tile here": that sample is rejected for missing
    imagery and the slot draws another centre; nothing fails."""
    tile = clean.tile_only_in_second()
    buf = io.BytesIO()
    Image.new("RGBA", (1, 1), (0, 0, 0, 0)).save(buf, "PNG")
    services.fault(tile, lambda n: Reply(200, buf.getvalue(), {"Content-Type": "image/png"}))
    result = run_cli(*build_args(services.server, tmp_path / "ds", tmp_path / "cache"))
    assert result.exit_code == 0, result.output
    manifest = json.loads((tmp_path / "ds" / "manifest.json").read_text())
    assert any(r["reason"] == "missing_imagery" for r in manifest["rejected"]), manifest["rejected"]


def test_a_tile_of_one_colour_rejects_its_sample_as_placeholder_imagery(
        services: Services, clean: Clean, tmp_path: Path) -> None:
    """The "no imagery here" tile of most servers is a valid image of one colour: each is counted, and
    a sample holding one is rejected; no accepted image holds a tile of one colour."""
    tile = clean.tile_only_in_second()
    services.fault(tile, lambda n: Reply(200, png(256, (255, 255, 255)), {"Content-Type": "image/png"}))
    out = tmp_path / "ds"

    result = run_cli(*build_args(services.server, out, tmp_path / "cache"))

    assert result.exit_code == 0, result.output
    manifest = json.loads((out / "manifest.json").read_text())
    reasons = [r for r in manifest["rejected"] if r["reason"] == "placeholder_imagery"]
    assert reasons and all("(1 of one colour)" in r["detail"] for r in reasons), manifest["rejected"]
    assert all(r["uniform_tiles"] == [tile.removeprefix("/tiles/").removesuffix(".png")] for r in reasons)
    assert manifest["samples"], "no sample was accepted"
    for sample in manifest["samples"]:
        assert sample["imagery"]["uniform_tiles"] == []
        assert uniform_tiles(out / next(f for f in sample["files"] if f.startswith("images/"))) == []


@pytest.mark.parametrize("workers", ["1", "2"])
def test_a_stopped_build_does_not_wait_out_a_servers_retry_after(
        services: Services, clean: Clean, tmp_path: Path, workers: str) -> None:
    """A server that asks for a 60 s pause: SIGTERM (and Ctrl-C) end the build in seconds, not after
    the pause; a second SIGTERM is never ignored."""
    tile = clean.tiles(0)[0]
    services.fault(tile, lambda n: Reply(503, "busy\n", {"Retry-After": "60"}))
    args = build_args(services.server, tmp_path / "ds", tmp_path / "cache", "--workers", workers)
    proc = subprocess.Popen([sys.executable, "-m", "osmseg", "-q", *args], env={**os.environ, "TILE_KEY": SECRET},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and proc.poll() is None and services.seen[tile] == 0:
        time.sleep(0.01)
    time.sleep(0.5)  # inside the 60 s pause
    assert proc.poll() is None, f"build exited early: {proc.communicate()[1].decode()[-500:]}"
    stopped = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=60)
    took = time.monotonic() - stopped
    assert proc.returncode == 143, stderr.decode()
    assert stderr.decode() == "terminated (SIGTERM): rerun the same command to resume; finished work is kept\n"
    assert took < 20, f"the build waited {took:.1f} s for the server's pause before it ended"


# -- a flaky network: every kind of fault at once ------------------------------------------------

#: the kinds of fault a real server, proxy or network gives, each as a Reply for a good answer
FAULT_KINDS: dict[str, Callable[[str, Reply], Reply]] = {
    "429": lambda path, good: Reply(429, "slow down\n", {"Retry-After": "0"}),
    "500": lambda path, good: Reply(500, "internal error\n"),
    "502": lambda path, good: Reply(502, "bad gateway\n"),
    "503": lambda path, good: Reply(503, "unavailable\n", {"Retry-After": "0"}),
    "504": lambda path, good: Reply(504, "gateway timeout\n"),
    "cut body": lambda path, good: Reply(good.status, good.body, good.headers, truncate=len(good.data) // 2),
    "dropped": lambda path, good: Reply(good.status, good.body, good.headers, truncate=0),
    "slow": lambda path, good: Reply(good.status, good.body, good.headers, delay=1.5),
    # a 200 with a corrupt body: a proxy's HTML page, a PNG cut short with a correct length, bad XML,
    # a valid image of the wrong size (a thumbnail), a tile of one colour (a placeholder, then the good tile)
    "thumbnail": lambda path, good: Reply(200, BROKEN_XML if path == MAP else png(128), good.headers),
    "html page": lambda path, good: Reply(200, "<html><body>Service temporarily unavailable</body></html>",
                                          {"Content-Type": "text/html"}),
    "broken body": lambda path, good: Reply(200, BROKEN_XML if path == MAP else good.data[: len(good.data) // 3],
                                            good.headers),
}


def flaky(services: Services, rate: float, seed: int) -> Counter[str]:
    """Make every request fail with probability ``rate``, with a fault drawn from every kind.

    The draw depends only on (seed, path, n-th request of that path), so a run is repeatable
    whatever the order the build's threads ask in. Returns the faults served, by kind.
    """
    served: Counter[str] = Counter()
    kinds = sorted(FAULT_KINDS)

    for path, good in services.good.items():
        def fault(n: int, path: str = path, good: Reply = good) -> Reply | None:
            rng = np.random.default_rng([seed, zlib.crc32(path.encode()), n])
            if rng.random() >= rate:
                return None
            kind = kinds[int(rng.integers(len(kinds)))]
            served[kind] += 1
            return FAULT_KINDS[kind](path, good)
        services.fault(path, fault)
    return served


# one draw of faults in make test, two more in make test-slow
@pytest.mark.parametrize("seed", [11, *(pytest.param(s, marks=pytest.mark.slow) for s in (12, 13))])
def test_a_build_through_ten_percent_faults_of_every_kind_finishes_in_one_run(
        services: Services, tmp_path: Path, seed: int) -> None:
    samples = 8
    reference = tmp_path / "clean"
    assert run_cli(*build_args(services.server, reference, tmp_path / "clean-cache", samples=samples)).exit_code == 0
    services.reset()
    served = flaky(services, 0.10, seed)

    result = run_cli(*build_args(services.server, tmp_path / "ds", tmp_path / "cache", "--timeout", "0.5",
                                 samples=samples))

    assert result.exit_code == 0, result.output
    assert sum(served.values()) >= 3, served  # the build really went through faults
    assert tree_bytes(tmp_path / "ds") == tree_bytes(reference)


@pytest.mark.slow
def test_a_long_build_through_ten_percent_faults_finishes_in_one_run(services: Services, tmp_path: Path) -> None:
    reference = tmp_path / "clean"
    assert run_cli(*build_args(services.server, reference, tmp_path / "clean-cache", samples=60)).exit_code == 0
    services.reset()
    served = flaky(services, 0.10, 7)
    result = run_cli(*build_args(services.server, tmp_path / "ds", tmp_path / "cache", "--timeout", "0.5",
                                 samples=60))
    assert result.exit_code == 0, result.output
    assert sum(served.values()) >= 5, served
    assert tree_bytes(tmp_path / "ds") == tree_bytes(reference)
