"""One name, one type, one meaning: every option of every command comes from one declaration.

Walks the ``osmseg`` group as a user's ``--help`` would (the plugins of training and localization
loaded): every option is made from a :class:`~osmseg.cli.options.Declared` (or is a former
spelling that refuses in one line), a flag has one declaration across all commands, and its help
starts with that declaration's meaning. A second declaration of a flag fails at import.
"""

from __future__ import annotations

import re

import click
import pytest
from click.testing import CliRunner

from osmseg.cli.main import cli
from osmseg.cli.options import DECLARED, Declared, DeclaredOption, MovedOption, declare


def commands() -> dict[str, click.Command]:
    """Every command of the group by name (the group itself as ``osmseg``)."""
    ctx = click.Context(cli)
    found: dict[str, click.Command] = {"osmseg": cli}
    for name in cli.list_commands(ctx):
        command = cli.get_command(ctx, name)
        assert command is not None and not isinstance(command, click.Group), name
        assert "could not be loaded" not in (command.help or ""), f"plugin {name} failed to load: {command.help}"
        found[name] = command
    return found


def test_every_option_of_every_command_is_declared_once() -> None:
    undeclared, meanings = [], {}
    for name, command in commands().items():
        for param in command.params:
            if not isinstance(param, click.Option) or param.name in ("version",):
                continue
            if isinstance(param, MovedOption):
                assert param.hidden and not param.expose_value, (name, param.opts)
                continue
            if not isinstance(param, DeclaredOption):
                undeclared.append(f"{name} {'/'.join(param.opts)}")
                continue
            declared = param.declared
            assert DECLARED[param.opts[0]] is declared
            assert param.help and param.help.startswith(declared.help.rstrip(".")), (name, param.opts, param.help)
            assert param.type == click.types.convert_type(declared.type) or declared.type is None, (name, param.opts)
            for flag in (*param.opts, *param.secondary_opts):
                meanings.setdefault(flag, {})[id(declared)] = f"{declared.module} ({name})"
    assert not undeclared, f"options not declared in osmseg.cli.options or their layer's: {undeclared}"
    twice = {flag: sorted(where.values()) for flag, where in meanings.items() if len(where) > 1}
    assert not twice, f"one name, two meanings: {twice}"
    assert {"--out", "--seed", "--mode", "--resolution", "--landmark-mode", "--aerial-resolution"} <= set(meanings)


def test_the_shared_options_mean_the_same_in_every_command() -> None:
    """--out, --seed, --device, --osm, --zoom, ... have one type wherever they appear."""
    types: dict[str, set[str]] = {}
    for command in commands().values():
        for param in command.params:
            if isinstance(param, DeclaredOption):
                for flag in param.opts:
                    types.setdefault(flag, set()).add(f"{param.type!r} multiple={param.multiple} nargs={param.nargs}")
    several = {f: t for f, t in types.items() if len(t) > 1}
    assert not several, several
    used_by = {flag: sum(flag in (p.opts if isinstance(p, click.Option) else ()) for c in commands().values()
                         for p in c.params) for flag in ("--out", "--seed", "--osm", "--zoom", "--camera-height")}
    assert all(n >= 2 for n in used_by.values()), used_by


def test_a_second_meaning_under_a_declared_name_fails_at_import() -> None:
    with pytest.raises(ValueError, match=r"--mode is declared in training\.cli and again in test_cli_options"):
        declare("--mode", help="Something else.")
    assert DECLARED["--mode"].module == "training.cli"
    assert isinstance(DECLARED["--landmark-mode"], Declared)


@pytest.mark.parametrize(("command", "old", "new"), [
    ("localize", ["--mode", "grid"], "--landmark-mode"),
    ("localize", ["--resolution", "0.3"], "--aerial-resolution"),
    ("localize", ["--aerial-classes", "aerial13"], "--aerial-landmarks"),
    ("localize-bench", ["--heading", "unknown"], "--view-heading"),
    ("localize-bench", ["--method", "profile"], "--methods"),
    ("localize-bench", ["--width", "600"], "--pano-width"),
    ("localize-bench", ["--table", "classes13.toml"], "--classes"),
    ("localize-bench", ["-n", "5"], "--viewpoints"),
    ("localize-pairs", ["--resolution", "0.3"], "--aerial-resolution"),
    ("train", ["--workers", "2"], "--loader-workers"),
])
def test_a_former_spelling_says_in_one_line_what_to_type_now(tmp_path, command: str, old: list[str],
                                                              new: str) -> None:
    result = CliRunner().invoke(cli, [command, str(tmp_path), *old, "--out", str(tmp_path / "out")])
    assert result.exit_code == 2, result.output
    message = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(message) == 1 and new in message[0] and old[0] in message[0], result.output
    assert re.search(re.escape(new) + r"\b", commands()[command].get_help(click.Context(commands()[command])))
    assert not (tmp_path / "out").exists()
