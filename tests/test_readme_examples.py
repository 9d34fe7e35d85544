"""The README's ``osmseg build`` examples, run the way a user runs them.

Each example is read out of README.md itself (so the README cannot drift from what is tested),
made runnable here (the shared real data's path for ``/data/...``, a temporary ``--out`` and
``--cache-dir``), and then run three ways:

1. as written, to the end;
2. again into the same folder: exit 0, nothing changes (a finished build is its own resume);
3. in a separate process killed with SIGKILL after its first finished sample, then rerun: the
   folder ends byte-identical to the uninterrupted build.

Examples that need the network (Bing, the OSM API, a tile server) cannot run here. For them the
test runs the same kind of area offline against an empty cache: one ``Error:`` line, exit 1,
and the folder it leaves is accepted by the corrected command. The ``--city`` kind is run for
real through the demo's recorded traffic (Bing and OSM API wire formats).
"""

from __future__ import annotations

import json
import os
import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from click.testing import CliRunner, Result

from osmseg.cli.main import cli

from conftest import REPO_ROOT, SHARED_DATA

README = REPO_ROOT / "README.md"
DEMO_CASSETTE = REPO_ROOT / "osmseg" / "demo" / "helsinki.yaml.gz"
DEMO_ENV = {"BING_MAPS_KEY": "demo-key-not-secret"}
#: README examples that name a network source: they are checked offline (see the module doc)
NETWORK = re.compile(r"--city|--imagery (bing|[A-Z][A-Za-z]+\.[A-Za-z0-9_.]+)\b|--osm (api|overpass)\b")


def readme_commands(prefix: str = "osmseg build") -> list[str]:
    """Every shell command in README.md's ``sh`` blocks that starts with ``prefix`` (continuations joined)."""
    text = README.read_text(encoding="utf-8")
    commands = []
    for block in re.findall(r"```sh\n(.*?)```", text, flags=re.S):
        joined = re.sub(r"\\\n\s*", " ", block)
        for line in joined.splitlines():
            line = line.split(" #")[0].strip()
            if line.startswith(prefix):
                commands.append(line)
    return commands


def runnable(command: str, out: Path) -> list[str]:
    """``command``'s arguments (after ``osmseg``) with ``/data/`` paths, ``--out`` and the cache made local."""
    args = shlex.split(command)[1:]
    args = [a.replace("/data/", f"{SHARED_DATA}/") for a in args]
    if "--out" in args:
        args[args.index("--out") + 1] = str(out)
    else:
        args += ["--out", str(out)]
    return [*args, "--cache-dir", str(out.parent / "cache")]


def tree_bytes(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` except the resumable-state folder, by relative path."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and ".osmseg-build" not in p.parts}


def run(args: list[str], env: dict[str, str] | None = None) -> Result:
    return CliRunner().invoke(cli, ["-q", *args], env=env)


def kill_after_first_sample(args: list[str], out: Path, env: dict[str, str] | None = None) -> None:
    """Start ``osmseg build ARGS`` in a process and SIGKILL it once a slot has finished."""
    proc = subprocess.Popen([sys.executable, "-m", "osmseg", "-q", *args], env={**os.environ, **(env or {})},
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    slots = out / ".osmseg-build" / "slots"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None and not any(slots.glob("*.json")):
        time.sleep(0.005)
    if proc.poll() is not None:
        pytest.fail(f"the build ended before it could be killed: {proc.communicate()[1].decode()[-500:]}")
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (out / "manifest.json").exists(), "the build finished before it could be killed"


def check_three_ways(args_for: "callable", tmp_path: Path, env: dict[str, str] | None = None) -> dict[str, bytes]:
    """Run whole, rerun into the same folder, kill and resume (see the module doc); the whole build's files."""
    whole_out = tmp_path / "whole" / "ds"
    first = run(args_for(whole_out), env)
    assert first.exit_code == 0, first.output
    whole = tree_bytes(whole_out)
    assert "manifest.json" in whole

    again = run(args_for(whole_out), env)
    assert again.exit_code == 0, again.output
    assert tree_bytes(whole_out) == whole

    killed_out = tmp_path / "killed" / "ds"
    kill_after_first_sample(args_for(killed_out), killed_out, env)
    resumed = run(args_for(killed_out), env)
    assert resumed.exit_code == 0, resumed.output
    assert tree_bytes(killed_out) == whole
    return whole


def test_the_readme_has_build_examples_of_every_kind_of_area() -> None:
    commands = readme_commands()
    assert any("--bbox" in c for c in commands) and any("--city" in c for c in commands)
    offline = [c for c in commands if not NETWORK.search(c)]
    assert offline, "no README build example runs without the network"


@pytest.mark.parametrize("command", [c for c in readme_commands() if not NETWORK.search(c)])
def test_readme_example_reruns_resumes_and_gives_identical_bytes(command: str, tmp_path: Path) -> None:
    if "/data/" in command and not SHARED_DATA.exists():
        pytest.skip(f"the example reads real data: {SHARED_DATA} is absent on this machine")
    whole = check_three_ways(lambda out: runnable(command, out), tmp_path)
    manifest = json.loads(whole["manifest.json"])
    assert manifest["summary"]["accepted"] >= 1


@pytest.mark.parametrize("command", [c for c in readme_commands() if NETWORK.search(c)])
def test_readme_network_example_fails_offline_in_one_line_and_leaves_a_usable_folder(
        command: str, tmp_path: Path) -> None:
    out = tmp_path / "ds"
    args = runnable(command, out)
    env = {"BING_MAPS_KEY": "not-a-real-key"}
    failed = run([*args, "--offline"], env)
    assert failed.exit_code in (1, 2), failed.output
    message = failed.output.strip()
    assert message.startswith(("Error:", "Usage:")) and "Traceback" not in failed.output, message
    # the corrected command (other imagery) is not refused by what the failure left behind
    corrected = [a for a in args]
    if "--imagery" in corrected:
        corrected[corrected.index("--imagery") + 1] = "xyz:https://tiles.example.org/{z}/{x}/{y}.png"
    else:
        corrected += ["--imagery", "xyz:https://tiles.example.org/{z}/{x}/{y}.png"]
    again = run([*corrected, "--offline"], env)
    assert "different build" not in again.output, again.output
    assert again.exit_code == 1 and "--offline" in again.output, again.output


def test_a_city_build_reruns_resumes_and_gives_identical_bytes(tmp_path: Path) -> None:
    """``--city``: the demo's Helsinki build, Bing and OSM API traffic replayed from its recording."""
    def args(out: Path) -> list[str]:
        return ["build", "--city", "Helsinki", "--samples", "4", "--seed", "0", "--imagery", "bing", "--osm", "api",
                "--no-overlap",
                "--replay", str(DEMO_CASSETTE), "--out", str(out), "--cache-dir", str(out.parent / "cache")]

    whole = check_three_ways(args, tmp_path, DEMO_ENV)
    assert json.loads(whole["manifest.json"])["area"]["name"] == "Helsinki"


@pytest.mark.parametrize("given", [[], ["--imagery", "bing"]])
def test_without_a_bing_key_the_error_prints_a_complete_command_that_works(
        given: list[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Bing Basic keys no longer exist: the error rewrites the user's command to a keyless provider."""
    monkeypatch.delenv("BING_MAPS_KEY", raising=False)
    monkeypatch.chdir(tmp_path)
    refused = CliRunner().invoke(cli, ["build", "--city", "Berlin", "--samples", "30", "--zoom", "18", *given,
                                       "--out", "data/berlin"])
    assert refused.exit_code == 2, refused.output
    error = next(line for line in refused.output.splitlines() if line.startswith("Error:"))
    assert "BING_MAPS_KEY" in error and "no longer exist" in error
    suggested = shlex.split(error.split("run instead: ", 1)[1].split("  (", 1)[0])
    assert suggested[:2] == ["osmseg", "build"] and "--imagery" in suggested
    assert suggested[suggested.index("--samples") + 1] == "30" and "Berlin" in suggested  # the user's own options
    assert not (tmp_path / "data").exists()
    # the suggested command passes every check and goes on to fetch (here: offline, empty cache)
    ran = CliRunner().invoke(cli, [*suggested[1:], "--offline", "--cache-dir", str(tmp_path / "cache")])
    assert ran.exit_code == 1 and "--offline" in ran.output, ran.output
