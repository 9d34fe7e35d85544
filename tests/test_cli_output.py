"""What the commands print where, as a user's terminal and a user's log file see it.

* Progress bars are drawn only when stderr is a terminal (a pseudo-terminal here), or when
  asked with ``--progress``; a log file (stderr a pipe) gets no ``\\r`` frames, for ``build``,
  ``train``, ``eval`` and ``localize-bench`` alike. ``--no-progress`` silences a terminal.
* Usage errors exit 2 with one ``Error:`` line, failures exit 1.
"""

from __future__ import annotations

import os
import pty
import select
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner
from conftest import TEST_DATA

from osmseg.cli.main import cli

TINYCITY = TEST_DATA / "tinycity" / "tinycity.osm"
TINYSEG = TEST_DATA / "tinyseg"


def osmseg_process(args: list[str], tty: bool = False, timeout: float = 240) -> tuple[int, bytes]:
    """Run ``python -m osmseg ARGS``; stderr a pipe, or a pseudo-terminal with ``tty``. (exit, stderr)."""
    env = dict(os.environ, OMP_NUM_THREADS="1", COLUMNS="100")
    if not tty:
        proc = subprocess.run([sys.executable, "-m", "osmseg", *args], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE, timeout=timeout)
        return proc.returncode, proc.stderr
    leader, follower = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "osmseg", *args], env=env, stdout=subprocess.DEVNULL,
                            stderr=follower)
    os.close(follower)
    out = b""
    while True:
        ready, _, _ = select.select([leader], [], [], timeout)
        if not ready:
            proc.kill()
            break
        try:
            chunk = os.read(leader, 65536)
        except OSError:  # the child closed the terminal
            break
        if not chunk:
            break
        out += chunk
    os.close(leader)
    return proc.wait(timeout=timeout), out


def build_args(out: Path) -> list[str]:
    """A fast build: tinycity's OSM data, no imagery at all (an empty tile folder), filters open."""
    (out.parent / "no-tiles").mkdir(parents=True, exist_ok=True)
    return ["build", "--lat", "60.17", "--lon", "24.94", "--radius-km", "0.08", "--samples", "2", "--seed", "1",
            "--imagery", f"xyz:file://{out.parent}/no-tiles/{{z}}/{{x}}/{{y}}.png", "--osm", str(TINYCITY),
            "--max-missing-imagery", "1", "--max-placeholder-tiles", "25", "--min-contrast", "0",
            "--out", str(out), "--cache-dir", str(out.parent / "cache")]


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    run = tmp_path_factory.mktemp("progress") / "run"
    result = CliRunner().invoke(cli, ["-q", "train", str(TINYSEG), "--out", str(run), "--config",
                                      str(TEST_DATA / "train" / "tiny.yaml"), "--epochs", "1"])
    assert result.exit_code == 0, result.output
    return run


def test_a_log_file_gets_no_progress_frames_a_terminal_does(tmp_path: Path, trained: Path) -> None:
    commands = {
        "build": build_args(tmp_path / "ds"),
        "train": ["train", str(TINYSEG), "--out", str(tmp_path / "run"), "--config",
                  str(TEST_DATA / "train" / "tiny.yaml"), "--epochs", "1"],
        "eval": ["eval", str(trained / "best.pt"), str(TINYSEG), "--out", str(tmp_path / "eval")],
        "localize-bench": ["localize-bench", str(tmp_path / "ds"), "--viewpoints", "2", "--out", str(tmp_path / "bench")],
    }
    for name, args in commands.items():
        code, err = osmseg_process(args)
        assert code == 0, (name, err.decode()[-800:])
        assert b"\r" not in err, f"{name} drew progress frames into a pipe: {err[:300]!r}"
    # a terminal sees the bar; --no-progress silences it; --progress draws it into a pipe
    code, err = osmseg_process(build_args(tmp_path / "tty"), tty=True)
    assert code == 0 and b"\r" in err and b"sample" in err, err[-500:]
    code, err = osmseg_process(["--no-progress", *build_args(tmp_path / "quiet")], tty=True)
    assert code == 0 and b"\r" not in err.replace(b"\r\n", b"\n"), err[-500:]
    code, err = osmseg_process(["--progress", *build_args(tmp_path / "asked")])
    assert code == 0 and b"\r" in err, err[-500:]


@pytest.mark.slow  # make test-slow: three commands in processes; --progress into a pipe: the log-file test
def test_every_long_command_reports_its_steps_as_bars_when_asked(tmp_path: Path, trained: Path) -> None:
    """The library reports steps through a callback; the command draws them: --progress into a
    pipe shows each command's own bars (tasks and units), and the summary still follows."""
    image = TINYSEG / "images" / "tinyseg_000.png"
    commands = {
        "train": (["train", str(TINYSEG), "--out", str(tmp_path / "run"), "--config",
                   str(TEST_DATA / "train" / "tiny.yaml"), "--epochs", "1"], [b"epoch 1 train", b"batch", b"epoch"]),
        "eval": (["eval", str(trained / "best.pt"), str(TINYSEG), "--out", str(tmp_path / "eval")],
                 [b"evaluate", b"image"]),
        "predict": (["predict", str(trained / "best.pt"), str(image), "--out", str(tmp_path / "pred")],
                    [b"predict tinyseg_000", b"window"]),
    }
    for name, (args, shown) in commands.items():
        code, err = osmseg_process(["--progress", *args])
        assert code == 0, (name, err.decode()[-800:])
        for text in shown:
            assert text in err, f"{name}: no {text!r} bar in {err[-500:]!r}"


@pytest.mark.parametrize(("args", "says"), [
    (["eval", "CHECKPOINT", "--out", "e"], "give a DATASET folder or --pair"),
    (["build", "--city", "Berlin", "--out", "x", "--imagery", "xyz:https://t.example/{z}/{x}/{y}.png?key=${KEY}"],
     "{env:KEY}"),
])
def test_usage_errors_exit_2_with_one_error_line(args: list[str], says: str, tmp_path: Path, trained: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    args = [str(trained / "best.pt") if a == "CHECKPOINT" else a for a in args]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 2, result.output
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and says in errors[0], result.output
    assert "Traceback" not in result.output
    assert not any(tmp_path.iterdir()), "a refused command wrote something"
