"""Tiles that say "no imagery here" (one colour, empty, 404) are verdicts, never taken on one answer.

A tile server under load, a CDN edge out of sync, a proxy that answers with a blank picture: each
sends, now and then, a tile of one colour or an empty answer for a place that has imagery. The
builder cannot tell such an answer from a real "no imagery here" by looking at it, so it asks
again (:data:`osmseg.net.http.ABSENT_ASKS` answers in all, the retry delay apart) before the
verdict condemns a sample; the verdict is kept in the cache apart from imagery (an ``--offline``
rebuild replays it) and a later run against the server asks again, so a verdict a fault caused is
mended by a rerun. What a user checks here: the bytes of the dataset equal those of a build that
saw no fault, the cache's imagery table never holds a tile of one colour (read with ``sqlite3``
and PIL, not with osmseg's cache code), and the ``incomplete:`` line says what to do.

The services, the reference build and the helpers are those of ``tests/core/test_build_faults.py``.
"""

from __future__ import annotations

import io
import json
import pickle
import sqlite3
import zlib
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image
from servers import Reply
from test_build_faults import (  # noqa: F401  (fixtures: pinned_clock, tiles, module_services, clean, services)
    SECRET,
    Clean,
    Services,
    build_args,
    clean,
    module_services,
    pinned_clock,
    png,
    run_cli,
    services,
    tiles,
    tree_bytes,
    uniform_tiles,
)

from osmseg.cli.main import cli
from osmseg.net.http import ABSENT_ASKS

WHITE = Reply(200, png(256, (255, 255, 255)), {"Content-Type": "image/png"})


def one_colour_at_random(services: Services, rate: float, seed: int) -> Counter[str]:
    """Answer each tile request with a white tile with probability ``rate``. The draw depends only
    on (seed, path, n-th request of that path), so a run is repeatable whatever order the build's
    threads ask in. Returns how many white tiles were served, by path."""
    served: Counter[str] = Counter()
    for path in services.good:
        if path.startswith("/tiles/"):
            def fault(n: int, path: str = path) -> Reply | None:
                if np.random.default_rng([seed, zlib.crc32(path.encode()), n]).random() >= rate:
                    return None
                served[path] += 1
                return WHITE
            services.fault(path, fault)
    return served


def cached_tiles(cache: Path) -> tuple[list[bytes], int]:
    """The tile bodies in the cache's imagery table (requests-cache's ``responses``, read with sqlite3
    and unpickled: requests-cache's SQLite serializer pickles each answer as a dict), and the number
    of verdicts kept."""
    with sqlite3.connect(cache / "http.sqlite") as db:
        rows = db.execute("SELECT value FROM responses").fetchall()
        verdicts = db.execute("SELECT COUNT(*) FROM verdicts").fetchone()[0]
    bodies = []
    for (value,) in rows:
        response = pickle.loads(value)
        if "/tiles/" in response["url"]:
            bodies.append(response["_content"])
    return bodies, int(verdicts)


def is_one_colour(body: bytes) -> bool:
    with Image.open(io.BytesIO(body)) as image:
        pixels = np.asarray(image.convert("RGB")).reshape(-1, 3)
    return bool((pixels.max(axis=0) == pixels.min(axis=0)).all())


@pytest.mark.parametrize("seed", [26, *(pytest.param(s, marks=pytest.mark.slow) for s in (17, 34))])
def test_a_build_through_five_percent_one_colour_tiles_gives_the_clean_bytes_in_one_run(
        services: Services, tmp_path: Path, seed: int) -> None:
    samples = 8
    reference = tmp_path / "clean"
    assert run_cli(*build_args(services.server, reference, tmp_path / "clean-cache", samples=samples)).exit_code == 0
    services.reset()
    served = one_colour_at_random(services, 0.05, seed)

    result = run_cli(*build_args(services.server, tmp_path / "ds", tmp_path / "cache", samples=samples))

    assert result.exit_code == 0, result.output
    assert sum(served.values()) >= 2, served  # the build really met white tiles
    assert tree_bytes(tmp_path / "ds") == tree_bytes(reference)
    bodies, verdicts = cached_tiles(tmp_path / "cache")
    assert bodies and not any(is_one_colour(b) for b in bodies)
    assert verdicts == 0


def test_a_placeholder_verdict_is_kept_apart_replayed_offline_and_asked_again_by_a_rerun(
        services: Services, clean: Clean, tmp_path: Path) -> None:
    """A tile white through every ask of the first run: that attempt of slot 1 is rejected and the slot
    takes its next centre. An --offline rebuild replays the verdict; once the server has imagery there
    again, the same command asks again and ends with the clean build's bytes."""
    tile = clean.tile_only_in_second()
    services.fault(tile, lambda n: WHITE)
    out, cache = tmp_path / "ds", tmp_path / "cache"
    # one process: a verdict is taken once per process (each worker asks for itself)
    args = build_args(services.server, out, cache, "--workers", "1")

    first = run_cli(*args)

    assert first.exit_code == 0, first.output
    assert services.seen[tile] == ABSENT_ASKS  # asked again before the verdict was taken (once in a run)
    manifest = json.loads((out / "manifest.json").read_text())
    rejected = [r for r in manifest["rejected"] if r["reason"] == "placeholder_imagery"]
    assert rejected and {r["slot"] for r in rejected} == {1} and rejected[0]["attempt"] == 0, rejected
    assert tree_bytes(out) != clean.files
    for sample in manifest["samples"]:
        assert uniform_tiles(out / next(f for f in sample["files"] if f.startswith("images/"))) == []
    bodies, verdicts = cached_tiles(cache)
    assert not any(is_one_colour(b) for b in bodies) and verdicts == 1

    offline = run_cli(*build_args(services.server, tmp_path / "offline", cache, "--offline"))
    assert offline.exit_code == 0, offline.output
    assert tree_bytes(tmp_path / "offline") == tree_bytes(out)  # the verdict, replayed from the cache

    services.reset()  # the server has imagery there again
    rerun = run_cli(*args)

    assert rerun.exit_code == 0, rerun.output
    assert services.seen[tile] == 1
    assert tree_bytes(out) == clean.files
    attempts = sorted(p.name for p in (out / ".osmseg-build" / "attempts").glob("*.json"))
    assert attempts == ["00000-00.json", "00001-00.json"]  # the old slot's later attempt is gone
    bodies, verdicts = cached_tiles(cache)
    assert verdicts == 0  # the imagery that came replaced the verdict

    again = run_cli(*args)  # nothing left to ask: a finished build without verdicts sends nothing
    assert again.exit_code == 0, again.output
    assert services.seen[tile] == 1 and tree_bytes(out) == clean.files


def test_a_dataset_left_incomplete_by_placeholders_says_what_to_do(
        services: Services, clean: Clean, tmp_path: Path) -> None:
    for path in services.good:  # white everywhere but under the first sample
        if path.startswith("/tiles/") and path not in clean.tiles(0):
            services.fault(path, lambda n: WHITE)
    args = build_args(services.server, tmp_path / "ds", tmp_path / "cache", "--max-tries", "2", samples=2)

    result = CliRunner().invoke(cli, args, env={"TILE_KEY": SECRET})  # not -q: the summary is wanted

    assert result.exit_code == 0, result.output
    lines = [x for x in result.stderr.splitlines() if x.startswith("incomplete:")]
    assert len(lines) == 1, result.stderr
    assert "one colour or empty" in lines[0] and "run the same command again later" in lines[0], lines[0]
    assert "--imagery" in lines[0], lines[0]
