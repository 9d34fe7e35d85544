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
import threading
import time
from pathlib import Path

import pytest
from test_build_workers import build_args, descendants, one_worker, run_cli, tree_bytes, wait_gone  # noqa: F401

from osmseg.errors import DatasetBusy, DatasetError
from osmseg.runtime.processes import INTERRUPTED, TERMINATED, owner
from training.datasets.splits import sample_groups

#: Starts ``osmseg ARGS`` at a common instant: once its imports are done it says so (a file
#: ``READY_DIR/ready-PID``), then waits for ``READY_DIR/go`` to name the instant, and busy-waits
#: for it: two of them begin within a millisecond of each other, however loaded the machine.
STARTER = """
import os, sys, time
from pathlib import Path
import osmseg.cli.main, osmseg.builder.run  # everything imported before the common start
folder = Path(sys.argv[1])
sys.argv = ["osmseg", *sys.argv[2:]]
(folder / f"ready-{os.getpid()}").touch()
while not (folder / "go").exists():
    time.sleep(0.001)
start = float((folder / "go").read_text())
while time.time() < start:
    pass
from osmseg.cli.launch import main
main()
"""


def start_together(procs: list[subprocess.Popen[bytes]], folder: Path) -> None:
    """Let processes started with ``start_at=folder`` go at one instant, once all are ready."""
    deadline = time.monotonic() + 300
    while len(list(folder.glob("ready-*"))) < len(procs):
        assert time.monotonic() < deadline and all(p.poll() is None for p in procs), "a starter did not get ready"
        time.sleep(0.01)
    (folder / "go.tmp").write_text(repr(time.time() + 0.2))
    (folder / "go.tmp").rename(folder / "go")


def popen(*args: str, tmpdir: Path | None = None, start_at: Path | None = None) -> subprocess.Popen[bytes]:
    env = dict(os.environ)
    if tmpdir is not None:
        env["TMPDIR"] = str(tmpdir)
    command = ([sys.executable, "-c", STARTER, str(start_at)] if start_at is not None
               else [sys.executable, "-m", "osmseg"])
    return subprocess.Popen([*command, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def after_progress(stderr: str) -> str:
    """What a stopped build said after the progress lines a log gets (stderr a pipe: ``build: 3/6
    samples ...``), which must be all it said before."""
    *progress, last = stderr.splitlines() or [""]
    assert all(line.startswith("build: ") for line in progress), stderr
    return last + "\n"


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


# one start in make test, eleven more in make test-slow (a race: the more starts, the likelier it shows)
@pytest.mark.parametrize("attempt", [0, *(pytest.param(i, marks=pytest.mark.slow) for i in range(1, 12))])
def test_two_builds_with_other_options_started_in_the_same_millisecond_one_owns_the_folder(
        tmp_path: Path, imagery_tif: Path, references: dict[str, dict[str, bytes]], attempt: int) -> None:
    out, barrier = tmp_path / "ds", tmp_path / "barrier"
    barrier.mkdir()
    procs = {seed: popen("-q", *build_args(out, imagery_tif, "--workers", "2", "--seed", seed, samples=4),
                         start_at=barrier) for seed in ("3", "4")}
    start_together(list(procs.values()), barrier)
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
        wait_for(lambda: slots_done(out) >= 1, holder)
        holder.send_signal(signal.SIGSTOP)  # frozen, holding the folder: however slow the others start
        other = subprocess.run([sys.executable, "-m", "osmseg", "-q",
                                *build_args(out, imagery_tif, "--workers", "1", "--seed", "5", samples=40)],
                               capture_output=True, text=True, timeout=120)
        reader = subprocess.run([sys.executable, "-m", "osmseg", "verify", str(out)], capture_output=True, text=True,
                                timeout=120)
        # a reader that falls back when a manifest is unusable (training's spatial groups) must not fall
        # back on a busy one: splits drawn without the groups would leak between train and test
        (out / "manifest.json").write_text("{}")  # (as a finished earlier build would have left)
        busy_reads = []
        try:
            sample_groups(out, ["a"])
            busy_reads.append("sample_groups read a busy folder")
        except DatasetBusy:
            pass
        assert holder.poll() is None, "the holder ended before the others were refused: they did not refuse at once"
    finally:
        holder.send_signal(signal.SIGCONT)
        holder.send_signal(signal.SIGINT)
        holder.communicate(timeout=60)
    assert other.returncode == 1 and other.stderr.count("\n") == 1, other.stderr
    assert f"is being built by another osmseg build (pid {holder.pid} on " in other.stderr
    assert "differs in: seed" in other.stderr
    assert reader.returncode == 1 and reader.stderr.count("\n") == 1, reader.stderr
    assert reader.stderr.startswith(f"Error: {out} is being built now (pid {holder.pid} on "), reader.stderr
    assert reader.stdout == ""
    assert not busy_reads, busy_reads


def test_a_build_reads_the_folder_it_holds_itself(tmp_path: Path) -> None:
    """Only other processes' builds make a folder busy: the process holding it may read it."""
    from osmseg.builder.state import BuildState
    from osmseg.output.manifest import read_manifest

    (tmp_path / "manifest.json").write_text("{}")
    state = BuildState(tmp_path)
    state.claim({"seed": 1}, "osmseg build --seed 1")
    try:
        with pytest.raises(DatasetError, match="manifest.json"):  # read (and found invalid), not refused as busy
            read_manifest(tmp_path)
    finally:
        state.release()


@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "kill -9"])
def test_a_killed_build_with_workers_leaves_nothing_behind_once_rerun(
        tmp_path: Path, imagery_tif: Path, one_worker: dict[str, bytes], stop: signal.Signals) -> None:
    out = tmp_path / "ds"
    # as long a $TMPDIR as a private folder with the fork server's socket inside still fits (40 characters,
    # a Slurm job's scratch folder): the run's folder is then made, and swept after a kill -9
    tmpdir = Path(tempfile.mkdtemp(prefix="osmseg-test-job-scratch-", dir="/tmp"))
    assert len(str(tmpdir)) >= 37
    proc = popen(*build_args(out, imagery_tif, "--workers", "2"), tmpdir=tmpdir)
    wait_for(lambda: slots_done(out) >= 1, proc)
    workers = descendants(proc.pid)
    proc.send_signal(stop)
    _, stderr = proc.communicate(timeout=60)
    assert wait_gone(workers), "workers outlived their stopped build"
    assert "leaked semaphore" not in stderr.decode() and "Traceback" not in stderr.decode(), stderr.decode()
    if stop == signal.SIGTERM:  # unwound: one line, exit 143, its temporary files removed by itself
        assert proc.returncode == 143 and after_progress(stderr.decode()) == TERMINATED + "\n", stderr.decode()
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
    for entries in (f"entries-{gone}-abc123", "entries-k3j9x_2q"):  # (the second: osmseg < 0.4 named no owner)
        (out / ".osmseg-build" / entries).mkdir()
        (out / ".osmseg-build" / entries / "samples.jsonl").write_text("{")
    # the output folder may be the user's: files osmseg did not name are theirs, wherever they are
    users = [out / ".notes.tmp", out / "mine" / ".draft.v2.tmp", out / "mine" / ".x.json.abc.def.tmp"]
    for path in users:
        path.parent.mkdir(exist_ok=True)
        path.write_text("the user's")

    result = run_cli(*build_args(out, imagery_tif, "--workers", "1"))
    assert result.exit_code == 0, result.output
    assert [p for p in temporary_names(out) if not p.startswith(("mine", ".notes"))] == []
    assert all(path.read_text() == "the user's" for path in users)
    for path in users:
        path.unlink()
    (out / "mine").rmdir()
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


@pytest.mark.parametrize("delay", [0.0, 0.3, 0.8, 1.2, 2.0])
def test_ctrl_c_or_sigterm_at_any_moment_of_the_start_says_one_line(tmp_path: Path, imagery_tif: Path,
                                                                     delay: float) -> None:
    """From the executable's first act to the building of samples (``delay`` seconds after it handles
    SIGTERM: the imports, the fork server, the workers' start): always the line and the status."""
    for stop, status, line in ((signal.SIGINT, 130, INTERRUPTED), (signal.SIGTERM, 143, TERMINATED)):
        out = tmp_path / f"ds-{stop.name}"
        proc = subprocess.Popen([sys.executable, "-m", "osmseg",
                                 *build_args(out, imagery_tif, "--workers", "2", samples=200)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        caught = 1 << (signal.SIGTERM - 1)  # from the moment the executable handles SIGTERM (its first act)
        deadline = time.monotonic() + 60
        while proc.poll() is None and time.monotonic() < deadline:
            info = Path(f"/proc/{proc.pid}/status").read_text() if Path(f"/proc/{proc.pid}").exists() else ""
            if int(next((line.split()[1] for line in info.splitlines() if line.startswith("SigCgt:")), "0"), 16) & caught:
                break
            time.sleep(0.001)
        time.sleep(delay)
        assert proc.poll() is None, "the build ended before it could be stopped"
        seen = signal_state(proc.pid)  # what the executable did with the signal the moment it was sent
        os.killpg(proc.pid, stop) if stop == signal.SIGINT else proc.send_signal(stop)  # as a terminal / kill does
        _, stderr = proc.communicate(timeout=60)
        said = stderr.decode()
        assert proc.returncode == status, (delay, stop.name, proc.returncode, seen, said[-1500:])
        assert after_progress(said) == line + "\n", (delay, stop.name, seen)


def signal_state(pid: int) -> str:
    """The signal masks of process ``pid`` and its threads (``/proc``): which signals its threads block,
    which the process ignores and catches, for the message of a stop that went unheard."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
        threads = [(task.name, (task / "comm").read_text().strip(),
                    next(x.split()[1] for x in (task / "status").read_text().splitlines() if x.startswith("SigBlk:")))
                   for task in Path(f"/proc/{pid}/task").iterdir()]
    except (OSError, StopIteration):
        return "gone"
    fields = [x for x in status.splitlines() if x.startswith(("SigPnd", "ShdPnd", "SigIgn", "SigCgt"))]
    return "; ".join(fields) + f"; threads (id, name, SigBlk): {threads}"


def test_a_run_sweeps_the_temporary_folders_of_ended_runs_only(tmp_path: Path) -> None:
    """A run's folder in $TMPDIR is its while it holds its lock, however old and whoever's (another
    container sharing /tmp); once the run has ended, any osmseg command removes it."""
    tmpdir = Path(tempfile.mkdtemp(prefix="t", dir="/tmp"))
    live, ended = tmpdir / "osmseg-run-livelive", tmpdir / "osmseg-run-endedabc"
    for folder in (live, ended):
        folder.mkdir()
        (folder / "lock").touch()
        (folder / "pymp-x").mkdir()
    holder = subprocess.Popen([sys.executable, "-c", "import fcntl, os, sys, time; "
                               f"fd = os.open({str(live / 'lock')!r}, os.O_RDWR); fcntl.flock(fd, fcntl.LOCK_SH); "
                               "print('held', flush=True); time.sleep(60)"], stdout=subprocess.PIPE)
    try:
        assert holder.stdout is not None and holder.stdout.readline() == b"held\n"
        for folder in (live, ended):
            os.utime(folder, (time.time() - 86400, time.time() - 86400))  # a day old
        run = subprocess.run([sys.executable, "-m", "osmseg", "--version"], env=dict(os.environ, TMPDIR=str(tmpdir)),
                             capture_output=True, text=True, timeout=60)
        assert run.returncode == 0, run.stderr
        assert sorted(p.name for p in tmpdir.iterdir()) == [live.name]
    finally:
        holder.kill()
        holder.wait()
    shutil.rmtree(tmpdir)


#: A run stopped by the scheduler between making its lock file and locking it (flock held back
#: until the file named in argv[1] exists); then it says whether its folder is still there.
STARTS_SLOWLY = """
import fcntl, os, sys, time
from pathlib import Path
real = fcntl.flock
def held_back(fd, op):
    if op == fcntl.LOCK_SH:
        print("made", flush=True)
        while not Path(sys.argv[1]).exists():
            time.sleep(0.01)
    return real(fd, op)
fcntl.flock = held_back
from osmseg.runtime.processes import use_private_temp_dir
private = use_private_temp_dir()
print(private is not None and os.path.isdir(private), flush=True)
"""


def test_a_run_starting_while_another_sweeps_keeps_its_folder(tmp_path: Path) -> None:
    """Each run sweeps the folders of ended runs as it starts. A run caught between making its
    folder's lock file and locking it is alive: the sweep of a run starting that instant keeps it."""
    tmpdir = Path(tempfile.mkdtemp(prefix="t", dir="/tmp"))
    go = tmp_path / "go"
    env = dict(os.environ, TMPDIR=str(tmpdir))
    slow = subprocess.Popen([sys.executable, "-c", STARTS_SLOWLY, str(go)], stdout=subprocess.PIPE, env=env)
    try:
        assert slow.stdout is not None and slow.stdout.readline() == b"made\n"
        run = subprocess.run([sys.executable, "-m", "osmseg", "--version"], env=env, capture_output=True, text=True,
                             timeout=60)
        assert run.returncode == 0, run.stderr
        go.touch()
        assert slow.stdout.readline() == b"True\n"   # its folder outlived the other run's sweep
    finally:
        go.touch()
        slow.kill()
        slow.wait()
        shutil.rmtree(tmpdir)


#: A signal whose handler runs inside a finalizer (here a ``__del__``), where Python drops its exception.
STOP_IN_A_FINALIZER = """
import os, signal, sys, time
from osmseg.runtime.processes import Terminated, terminate_by_exception
# a Ctrl-C as a command in a terminal gets it, whatever this test's process passed on: a SIGINT it
# ignored or held blocked is inherited across exec (once, in the parallel suite, this child
# never saw its own SIGINT and "went on")
signal.signal(signal.SIGINT, signal.default_int_handler)
signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
terminate_by_exception()
stop = {"SIGINT": signal.SIGINT, "SIGTERM": signal.SIGTERM}[sys.argv[1]]

class Finalized:
    def __del__(self):
        os.kill(os.getpid(), stop)  # the handler runs before os.kill returns: inside __del__

try:
    Finalized()
    for _ in range(200):
        time.sleep(0.01)
    print("went on")
except (KeyboardInterrupt, Terminated) as stopped:
    print(type(stopped).__name__)
"""


def test_a_ctrl_c_or_sigterm_whose_handler_runs_in_a_finalizer_still_stops_the_command() -> None:
    """What CI hit: a SIGTERM whose handler ran in a weakref callback during training was printed as
    "Exception ignored" and dropped, and the run went on to its last epoch and exited 0."""
    for stop, raised in (("SIGTERM", "Terminated"), ("SIGINT", "KeyboardInterrupt")):
        run = subprocess.run([sys.executable, "-c", STOP_IN_A_FINALIZER, stop], capture_output=True, text=True,
                             timeout=60, cwd=Path(__file__).resolve().parents[2])
        assert (run.stdout, run.stderr) == (raised + "\n", "")


def test_a_ctrl_c_or_sigterm_while_signals_are_held_arrives_as_the_block_ends() -> None:
    """What the command line's imports run under (the exit status of a Ctrl-C in a compiled
    module's start, above): the signal is neither lost nor delivered inside the block."""
    from osmseg.runtime.processes import Terminated, signals_held, terminate_by_exception

    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    terminate_by_exception()
    signal.signal(signal.SIGINT, signal.default_int_handler)  # as the command line starts, whatever ran here before
    try:
        for stop, raised in ((signal.SIGINT, KeyboardInterrupt), (signal.SIGTERM, Terminated)):
            inside = []
            with pytest.raises(raised):
                with signals_held():
                    signal.pthread_kill(threading.main_thread().ident, stop)  # the only thread while the command line imports
                    time.sleep(0.05)  # a pending signal would have run its handler by now
                    inside.append(stop)
                for _ in range(1000):  # Python runs a handler between bytecodes: the next ones after the block
                    pass
            assert inside == [stop]
    finally:
        signal.signal(signal.SIGTERM, before[0])
        signal.signal(signal.SIGINT, before[1])


ORPHAN = r"""
import sys, threading, time
from pathlib import Path
from osmseg.builder.workers import _die_with_build
from osmseg.output.atomic import atomic_path

_die_with_build(int(sys.argv[1]))  # as a build worker does in its initializer
with atomic_path(Path(sys.argv[2]) / "bbox_00000.png") as tmp:
    tmp.write_bytes(b"\x89PNG half a sample")
    print(tmp, flush=True)
    time.sleep(60)  # still writing when its build is killed
"""


def test_a_worker_whose_build_is_killed_takes_its_half_written_file_with_it(tmp_path: Path) -> None:
    """``kill -9`` of a build: its workers end at once (they watch the build's pid) and remove the
    files they were writing, so a resumed build that swept the folder while they still lived (and
    kept their files, as a live writer's) is not left with their litter (was: a
    ``images/.bbox_00000.png.HOST-PID.*.tmp`` in the resumed dataset, now and then under load)."""
    build = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    images = tmp_path / "images"
    images.mkdir()
    worker = subprocess.Popen([sys.executable, "-c", ORPHAN, str(build.pid), str(images)], stdout=subprocess.PIPE,
                              text=True)
    try:
        half = Path(worker.stdout.readline().strip())  # type: ignore[union-attr]
        assert half.is_file() and half.name.startswith(".bbox_00000.png.") and half.suffix == ".tmp"
        build.kill()
        build.wait()
        assert worker.wait(timeout=30) == 1  # os._exit(1): the worker ended with its build
        assert sorted(p.name for p in images.iterdir()) == []  # and took its half-written file with it
    finally:
        for proc in (build, worker):
            proc.kill()
            proc.wait()


@pytest.mark.parametrize("workers", ["1", "2"])
def test_a_build_started_with_stops_blocked_still_hears_them(tmp_path: Path, imagery_tif: Path, workers: str) -> None:
    """A process that starts ``osmseg`` from inside its own blocked section passes the blocked mask on
    across ``exec``: the command line unblocks Ctrl-C and SIGTERM, or the build would go on to its
    end whatever the user pressed (one worker: nothing else unblocks them)."""
    for stop, status, line in ((signal.SIGINT, 130, INTERRUPTED), (signal.SIGTERM, 143, TERMINATED)):
        out = tmp_path / f"ds-{stop.name}"
        proc = subprocess.Popen([sys.executable, "-m", "osmseg",
                                 *build_args(out, imagery_tif, "--workers", workers, samples=200)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
                                preexec_fn=lambda: (signal.signal(signal.SIGINT, signal.SIG_DFL),
                                                    signal.pthread_sigmask(signal.SIG_BLOCK,
                                                                           {signal.SIGINT, signal.SIGTERM})))
        wait_for(lambda: slots_done(out) >= 2, proc)  # building samples
        os.killpg(proc.pid, stop) if stop == signal.SIGINT else proc.send_signal(stop)
        _, stderr = proc.communicate(timeout=120)
        assert (proc.returncode, after_progress(stderr.decode())) == (status, line + "\n"), stop.name
