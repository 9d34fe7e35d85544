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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click
import pytest
from click.testing import CliRunner, Result
from conftest import REPO_ROOT, SHARED_DATA

from osmseg.cli.main import cli

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


def check_three_ways(args_for: callable, tmp_path: Path, env: dict[str, str] | None = None) -> dict[str, bytes]:
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


# ------------------------------------------------------------------------------ every example, as printed

DOCS = [README, *sorted((REPO_ROOT / "docs").glob("*.md"))]


def example_commands(path: Path) -> list[list[str]]:
    """The arguments (after ``osmseg``) of every osmseg command in ``path``'s code blocks: the
    lines of ``sh`` blocks, and ``$ osmseg`` lines of the others (continuations joined, comments
    cut; ``torchrun ... -m osmseg`` counts). Lines with a ``...`` placeholder are left out."""
    text = path.read_text(encoding="utf-8")
    commands = []
    for lang, block in re.findall(r"```(\w*)\n(.*?)```", text, flags=re.S):
        for line in re.sub(r"\\\n\s*", " ", block).splitlines():
            line = line.strip()
            if lang != "sh":
                if not line.startswith("$ "):
                    continue
                line = line[2:]
            words = shlex.split(line, comments=True)
            if "-m" in words and words[0] == "torchrun":
                words = words[words.index("-m") + 1:]
            if words[:1] == ["osmseg"] and "..." not in line:
                commands.append(words[1:])
    return commands


@dataclass
class Parsed:
    command: str
    values: dict[str, Any]   # parameter name -> the raw value as typed
    inputs: list[str]        # paths the command reads
    outputs: list[str]       # folders it writes


def parse_example(args: list[str]) -> Parsed:
    """``osmseg ARGS`` parsed by the command's own option table, as click would run it: unknown
    options, wrong types, missing required values and deprecated spellings raise. Paths are not
    opened (they are checked against the examples' data instead)."""
    group = click.Context(cli, info_name="osmseg", **cli.context_settings)
    _, rest, _ = cli.make_parser(group).parse_args(list(args))
    assert rest, f"no command in: osmseg {shlex.join(args)}"
    name, rest = rest[0], rest[1:]
    cmd = cli.get_command(group, name)
    assert cmd is not None, f"no command {name!r}"
    ctx = click.Context(cmd, parent=group, info_name=name)
    values, extra, _ = cmd.make_parser(ctx).parse_args(rest)
    assert not extra, f"unexpected arguments {extra}"
    values = {k: v for k, v in values.items() if repr(v) != "Sentinel.UNSET"}  # click 8.2+: not given
    parsed = Parsed(name, values, [], [])
    for param in cmd.params:
        if param.name not in values:
            assert not param.required, f"osmseg {name}: {param.opts} is required"
            continue
        assert not getattr(param, "hidden", False), f"osmseg {name}: a deprecated spelling {param.opts}"
        value = values[param.name]
        if isinstance(param.type, click.Path):
            items = value if isinstance(value, (list, tuple)) else [value]
            paths = [str(x) for v in items for x in (v if isinstance(v, (list, tuple)) else [v])]
            (parsed.inputs if param.type.exists else parsed.outputs).extend(paths)
        else:
            param.type_cast_value(ctx, value)  # raises click.BadParameter, as the command would
    for option in ("imagery", "osm"):  # sources spelled as text: geotiff:PATH, geojson:PATH:tags, xyz:file://...
        spec = str(values.get(option, ""))
        kind, _, rest_ = spec.partition(":")
        if kind in ("geotiff", "geojson"):
            parsed.inputs.append(rest_.split(":")[0])
        elif kind == "xyz" and rest_.startswith("file://"):
            parsed.inputs.append(rest_[len("file://"):])
        elif spec.endswith((".pbf", ".osm", ".tif")):
            parsed.inputs.append(spec)
    return parsed


def example_data() -> list[str]:
    """The paths README.md's "Example data" table accounts for (first column)."""
    text = README.read_text(encoding="utf-8")
    if "## Example data" not in text:
        return []
    section = text.split("## Example data", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in section.splitlines() if line.startswith("| `")]
    return [path for row in rows for path in re.findall(r"`([^`]+)`", row.split("|")[1])]


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_every_example_parses_as_printed(doc: Path) -> None:
    commands = example_commands(doc)
    if doc == README:
        assert len(commands) >= 10  # the extractor finds the examples
    for args in commands:
        try:
            parse_example(args)
        except (click.ClickException, AssertionError) as exc:
            message = exc.format_message() if isinstance(exc, click.ClickException) else str(exc)
            pytest.fail(f"{doc.name}: osmseg {shlex.join(args)}: {message}")


def test_every_path_a_readme_example_reads_comes_from_somewhere() -> None:
    listed = example_data()
    assert listed, "README.md has no Example data table"
    produced: list[str] = []
    used: set[str] = set()
    unexplained = []
    for args in example_commands(README):
        parsed = parse_example(args)
        for path in parsed.inputs:
            p = path.rstrip("/")
            if any(p == o or p.startswith(o + "/") for o in produced) or (REPO_ROOT / p).exists():
                continue
            hits = [entry for entry in listed if p == entry.rstrip("/") or p.startswith(entry.rstrip("/") + "/")
                    or (entry.endswith("/") and p.startswith(entry))]
            used.update(hits)
            if not hits:
                unexplained.append(f"{path} (osmseg {shlex.join(args)})")
        produced += [o.rstrip("/") for o in parsed.outputs]
    assert unexplained == [], "README examples read paths that no example makes and Example data does not explain"
    assert set(listed) == used, f"Example data lists paths no example reads: {sorted(set(listed) - used)}"
