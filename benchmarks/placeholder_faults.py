"""A tile server that answers 5 % of tile requests with a white tile, at random: does a build give
the clean build's bytes, and does a rerun against the healthy server mend it?

Run from a checkout's root (it uses the fault services of ``tests/core/test_build_faults.py``: the
OSM API and a z18 tile block of tinycity on 127.0.0.1)::

    .venv/bin/python benchmarks/placeholder_faults.py [SAMPLES]   # default 30

For three seeds of the faults it prints the white tiles served, the build's exit code and
samples, how many files differ from a build that saw no fault, and the same after a rerun of
the same command against the healthy server (with the requests that rerun made). Run it in an
older checkout to see the defect it measures (issue 31: a white tile was cached as "no
imagery", samples were rejected for it, and a rerun asked nothing).
"""

from __future__ import annotations

import sys
import tempfile
import zlib
from pathlib import Path

import numpy as np

from osmseg.output.manifest import manifest_path, read_manifest

sys.path.insert(0, "tests")  # servers.py
sys.path.insert(0, "tests/core")  # test_build_faults.py
import servers
from servers import Reply, ScriptedServer
from test_build_faults import (
    SERVER_DATE,
    TINYCITY,
    Services,
    build_args,
    png,
    render_tiles,
    run_cli,
    tree_bytes,
)

RATE = 0.05
WHITE = Reply(200, png(256, (255, 255, 255)), {"Content-Type": "image/png"})


def white_at_random(services: Services, seed: int) -> list[int]:
    """Answer each tile request with a white tile with probability RATE, drawn from (seed, path,
    n-th request): the same faults whatever order the build asks in. Returns a counter (one item)."""
    served = [0]
    for path in services.good:
        if path.startswith("/tiles/"):
            def fault(n: int, path: str = path) -> Reply | None:
                if np.random.default_rng([seed, zlib.crc32(path.encode()), n]).random() >= RATE:
                    return None
                served[0] += 1
                return WHITE
            services.fault(path, fault)
    return served


def differing(a: dict[str, bytes], b: dict[str, bytes]) -> int:
    return sum(1 for k in set(a) | set(b) if a.get(k) != b.get(k))


def main() -> None:
    samples = int(sys.argv[1]) if len(sys.argv) > 1 else 30
    servers._RequestHandler.date_time_string = lambda self, timestamp=None: SERVER_DATE
    tmp = Path(tempfile.mkdtemp(prefix="placeholder-faults-"))
    with ScriptedServer() as server:
        services = Services(server, render_tiles(), TINYCITY.read_bytes())
        reference = run_cli(*build_args(server, tmp / "clean", tmp / "clean-cache", samples=samples))
        assert reference.exit_code == 0, reference.output
        clean = tree_bytes(tmp / "clean")
        for seed in (1, 2, 3):
            services.reset()
            served = white_at_random(services, seed)
            out, cache = tmp / f"ds{seed}", tmp / f"cache{seed}"
            first = run_cli(*build_args(server, out, cache, samples=samples))
            accepted = (read_manifest(out).summary.accepted or 0) if manifest_path(out).is_file() else 0
            after_first = differing(clean, tree_bytes(out))
            services.reset()  # the server is healthy now
            asked = server.count()
            again = run_cli(*build_args(server, out, cache, samples=samples))
            print(f"seed {seed}: white tiles served {served[0]}; exit {first.exit_code}; samples {accepted}/{samples}; "
                  f"files differing from the clean build {after_first}; rerun on the healthy server: exit "
                  f"{again.exit_code}, {server.count() - asked} requests, files differing {differing(clean, tree_bytes(out))}")


if __name__ == "__main__":
    main()
