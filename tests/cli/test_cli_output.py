"""What the commands print where, as a user's terminal and a user's log file see it.

* Progress bars are drawn only when stderr is a terminal (a pseudo-terminal here); a log (stderr
  a file or a pipe) gets plain lines instead, never a ``\\r`` frame, even with ``--progress``: a
  line per tenth of a task or per minute, and one per epoch of training with its losses,
  validation mIoU and time, for ``build``, ``train``, ``eval``, ``predict`` and
  ``localize-bench`` alike. ``--no-progress`` and ``-q`` silence both.
* Usage errors exit 2 with one ``Error:`` line, failures exit 1.
"""

from __future__ import annotations

import csv
import os
import pty
import re
import select
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner
from conftest import TEST_DATA

from osmseg.cli.main import cli
from osmseg.runtime.progress import Step

TINYCITY = TEST_DATA / "tinycity" / "tinycity.osm"
TINYSEG = TEST_DATA / "tinyseg"


def osmseg_process(args: list[str], tty: bool = False, timeout: float = 240, log: Path | None = None
                   ) -> tuple[int, bytes]:
    """Run ``python -m osmseg ARGS``; stderr a pipe, the file ``log``, or a pseudo-terminal with
    ``tty``. (exit, stderr)."""
    env = dict(os.environ, OMP_NUM_THREADS="1", COLUMNS="100")
    if log is not None:
        with log.open("wb") as file:
            code = subprocess.run([sys.executable, "-m", "osmseg", *args], env=env, stdout=subprocess.DEVNULL,
                                  stderr=file, timeout=timeout).returncode
        return code, log.read_bytes()
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
    # a terminal sees the bar; --no-progress silences it; --progress into a file gives lines, not frames
    code, err = osmseg_process(build_args(tmp_path / "tty"), tty=True)
    assert code == 0 and b"\r" in err and b"sample" in err, err[-500:]
    code, err = osmseg_process(["--no-progress", *build_args(tmp_path / "quiet")], tty=True)
    assert code == 0 and b"\r" not in err.replace(b"\r\n", b"\n"), err[-500:]
    code, err = osmseg_process(["--progress", *build_args(tmp_path / "asked")], log=tmp_path / "asked.log")
    assert code == 0 and b"\r" not in err and b"build: 2/2 samples (100%)" in err, err[-500:]


def test_a_build_in_a_log_says_how_far_it_got_in_plain_lines(tmp_path: Path) -> None:
    """Off a terminal a build reports its samples as lines (here each of 2 passes a tenth), then
    its summary; --no-progress keeps the summary only, -q prints nothing."""
    code, err = osmseg_process(build_args(tmp_path / "ds"), log=tmp_path / "build.log")
    assert code == 0, err.decode()[-800:]
    lines = err.decode().splitlines()
    progress = [line for line in lines if line.startswith("build: ")]
    assert [line.split(" in ")[0] for line in progress] == ["build: 1/2 samples (50%)", "build: 2/2 samples (100%)"]
    summary = next(i for i, line in enumerate(lines) if line.startswith("accepted 2 samples"))
    assert "; accepted 2" in progress[-1] and lines.index(progress[-1]) < summary
    code, err = osmseg_process(["--no-progress", *build_args(tmp_path / "quiet")], log=tmp_path / "quiet.log")
    assert code == 0 and b"build: " not in err and b"accepted 2 samples" in err, err[-500:]
    code, err = osmseg_process([*build_args(tmp_path / "hushed"), "-q"], log=tmp_path / "hushed.log")
    assert (code, err) == (0, b"")


def test_a_rerun_build_says_it_had_nothing_to_do_and_counts_agree_with_their_nouns(tmp_path: Path) -> None:
    """A finished build run again says first that every sample was already built, then its usual
    summary (before, only the summary, as if it had built them); -q still prints nothing. A build
    of one sample says "accepted 1 sample" (it said "accepted 1 samples")."""
    args = ["--no-progress", *build_args(tmp_path / "ds")]
    first = osmseg_process(args, log=tmp_path / "first.log")[1].decode().splitlines()
    assert first[0].startswith("accepted 2 samples; rejected ") and not any("nothing to do" in x for x in first)
    code, err = osmseg_process(args, log=tmp_path / "again.log")
    again = err.decode().splitlines()
    assert code == 0 and again[0] == "nothing to do: every sample was already built", again
    assert again[1] == first[0] and again[2].startswith("time "), again
    assert osmseg_process([*args, "-q"], log=tmp_path / "hushed.log") == (0, b"")
    one = [*build_args(tmp_path / "one"), "--no-progress"]
    one[one.index("--samples") + 1] = "1"
    lines = osmseg_process(one, log=tmp_path / "one.log")[1].decode().splitlines()
    assert lines[0].startswith("accepted 1 sample; rejected "), lines


def test_a_log_rounds_its_percentages() -> None:
    """8 of 12 is 67 % (it said 66 %, floored); 100 % only at the end, 0 % only before the first."""
    from osmseg.cli.drawers import ProgressLines

    lines: list[str] = []
    draw = ProgressLines(lines.append, clock=lambda: 0.0)
    for done in range(13):
        draw(Step("build", done, 12, "sample"))
    said = [line.split(" in ")[0] for line in lines]
    assert "build: 8/12 samples (67%)" in said and "build: 11/12 samples (92%)" in said, said
    assert said[-1] == "build: 12/12 samples (100%)"
    lines.clear()
    for done in (0, 1, 199, 200):
        draw(Step("predict", done, 200, "window"))
    assert [line.split(" in ")[0] for line in lines] == ["predict: 199/200 windows (99%)",
                                                         "predict: 200/200 windows (100%)"], lines


def test_training_in_a_log_prints_one_line_per_epoch(tmp_path: Path) -> None:
    """Stderr a file, as ``make demo 2> log`` or a batch job: one line per epoch with the epoch,
    its training loss, validation loss and mIoU (those of log.csv) and its seconds; the batches
    of an epoch are its detail, shown only when a minute passes without a line."""
    run = tmp_path / "run"
    code, err = osmseg_process(["train", str(TINYSEG), "--out", str(run), "--config",
                                str(TEST_DATA / "train" / "tiny.yaml"), "--epochs", "2"], log=tmp_path / "train.log")
    assert code == 0, err.decode()[-800:]
    assert b"\r" not in err
    lines = err.decode().splitlines()
    epochs = [line for line in lines if line.startswith("train: ")]
    assert [line.split(" in ")[0] for line in epochs] == ["train: 1/2 epochs (50%)", "train: 2/2 epochs (100%)"]
    with (run / "log.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    for line, row in zip(epochs, rows):
        assert (f"train loss {float(row['train_loss']):.4g}, val loss {float(row['val_loss']):.4g}, "
                f"val mIoU {float(row['val_miou']):.4g}, epoch ") in line, line
        assert re.search(r", epoch [\d.,]+ s$", line), line
    assert all(" min " in line for line in lines if "batch" in line), "batches shown before a minute passed"
    assert lines[-2].startswith("final epoch 2: val mIoU ") and " best epoch " in lines[-2], lines
    assert lines[-1].startswith(f"use {run / 'model.pt'} "), lines


def test_a_log_gets_a_line_per_tenth_per_minute_and_per_result() -> None:
    """The cadence of :class:`ProgressLines`, on a clock the test turns: a task's tenths and its
    end; a task within another (an epoch's batches) only after a minute without a line; every
    step that carries values (an epoch's losses)."""
    from osmseg.cli.drawers import ProgressLines

    now = [0.0]
    lines: list[str] = []
    draw = ProgressLines(lines.append, clock=lambda: now[0])
    for done in range(0, 41):  # 40 samples, 2 s each: a line per 4 samples (a tenth)
        now[0] = 2.0 * done
        draw(Step("build", done, 40, "sample"))
    assert [line.split(" in ")[0] for line in lines] == [f"build: {4 * k}/40 samples ({10 * k}%)" for k in range(1, 11)]
    assert lines[0] == "build: 4/40 samples (10%) in 8 s, about 1 min 12 s left" and "left" not in lines[-1]
    lines.clear()
    draw(Step("train", 0, 2, "epoch"))
    for epoch in (1, 2):  # 100 batches of 1.5 s: 2.5 minutes an epoch
        for batch in range(0, 101):
            now[0] += 1.5
            draw(Step(f"epoch {epoch} train", batch, 100, "batch"))
        draw(Step("train", epoch, 2, "epoch", values=(("train loss", 0.5 / epoch), ("epoch seconds", 151.5))))
    said = [line.split(" in ")[0] for line in lines]
    assert said == ["epoch 1 train: 39/100 batches (39%)", "epoch 1 train: 79/100 batches (79%)",
                    "train: 1/2 epochs (50%)", "epoch 2 train: 39/100 batches (39%)",
                    "epoch 2 train: 79/100 batches (79%)", "train: 2/2 epochs (100%)"], lines
    assert lines[-1].endswith("; train loss 0.25, epoch 152 s")
    assert not any("\r" in line for line in lines)


@pytest.mark.slow  # make test-slow: three commands in processes; --progress into a pipe: the log-file test
def test_every_long_command_reports_its_steps_in_a_log_when_asked(tmp_path: Path, trained: Path) -> None:
    """The library reports steps through a callback; the command draws them: --progress into a
    pipe shows each command's own lines (tasks and units), and the summary still follows."""
    image = TINYSEG / "images" / "tinyseg_000.png"
    commands = {
        "train": (["train", str(TINYSEG), "--out", str(tmp_path / "run"), "--config",
                   str(TEST_DATA / "train" / "tiny.yaml"), "--epochs", "1"], [b"train: 1/1 epoch (100%)", b"val mIoU"]),
        "eval": (["eval", str(trained / "best.pt"), str(TINYSEG), "--out", str(tmp_path / "eval")],
                 [b"evaluate: ", b" images (100%)"]),
        "predict": (["predict", str(trained / "best.pt"), str(image), "--out", str(tmp_path / "pred")],
                    [b"predict: 1/1 image (100%)"]),
    }
    for name, (args, shown) in commands.items():
        code, err = osmseg_process(["--progress", *args])
        assert code == 0, (name, err.decode()[-800:])
        assert b"\r" not in err, (name, err[-500:])
        for text in shown:
            assert text in err, f"{name}: no {text!r} line in {err[-500:]!r}"


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
