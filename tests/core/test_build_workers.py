"""``osmseg build --workers N`` and concurrent ``--shard`` processes, as users run them.

What a user checks: the dataset's bytes do not depend on the number of workers; a build with
workers killed or interrupted at any moment resumes to those bytes and leaves no worker behind;
several shard processes started at once on one folder (a Slurm array job) make the same dataset
as one process; and the workers of one build stay one polite HTTP client (per-host limits and
``Retry-After`` hold across them). Sources are the project's own: tinycity's OSM file with a
GeoTIFF painted from it (``imagery_tif``), and the scripted tile server of test_build_faults.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from click.testing import CliRunner
from conftest import TINYCITY, TINYCITY_CENTRE
from servers import Reply
from test_build_faults import (  # noqa: F401  (fixtures)
    Services,
    build_args as service_args,
    clean,
    module_services,
    pinned_clock,
    run_cli as service_cli,
    services,
    tiles,
)

from osmseg.cli.main import cli

LON, LAT = TINYCITY_CENTRE


def build_args(out: Path, imagery: Path, *extra: str, samples: int = 6) -> list[str]:
    return ["build", "--lat", str(LAT), "--lon", str(LON), "--radius-km", "0.08", "--samples", str(samples),
            "--seed", "1", "--imagery", f"geotiff:{imagery}", "--osm", str(TINYCITY), "--out", str(out),
            "--cache-dir", str(out.parent / "cache"), *extra]


def tree_bytes(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` except the resumable-state folder, by relative path."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and ".osmseg-build" not in p.parts}


def run_cli(*args: str) -> click.testing.Result:  # noqa: F821
    return CliRunner().invoke(cli, ["-q", *args], catch_exceptions=False)


def popen_build(*args: str) -> subprocess.Popen[bytes]:
    # a background job of a non-interactive shell inherits SIGINT ignored: give the build the default
    return subprocess.Popen([sys.executable, "-m", "osmseg", "-q", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def wait_for_slots(out: Path, proc: subprocess.Popen[bytes], count: int) -> None:
    slots = out / ".osmseg-build" / "slots"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None and len(list(slots.glob("*.json"))) < count:
        time.sleep(0.02)
    assert proc.poll() is None, f"build exited early: {proc.communicate()[1].decode()[-800:]}"


def descendants(pid: int) -> set[int]:
    """Every process below ``pid`` (Linux /proc)."""
    found: set[int] = set()
    todo = [pid]
    while todo:
        for task in Path(f"/proc/{todo.pop()}/task").glob("*"):
            try:
                kids = {int(k) for k in (task / "children").read_text().split()}
            except OSError:
                kids = set()
            todo += sorted(kids - found)
            found |= kids
    return found


def wait_gone(pids: set[int], seconds: float = 10.0) -> bool:
    """Whether every process of ``pids`` has ended within ``seconds``."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and any(alive(p) for p in pids):
        time.sleep(0.05)
    return not any(alive(p) for p in pids)


def alive(pid: int) -> bool:
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    return "\nState:\tZ" not in status  # a zombie has stopped: it only waits to be reaped


@pytest.fixture(scope="module")
def one_worker(imagery_tif: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    """The reference: the 6-sample build in one process."""
    out = tmp_path_factory.mktemp("one") / "ds"
    result = run_cli(*build_args(out, imagery_tif, "--workers", "1"))
    assert result.exit_code == 0, result.output
    return tree_bytes(out)


def test_two_workers_write_the_bytes_of_one(tmp_path: Path, imagery_tif: Path, one_worker: dict[str, bytes]) -> None:
    out = tmp_path / "ds"
    result = run_cli(*build_args(out, imagery_tif, "--workers", "2"))
    assert result.exit_code == 0, result.output
    assert tree_bytes(out) == one_worker
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["summary"]["accepted"] == 6 and "workers" not in manifest["command"]
    # the overview sheet was drawn from thumbnails kept while writing; from the files it is the same
    kept = out / ".osmseg-build" / "thumbnails"
    assert sorted(p.name for p in kept.iterdir())[:2] == [f"{manifest['samples'][0]['name']}.image.png",
                                                          f"{manifest['samples'][0]['name']}.labels.png"]
    for thumb in kept.iterdir():
        thumb.unlink()
    assert run_cli(*build_args(out, imagery_tif, "--workers", "2")).exit_code == 0  # finalises again
    assert tree_bytes(out) == one_worker


@pytest.mark.parametrize("stop", [signal.SIGKILL, signal.SIGINT], ids=["kill -9", "Ctrl-C"])
def test_a_build_stopped_with_workers_leaves_no_worker_and_resumes_to_the_same_bytes(
        tmp_path: Path, imagery_tif: Path, one_worker: dict[str, bytes], stop: signal.Signals) -> None:
    out = tmp_path / "ds"
    proc = popen_build(*build_args(out, imagery_tif, "--workers", "2"))
    wait_for_slots(out, proc, 1)
    workers = descendants(proc.pid)
    assert workers, "the build started no worker process"
    proc.send_signal(stop)
    _, stderr = proc.communicate(timeout=30)
    if stop == signal.SIGINT:  # Ctrl-C: the build stops its workers itself and says how to go on
        assert proc.returncode == 130, stderr.decode()
        assert stderr.decode().strip() == "interrupted: rerun the same command to resume; finished work is kept"
        assert not list(out.glob("*/.*.tmp")), "a half-written file was left"
    # kill -9: each worker sees its build gone and ends (the fork server and resource tracker follow)
    assert wait_gone(workers), "workers outlived their stopped build"
    assert not (out / "manifest.json").exists(), "the build finished before it could be stopped"

    result = run_cli(*build_args(out, imagery_tif, "--workers", "2"))
    assert result.exit_code == 0, result.output
    assert tree_bytes(out) == one_worker


def _cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


@pytest.mark.parametrize("moment", ["server importing", "workers starting", "workers opening sources"])
def test_ctrl_c_while_a_build_with_workers_starts_says_one_line(tmp_path: Path, imagery_tif: Path,
                                                                moment: str) -> None:
    """Ctrl-C (SIGINT to the whole process group, as a terminal sends it) while the fork server is
    still importing, while the pool forks its workers, or while they open their sources: exit 130
    and no traceback from any of the processes, however early it comes."""
    out = tmp_path / "ds"
    proc = subprocess.Popen([sys.executable, "-m", "osmseg", "-q", *build_args(out, imagery_tif, "--workers", "2")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and proc.poll() is None:
        below = descendants(proc.pid)
        servers = [p for p in below if b"forkserver" in _cmdline(p)]
        if servers and (moment == "server importing" or descendants(servers[0])):
            break
        time.sleep(0.002)
    if moment == "workers opening sources":
        time.sleep(0.03)
    assert proc.poll() is None, "the build ended before it could be interrupted"
    os.killpg(proc.pid, signal.SIGINT)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr.decode()
    assert "Traceback" not in stderr.decode() and "Exception in initializer" not in stderr.decode(), stderr.decode()
    # and the folder resumes (6 samples: every moment above comes before a worker has built its first one)
    result = run_cli(*build_args(out, imagery_tif, "--workers", "2"))
    assert result.exit_code == 0, result.output

def test_shards_started_at_once_on_one_folder_make_the_one_process_dataset(
        tmp_path: Path, imagery_tif: Path, one_worker: dict[str, bytes]) -> None:
    """As a Slurm array job: N processes, --shard K/N, one shared --out, started together."""
    out = tmp_path / "ds"
    procs = [popen_build(*build_args(out, imagery_tif, "--shard", f"{k}/3", "--workers", "1")) for k in (1, 2, 3)]
    results = [p.communicate(timeout=300) for p in procs]
    for proc, (_, stderr) in zip(procs, results):
        assert proc.returncode == 0, stderr.decode()
    # the shard that finished last wrote the manifest (any may have; each says where the dataset is)
    assert any(stdout.decode().strip() == str(out / "manifest.json") for stdout, _ in results)
    assert tree_bytes(out) == one_worker


def test_workers_keep_their_log_records_quiet_by_default_and_say_them_with_v(
        tmp_path: Path, imagery_tif: Path) -> None:
    """Per-object OSM warnings of workers go through the command's own logging: hidden without -v,
    and with -v the same lines as from one process."""
    lines = {}
    for workers in ("1", "2"):
        for flag in ("", "-v"):
            out = tmp_path / f"w{workers}{flag}" / "ds"
            run = subprocess.run([sys.executable, "-m", "osmseg", *([flag] if flag else []),
                                  *build_args(out, imagery_tif, "--workers", workers, samples=3)],
                                 capture_output=True, text=True, timeout=300)
            assert run.returncode == 0, run.stderr
            said = sorted(line for line in run.stderr.splitlines() if line.startswith("WARNING osmseg.osm"))
            if flag:
                lines[workers] = said
            else:
                assert said == [], said
    assert lines["1"] and lines["1"] == lines["2"]


def test_record_with_several_workers_is_a_usage_error(tmp_path: Path, imagery_tif: Path) -> None:
    result = CliRunner().invoke(cli, build_args(tmp_path / "ds", imagery_tif, "--workers", "2",
                                                "--record", str(tmp_path / "c.yaml")))
    assert result.exit_code == 2, result.output
    assert "--workers 1" in result.stderr and not (tmp_path / "ds").exists()


# -- one polite client across workers -------------------------------------------------------------

def test_workers_share_the_per_host_limit_and_a_retry_after(services: Services, tmp_path: Path) -> None:
    """Two workers fetching 25 tiles each on 4 threads would have 8 requests in flight; the host's
    limit (6) holds across them, and a 429 with Retry-After: 2 answered to one worker holds back
    every worker's requests to that host for those two seconds.

    A request that had passed its gate before the 429 reached its worker and wrote the pause may
    still land just after the refusal (no client can recall it), so the quiet window starts
    0.3 s after the refusal; without a shared pause the other worker's four threads would send
    a dozen tiles in the 1.6 s that remain."""
    pause: list[float] = []
    lock = threading.Lock()

    def slow(n: int, good: Reply) -> Reply:
        return Reply(good.status, good.body, good.headers, delay=0.15)

    for path, good in services.good.items():
        if path.startswith("/tiles/"):
            services.fault(path, lambda n, good=good: slow(n, good))
    first_tile = sorted(p for p in services.good if p.startswith("/tiles/"))[24]

    def limited(n: int, good: Reply = services.good[first_tile]) -> Reply:
        if n == 1:
            with lock:
                pause.append(time.monotonic())
            return Reply(429, "slow down\n", {"Retry-After": "2"})
        return slow(n, good)

    services.fault(first_tile, limited)
    result = service_cli(*service_args(services.server, tmp_path / "ds", tmp_path / "cache", "--workers", "2",
                                       samples=4))
    assert result.exit_code == 0, result.output
    assert 4 <= services.server.max_in_flight <= 6, services.server.max_in_flight
    assert len(pause) == 1  # the centre tile is in every sample: it was asked for, and refused once
    during = [(s.path, round(s.arrived - pause[0], 3)) for s in services.server.requests()
              if pause[0] + 0.3 < s.arrived < pause[0] + 1.9]
    assert during == [], f"requests sent to the host while it was paused (path, seconds after the 429): {during}"


def test_a_worker_that_cannot_open_its_sources_says_why_in_one_line(tmp_path: Path) -> None:
    """A worker whose sources fail to open (the GeoTIFF went away after the build checked it) raises
    the source's own one-line error in the build, not "a worker process died"."""
    from concurrent.futures import ProcessPoolExecutor

    from osmseg.builder.config import BuildConfig
    from osmseg.builder.workers import WorkerSetup, _build_slot, _start_worker
    from osmseg.errors import ConfigError
    from osmseg.places import Area
    from osmseg.runtime.processes import worker_context

    config = BuildConfig(out_dir=tmp_path / "ds", area=Area("t", LAT, LON, 0.08),
                         imagery=f"geotiff:{tmp_path / 'gone.tif'}", osm=str(TINYCITY), samples=1,
                         cache_dir=tmp_path / "cache")
    context = worker_context()
    setup = WorkerSetup(config=config, env={}, regions=(), gate_dir=None, log_queue=context.Queue(),
                        log_level=30, parent=os.getpid())
    with ProcessPoolExecutor(1, mp_context=context, initializer=_start_worker, initargs=(setup,)) as pool:
        with pytest.raises(ConfigError, match="gone.tif does not exist"):
            pool.submit(_build_slot, 0, False).result(timeout=120)


# -- the executable starts the fork server before it imports the builder ---------------------------

EARLY_SERVER = """
import importlib.abc, os, sys
seen = {}
class Watch(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name == "osmseg.builder.run" and "children" not in seen:  # the builder is about to be imported
            pid = os.getpid()
            seen["children"] = [open(f"/proc/{c}/cmdline", "rb").read().decode(errors="replace")
                                for t in os.listdir(f"/proc/{pid}/task")
                                for c in open(f"/proc/{pid}/task/{t}/children").read().split()]
        return None
sys.meta_path.insert(0, Watch())
sys.argv = ["osmseg", *sys.argv[1:]]
try:
    from osmseg.cli.launch import main
    main()
finally:
    print("CHILDREN", repr(seen.get("children")), file=sys.stderr)
"""


@pytest.mark.skipif(not Path(f"/proc/{os.getpid()}/task/{os.getpid()}/children").exists(),
                    reason="reads a process's children from Linux's /proc")
@pytest.mark.parametrize("workers, early", [("2", True), ("1", False)])
def test_the_executable_starts_the_fork_server_before_it_imports_the_builder(
        tmp_path: Path, imagery_tif: Path, workers: str, early: bool) -> None:
    """``osmseg build --workers 2``: the fork server is already running (importing osmseg for the
    workers) when the command imports the builder, so both import side by side; ``--workers 1``
    starts none. The build itself is unchanged: two samples (two slots, so two workers), exit 0."""
    run = subprocess.run([sys.executable, "-c", EARLY_SERVER, "-q",
                          *build_args(tmp_path / "ds", imagery_tif, "--workers", workers, samples=2)],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    said = [line for line in run.stderr.splitlines() if line.startswith("CHILDREN ")]
    children = eval(said[-1].split(" ", 1)[1])
    servers = [c for c in children if "forkserver" in c]
    assert len(servers) == (1 if early else 0), children
    assert (tmp_path / "ds" / "manifest.json").exists()


def test_the_executable_imports_nothing_heavy_before_it_starts_the_server() -> None:
    """The launcher's own imports are the standard library's: anything heavier would delay the
    very server start it exists for."""
    code = ("import sys; import osmseg.cli.launch; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('numpy', 'click', 'rasterio', 'pyproj', "
            "'cv2', 'osmium', 'requests') or m in ('osmseg.builder.run', 'osmseg.cli.main')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
