"""One build owns its folder, and every way a build can end leaves nothing behind and says so.

What a user checks, with real processes started as a shell starts them:

* two ``osmseg build`` commands with other options started in the same millisecond into one
  ``--out``: one builds, the other refuses at once with one line naming what holds the folder,
  and the dataset is exactly the winner's (``osmseg verify`` clean);
* a command that reads the dataset (``verify``) while a build holds it refuses the same way;
* ``SIGTERM`` (a scheduler's time limit, ``kill``) ends a build with one line and exit 143;
  ``kill -9`` and ``SIGTERM`` with workers leave nothing in ``$TMPDIR`` once the next run has
  run, no worker behind, and no "leaked semaphore" warning; a kill during the dataset-level
  files leaves no temporary name in the dataset after the rerun; every rerun ends in the bytes
  of an uninterrupted build;
* an output folder deleted while its build runs is said to be deleted;
* Ctrl-C at any moment of the start-up ends with the line and exit status of an interrupt.

Sources are the project's own (tinycity's OSM file and a GeoTIFF painted from it).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from osmseg.processes import INTERRUPTED, TERMINATED, owner

from test_build_workers import build_args, descendants, one_worker, run_cli, tree_bytes, wait_gone  # noqa: F401

#: Starts ``osmseg ARGS`` once its imports are done, at the wall-clock instant given first: two of
#: them started with the same instant begin within a millisecond of each other.
STARTER = """
import sys, time
import osmseg.cli.main, osmseg.build  # everything imported before the common start
start = float(sys.argv[1])
sys.argv = ["osmseg", *sys.argv[2:]]
while time.time() < start:
    pass
from osmseg.cli.launch import main
main()
"""


def popen(*args: str, tmpdir: Path | None = None, start_at: float | None = None) -> subprocess.Popen[bytes]:
    env = dict(os.environ)
    if tmpdir is not None:
        env["TMPDIR"] = str(tmpdir)
    command = ([sys.executable, "-c", STARTER, repr(start_at)] if start_at is not None
               else [sys.executable, "-m", "osmseg"])
    return subprocess.Popen([*command, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def wait_for(condition, proc: subprocess.Popen[bytes], seconds: float = 120) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and proc.poll() is None and not condition():
        time.sleep(0.002)
    assert proc.poll() is None, f"the build ended too early: {proc.communicate()[1].decode()[-800:]}"


def slots_done(out: Path) -> int:
    return len(list((out / ".osmseg-build" / "slots").glob("*.json")))


def temporary_names(out: Path) -> list[str]:
    """Every temporary file or folder in a dataset folder, build state included."""
    return sorted(str(p.relative_to(out)) for p in out.rglob("*")
                  if p.name.endswith(".tmp") or p.name.startswith("entries-"))


def dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


@pytest.fixture(scope="module")
def references(imagery_tif: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict[str, bytes]]:
    """The 4-sample datasets of seeds 3 and 4, each built alone in one process."""
    found = {}
    for seed in ("3", "4"):
        out = tmp_path_factory.mktemp(f"seed{seed}") / "ds"
        result = run_cli(*build_args(out, imagery_tif, "--workers", "1", "--seed", seed, samples=4))
        assert result.exit_code == 0, result.output
        found[seed] = tree_bytes(out)
    return found


@pytest.mark.parametrize("attempt", [*range(3), *(pytest.param(i, marks=pytest.mark.slow) for i in range(3, 12))])
def test_two_builds_with_other_options_started_in_the_same_millisecond_one_owns_the_folder(
        tmp_path: Path, imagery_tif: Path, references: dict[str, dict[str, bytes]], attempt: int) -> None:
    out = tmp_path / "ds"
    start = time.time() + 3.0  # both have imported everything by then
    procs = {seed: popen("-q", *build_args(out, imagery_tif, "--workers", "2", "--seed", seed, samples=4),
                         start_at=start) for seed in ("3", "4")}
    ended = {seed: proc.communicate(timeout=300) for seed, proc in procs.items()}
    codes = {seed: proc.returncode for seed, proc in procs.items()}
    assert sorted(codes.values()) == [0, 1], {s: (codes[s], ended[s][1].decode()[-600:]) for s in procs}
    winner = next(s for s, code in codes.items() if code == 0)
    loser = next(s for s in procs if s != winner)
    line = ended[loser][1].decode().strip()
    assert "\n" not in line and "Traceback" not in line, line
    holder = procs[winner].pid
    assert line.startswith(f"Error: {out} is being built by another osmseg build (pid {holder} on "), line
    assert "with other options (differs in: seed)" in line and line.endswith("or use another --out"), line
    # the folder holds the winner's dataset, byte for byte, and says so
    assert tree_bytes(out) == references[winner]
    assert run_cli("verify", str(out)).exit_code == 0


def test_while_a_build_holds_its_folder_other_commands_refuse_at_once(tmp_path: Path, imagery_tif: Path) -> None:
    out = tmp_path / "ds"
    holder = popen("-q", *build_args(out, imagery_tif, "--workers", "1", samples=40))
    try:
        wait_for(lambda: slots_done(out) >= 4, holder)
        other = subprocess.run([sys.executable, "-m", "osmseg", "-q",
                                *build_args(out, imagery_tif, "--workers", "1", "--seed", "5", samples=40)],
                               capture_output=True, text=True, timeout=120)
        reader = subprocess.run([sys.executable, "-m", "osmseg", "verify", str(out)], capture_output=True, text=True,
                                timeout=120)
        assert holder.poll() is None, "the holder ended before the others were refused: they did not refuse at once"
    finally:
        holder.send_signal(signal.SIGINT)
        holder.communicate(timeout=60)
    assert other.returncode == 1 and other.stderr.count("\n") == 1, other.stderr
    assert f"is being built by another osmseg build (pid {holder.pid} on " in other.stderr
    assert "differs in: seed" in other.stderr
    assert reader.returncode == 1 and reader.stderr.count("\n") == 1, reader.stderr
    assert reader.stderr.startswith(f"Error: {out} is being built now (pid {holder.pid} on "), reader.stderr
    assert reader.stdout == ""


@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "kill -9"])
def test_a_killed_build_with_workers_leaves_nothing_behind_once_rerun(
        tmp_path: Path, imagery_tif: Path, one_worker: dict[str, bytes], stop: signal.Signals) -> None:
    out = tmp_path / "ds"
    tmpdir = Path(tempfile.mkdtemp(prefix="t", dir="/tmp"))  # short: the fork server's socket is named in it
    proc = popen(*build_args(out, imagery_tif, "--workers", "2"), tmpdir=tmpdir)
    wait_for(lambda: slots_done(out) >= 1, proc)
    workers = descendants(proc.pid)
    proc.send_signal(stop)
    _, stderr = proc.communicate(timeout=60)
    assert wait_gone(workers), "workers outlived their stopped build"
    assert "leaked semaphore" not in stderr.decode() and "Traceback" not in stderr.decode(), stderr.decode()
    if stop == signal.SIGTERM:  # unwound: one line, exit 143, its temporary files removed by itself
        assert proc.returncode == 143 and stderr.decode() == TERMINATED + "\n", stderr.decode()
        assert temporary_names(out) == [] and list(tmpdir.iterdir()) == []
    assert not (out / "manifest.json").exists(), "the build finished before it could be stopped"

    rerun = subprocess.run([sys.executable, "-m", "osmseg", "-q", *build_args(out, imagery_tif, "--workers", "2")],
                           env=dict(os.environ, TMPDIR=str(tmpdir)), capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr
    assert "leaked semaphore" not in rerun.stderr
    assert list(tmpdir.iterdir()) == [], "the rerun left what the kill left in $TMPDIR"
    tmpdir.rmdir()
    assert temporary_names(out) == []
    assert tree_bytes(out) == one_worker


@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "kill -9"])
def test_a_kill_while_the_dataset_files_are_written_leaves_no_temporary_name_after_the_rerun(
        tmp_path: Path, imagery_tif: Path, one_worker: dict[str, bytes], stop: signal.Signals) -> None:
    out = tmp_path / "ds"
    assert run_cli(*build_args(out, imagery_tif, "--workers", "1")).exit_code == 0
    (out / "manifest.json").unlink()  # every slot is done: a rerun only writes the dataset-level files
    shutil.rmtree(out / "stac")
    proc = popen("-q", *build_args(out, imagery_tif, "--workers", "1"))
    wait_for(lambda: any((out / ".osmseg-build").glob("entries-*")), proc)
    proc.send_signal(stop)
    _, stderr = proc.communicate(timeout=60)
    if stop == signal.SIGTERM:
        assert proc.returncode == 143 and stderr.decode() == TERMINATED + "\n", stderr.decode()
        assert temporary_names(out) == [], "the terminated build left temporary files"
    # what a kill at a worse moment leaves (names of a process that is gone) in every folder
    gone = f"{owner().rsplit('-', 1)[0]}-{dead_pid()}"
    for folder in ("stac/items", "stac", ".", "geo", ".osmseg-build/slots", ".osmseg-build"):
        (out / folder).mkdir(parents=True, exist_ok=True)
        (out / folder / f".x.json.{gone}.abc123.tmp").write_text("half")
    (out / ".osmseg-build" / f"entries-{gone}-abc123").mkdir()
    (out / ".osmseg-build" / f"entries-{gone}-abc123" / "samples.jsonl").write_text("{")

    result = run_cli(*build_args(out, imagery_tif, "--workers", "1"))
    assert result.exit_code == 0, result.output
    assert temporary_names(out) == []
    assert tree_bytes(out) == one_worker


def test_an_output_folder_deleted_while_its_build_runs_is_said_to_be_deleted(tmp_path: Path,
                                                                           imagery_tif: Path) -> None:
    out = tmp_path / "ds"
    proc = popen("-q", *build_args(out, imagery_tif, "--workers", "1", samples=60))
    wait_for(lambda: slots_done(out) >= 2, proc)
    shutil.rmtree(out)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 1, stderr.decode()
    line = stderr.decode().strip()
    assert line == (f"Error: {out} was deleted while this build ran (its build state is gone): run the same "
                    "command again to build it anew"), line


@pytest.mark.parametrize("delay", [0.3, 0.8, 1.0, 1.2, 2.0])
def test_ctrl_c_or_sigterm_at_any_moment_of_the_start_says_one_line(tmp_path: Path, imagery_tif: Path,
                                                                     delay: float) -> None:
    """From the executable's first imports to the building of samples: always the line and the status."""
    for stop, status, line in ((signal.SIGINT, 130, INTERRUPTED), (signal.SIGTERM, 143, TERMINATED)):
        out = tmp_path / f"ds-{stop.name}"
        proc = subprocess.Popen([sys.executable, "-m", "osmseg",
                                 *build_args(out, imagery_tif, "--workers", "2", samples=200)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        time.sleep(delay)
        assert proc.poll() is None, "the build ended before it could be stopped"
        os.killpg(proc.pid, stop) if stop == signal.SIGINT else proc.send_signal(stop)  # as a terminal / kill does
        _, stderr = proc.communicate(timeout=60)
        assert (proc.returncode, stderr.decode()) == (status, line + "\n"), (delay, stop.name)
