"""Conventions every ``osmseg`` command shares, the plugins of training and localization included.

* ``-v``, ``-q`` and ``--progress`` work after the command's name as before it, and add up;
* a short option means one thing in every command (``-n`` is ``build --samples``);
* ``train --loader-workers`` (DataLoader processes) is named apart from ``build --workers``
  (build processes); the old spellings still work for a while and say what to type instead;
* ``--help`` shows every option's default (train's are TrainConfig's);
* summaries print figures at one precision per unit (:mod:`osmseg.units`) and lead with the
  default localization method (profile), in the terminal and in errors.png's title.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import click
import pytest
from click.testing import CliRunner
from conftest import TEST_DATA, table_after

from osmseg.cli.main import cli
from osmseg.demo import DEMO_CASSETTE

TINYSEG = TEST_DATA / "tinyseg"
COMMANDS = sorted(cli.list_commands(click.Context(cli)))


def command(name: str) -> click.Command:
    found = cli.get_command(click.Context(cli), name)
    assert found is not None, name
    return found


def osmseg_process(*args: object, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """``python -m osmseg ARGS`` as a user runs it (stderr a pipe: no progress bars)."""
    return subprocess.run([sys.executable, "-m", "osmseg", *(str(a) for a in args)], capture_output=True, text=True,
                          env={**os.environ, "OMP_NUM_THREADS": "1", **(env or {})}, timeout=300)


def demo_build(out: Path, *extra: str) -> list[str]:
    """The demo's Helsinki build, replayed from its recording (no network), one sample."""
    return ["build", "--city", "Helsinki", "--samples", "1", "--seed", "0", "--imagery", "bing", "--osm", "api",
            "--no-overlap", "--replay", str(DEMO_CASSETTE), "--out", str(out), "--cache-dir", str(out.parent / "cache"),
            *extra]


DEMO_ENV = {"BING_MAPS_KEY": "demo-key-not-secret"}


def test_every_command_is_a_plugin_or_core_command_that_loaded() -> None:
    assert {"build", "verify", "train", "predict", "eval", "localize", "localize-bench", "localize-pairs", "demo"} <= set(COMMANDS)


def test_a_command_imports_only_its_own_package() -> None:
    """``osmseg build`` loads neither training (torch) nor the localization methods, nor ``train``
    localization: each command is imported when asked for, not with the group."""
    probe = ("import sys, click; from osmseg.cli.main import cli; ctx = click.Context(cli); "
             "cli.get_command(ctx, sys.argv[1]); "
             "print(sorted({m.split('.')[0] for m in sys.modules} & {'torch', 'training', 'localization', 'scipy'}))")
    seen = {name: subprocess.run([sys.executable, "-c", probe, name], capture_output=True, text=True, check=True,
                                 timeout=120).stdout.strip() for name in ("verify", "build", "train", "localize")}
    assert seen["verify"] == seen["build"] == "[]", seen
    assert "training" in seen["train"] and "localization" not in seen["train"], seen
    assert "localization" in seen["localize"], seen


def test_a_plugin_that_fails_to_import_is_a_command_that_says_why(monkeypatch: pytest.MonkeyPatch) -> None:
    """One broken package does not take the other commands down: its command prints the import's
    traceback and exits 1, and ``osmseg --help`` still lists the rest."""
    import osmseg.cli.main as group

    monkeypatch.setattr(group, "CORE_COMMANDS", {**group.CORE_COMMANDS, "broken": "osmseg.no_such_module:command"})
    monkeypatch.setattr(cli, "commands", dict(cli.commands))  # the broken command is not kept after the test
    monkeypatch.setattr(cli, "_found", None)
    listing = CliRunner().invoke(cli, ["--help"])
    assert listing.exit_code == 0 and "broken" in listing.output and "build" in listing.output, listing.output
    result = CliRunner().invoke(cli, ["broken"])
    assert result.exit_code == 1 and "No module named 'osmseg.no_such_module'" in result.output, result.output


@pytest.mark.parametrize("name", COMMANDS)
def test_output_options_are_accepted_after_every_command(name: str) -> None:
    result = CliRunner().invoke(cli, [name, "-v", "-vv", "-q", "--no-progress", "--progress", "--help"])
    assert result.exit_code == 0, result.output
    for flag in ("-v, --verbose", "-q, --quiet", "--progress / --no-progress"):
        assert flag in result.output, (name, flag)


def test_verbosity_after_the_command_acts_as_before_it_and_adds_up(tmp_path: Path) -> None:
    loud = osmseg_process(*demo_build(tmp_path / "loud", "-v"), env=DEMO_ENV)
    assert loud.returncode == 0, loud.stderr[-800:]
    per_object = "WARNING osmseg.osm.features: way"  # each broken OSM object: listed from -v on
    assert per_object in loud.stderr and "accepted 1 sample" in loud.stderr

    quiet = osmseg_process(*demo_build(tmp_path / "quiet", "-q"), env=DEMO_ENV)
    assert quiet.returncode == 0, quiet.stderr[-800:]
    assert quiet.stderr == "" and quiet.stdout.strip().endswith("manifest.json")

    both = osmseg_process("-q", *demo_build(tmp_path / "both", "-v"), env=DEMO_ENV)  # -q then -v: the default
    assert both.returncode == 0 and "accepted 1 sample" in both.stderr and per_object not in both.stderr, both.stderr

    # a plugin command (localization) on the dataset just built: -q after it silences its summary
    bench = ["localize-bench", tmp_path / "loud", "--viewpoints", "1", "--methods", "paper", "--no-plots", "--out"]
    said = osmseg_process(*bench, tmp_path / "b1")
    hushed = osmseg_process(*bench, tmp_path / "b2", "-q")
    assert said.returncode == hushed.returncode == 0, said.stderr + hushed.stderr
    assert "1 rendered panorama, classes" in said.stderr and hushed.stderr == ""
    assert hushed.stdout.strip() == str(tmp_path / "b2" / "results.json")


def test_a_short_option_means_one_thing_in_every_command() -> None:
    meaning: dict[str, set[str]] = {}
    for name in ["", *COMMANDS]:
        cmd = cli if not name else command(name)
        for param in cmd.params:
            if not isinstance(param, click.Option) or param.hidden:
                continue
            longs = [o for o in param.opts + param.secondary_opts if o.startswith("--")]
            for short in (o for o in param.opts if re.fullmatch(r"-[A-Za-z]", o)):
                meaning.setdefault(short, set()).add(longs[0] if longs else short)
    assert meaning.get("-n") == {"--samples"}
    assert {short: longs for short, longs in meaning.items() if len(longs) > 1} == {}


def test_train_loader_workers_are_named_apart_from_build_workers(tmp_path: Path) -> None:
    train_help = CliRunner().invoke(cli, ["train", "--help"]).output
    build_help = CliRunner().invoke(cli, ["build", "--help"]).output
    assert "--loader-workers" in train_help and "--workers" not in train_help.replace("--loader-workers", "")
    assert "--workers" in build_help and "--loader-workers" not in build_help
    both = CliRunner().invoke(cli, ["train", str(TINYSEG), "--out", str(tmp_path / "r"), "--workers", "1",
                                    "--loader-workers", "1"])
    assert both.exit_code == 2 and "--loader-workers" in both.output.splitlines()[-1]
    assert not (tmp_path / "r").exists()


def test_a_config_file_with_the_old_workers_key_is_read_with_a_warning(tmp_path: Path,
                                                                        caplog: pytest.LogCaptureFixture) -> None:
    from training.run.config import make_config

    file = tmp_path / "old.toml"
    file.write_text("workers = 3\nepochs = 2\n")
    config = make_config(tmp_path, tmp_path / "run", file, {})
    assert (config.loader_workers, config.epochs) == (3, 2)
    assert "'workers' is now 'loader_workers'" in caplog.text


@pytest.mark.parametrize("name", COMMANDS)
def test_help_shows_every_default(name: str) -> None:
    cmd = command(name)
    ctx = click.Context(cmd, parent=click.Context(cli, **cli.context_settings), info_name=name)
    missing = []
    for param in cmd.params:
        if not isinstance(param, click.Option) or param.hidden or param.count or param.required:
            continue
        record = param.get_help_record(ctx)
        assert record is not None
        default = param.get_default(ctx, call=False)
        given = default is not None and repr(default) != "Sentinel.UNSET" and default != ()
        has_default = given and not (param.is_flag and default is False and not param.secondary_opts)
        if has_default and "default:" not in record[1]:
            missing.append(record[0])
        # a default is said by click's "[default: ...]", not in a note of the help text
        assert not re.search(r"\[[^\]]*\]\s*$", param.help or ""), (record[0], param.help)
    assert missing == [], f"osmseg {name} --help shows no default for {missing}"


def test_train_help_shows_the_training_defaults() -> None:
    from training.run.config import FIELDS
    from training.run.recipe import RECIPES

    text = " ".join(CliRunner().invoke(cli, ["train", "--help"], terminal_width=400).output.split())
    for option, field in [("--batch-size", "batch_size"), ("--lr", "lr"), ("--class-weights", "class_weights")]:
        shown = re.search(re.escape(option) + r" .*?\[default: \(the recipe's \(([^)]+)\)\)(?:; [^\]]+)?\]", text)
        assert shown and shown.group(1) == ", ".join(f"{r.name} {getattr(r, field)}" for r in RECIPES.values()), \
            (option, shown and shown.group(0))
    for option, field in [("--epochs", "epochs"), ("--recipe", "recipe"),
                          ("--width", "width"), ("--model", "model"), ("--loader-workers", "loader_workers"),
                          ("--seed", "seed"), ("--device", "device"), ("--split-by", "split_by")]:
        shown = re.search(re.escape(option) + r" .*?\[default: ([^;\]]+)", text)
        assert shown and shown.group(1) == str(FIELDS[field].default), (option, shown and shown.group(0))


# ------------------------------------------------------------------------------ figures in summaries

#: a measured figure with its unit (not a setting: a recall radius "@10 m", "within 10 m", "beyond 50 m")
NUMBER_WITH_UNIT = re.compile(r"(?<![\w.@])(?<!within )(?<!beyond )(-?\d+(?:\.\d+)?) ?(m|px|°)(?![\w/])")


def decimals(text: str) -> int:
    return len(text.split(".")[1]) if "." in text else 0


def test_localization_summary_leads_with_the_default_method_at_one_precision(tmp_path: Path) -> None:
    """As ``osmseg demo`` runs it: paper first (its class subsets), profile beside it."""
    built = osmseg_process("-q", *demo_build(tmp_path / "ds"), env=DEMO_ENV)
    assert built.returncode == 0, built.stderr
    result = osmseg_process("localize-bench", tmp_path / "ds", "--viewpoints", "3", "--methods", "paper,profile",
                            "--out", tmp_path / "bench", "--no-plots")
    assert result.returncode == 0, result.stderr
    lines = result.stderr.splitlines()
    results = json.loads((tmp_path / "bench" / "results.json").read_text())
    profile = results["methods"]["profile"]
    first = next(i for i, line in enumerate(lines) if "rendered panoramas" in line)  # after the progress lines
    assert lines[first + 1].startswith("profile method: ")
    assert f"median {profile['median_error']:.2f} m" in lines[first + 1]
    assert any(line.startswith("paper method by number of landmark classes") for line in lines)
    found = NUMBER_WITH_UNIT.findall(result.stderr)
    assert found
    for value, unit in found:
        assert decimals(value) == {"m": 2, "px": 1, "°": 1}[unit], (value, unit, result.stderr)
    for recall in re.findall(r"@\d+ m (\d\.\d+)", result.stderr):
        assert decimals(recall) == 3, result.stderr
    for row in table_after(result.stderr, ["method", "answered"], 2):
        assert row["answered"].count("/") == 1  # answered/asked
        assert all(decimals(row[f"@{r} m"]) == 3 for r in (10, 25, 50) if row[f"@{r} m"] != "-"), row  # ratios

    from localization.bench.plots import errors_title

    title = errors_title(results)
    assert "angular profiles: median" in title and f"{profile['median_error']:.2f} m" in title
