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


@pytest.mark.parametrize("old", [["--osm", "city.osm"], ["--bbox", "26.94,60.53,26.95,60.54"], ["--lat", "60.5"],
                                 ["--radius-km", "1"], ["--shard", "1/2"], ["--cache-dir", "cache"], ["--zoom", "18"]])
def test_localize_names_localize_region_for_a_region_option(tmp_path, old: list[str]) -> None:
    """The former ``osmseg localize --osm FILE --bbox ...`` (one command, two meanings) is now two
    commands; the old spelling says in one line which to run, before any file is read."""
    query = tmp_path / "query.png"
    query.write_bytes(b"")
    result = CliRunner().invoke(cli, ["localize", "--ground", str(query), *old, "--out", str(tmp_path / "out")])
    assert result.exit_code == 2, result.output
    message = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(message) == 1 and f"{old[0]} is a region search's" in message[0], result.output
    assert "osmseg localize-region --ground FILE --osm FILE --bbox W,S,E,N" in message[0]
    assert not (tmp_path / "out").exists()


def test_localize_and_localize_region_each_take_only_their_own_options() -> None:
    """The image command takes the aerial image's and the paper method's options, the region
    command the region's; what they share (the ground view, how it was taken) is declared once."""
    found = commands()

    def taken(name: str) -> set[str]:
        return {flag for p in found[name].params if isinstance(p, DeclaredOption) for flag in p.opts}

    image, region = taken("localize"), taken("localize-region")
    assert {"--aerial", "--aerial-resolution", "--window", "--method", "--min-kappa"} <= image - region
    assert {"--osm", "--bbox", "--lat", "--zoom", "--shard", "--cache-dir"} <= region - image
    assert {"--ground", "--ground-table", "--heading", "--fov", "--camera-height", "--tilt", "--vista-weight",
            "--truth"} <= image & region


def test_a_request_is_built_from_a_command_s_flat_parameters_and_refuses_a_stray_one() -> None:
    """osmseg.cli.requests: a part of a request is filled from the parameters its own fields name;
    a parameter no field takes is an error (a command and its request cannot drift apart)."""
    from localization.cli.localize import ImageQuery, PaperOptions
    from osmseg.cli.requests import make_request, part_options

    ctx = click.Context(commands()["localize"])
    params = {p.name: p.get_default(ctx) for p in ctx.command.params if p.expose_value and p.name}
    params.update(aerial_path="a.png", ground_path="g.png", window_text="120")
    query = make_request(ImageQuery, params, typed={"window_text": "--window"})
    assert query.paper.window == 120 and query.aerial.aerial_path == "a.png" and query.profile.view.fov_deg == 360
    assert "window_text" in part_options(PaperOptions) and "feature_threshold" in part_options(PaperOptions)
    with pytest.raises(TypeError, match="no field for the parameters colour"):
        make_request(ImageQuery, {**params, "colour": "red"})
    with pytest.raises(Exception, match="--window applies to --method paper"):
        query.config()  # the profile method is the default: --window was typed for nothing
