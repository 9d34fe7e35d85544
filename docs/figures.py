"""Every figure README.md and docs/*.md quote from a command, measured again and written in.

A measured figure sits between two HTML comments, which Markdown does not show, inline or
around a whole block::

    the paper method's median error is <!-- fig demo40.paper.median -->119.32 m<!-- /fig -->

``python docs/figures.py`` (``make docs-figures``) runs the commands behind every marker
(``python -m osmseg ...`` in a temporary folder, exactly as the docs print them, with this
checkout's code) or the library calls that analyse their results, and rewrites what lies
between the markers. Numbers are written at the one precision of :mod:`osmseg.units`. The
first part of a key names the *figure set* that measures it (``docs/figure_sets.py`` says
what each runs); a set is

* **cheap**: seconds to a minute, deterministic; ``tests/project/test_docs_figures.py`` runs these again
  and fails when a doc says something else;
* **expensive**: minutes, or timings that differ on every run: only this script regenerates them;
* or it **needs** something osmseg does not ship: PyTorch, ``../shared/data``, or the authors'
  annotated pairs (``--pairs DIR``, github.com/sebagreen/landmark-graph-matching); without it
  the set is skipped and its figures are left as they are (the script says so).

Usage::

    python docs/figures.py                 # every set it can run; rewrites README.md and docs/*.md
    python docs/figures.py --cheap         # the cheap sets only
    python docs/figures.py --only demo40 pairs --pairs ../landmark-graph-matching
    python docs/figures.py --check         # rewrite nothing: list the figures that differ, exit 1 if any

Imports: osmseg, training and localization (the top of the layers, as the CLI).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

REPO_ROOT = Path(__file__).resolve().parent.parent
for _path in (REPO_ROOT, REPO_ROOT / "docs"):  # this checkout's osmseg, and figure_sets beside this file
    if str(_path) not in sys.path:
        sys.path.insert(0, str(_path))

#: the documents whose figures this script owns
DOCUMENTS = (REPO_ROOT / "README.md", *sorted((REPO_ROOT / "docs").glob("*.md")))
#: a figure between its markers; group 1 the key, group 2 what the doc says now
MARKER = re.compile(r"<!-- fig ([\w.-]+) -->(.*?)<!-- /fig -->", re.S)
OPENING = re.compile(r"<!-- fig ([^>]*?) ?-->")
CLOSING = "<!-- /fig -->"


@dataclass(frozen=True)
class Figure:
    """What a marker holds: the text, and the parts of it that differ between runs (timings),
    as a regular expression, left out when a figure is compared with the doc."""

    text: str
    volatile: str | None = None

    def comparable(self, text: str | None = None) -> str:
        text = self.text if text is None else text
        return re.sub(self.volatile, "~", text) if self.volatile else text


@dataclass(frozen=True)
class FigureSet:
    name: str
    cost: str                      # "cheap" | "expensive"
    needs: str                     # "" | "torch" | "shared data" | "pairs"
    measure: Callable[[Workspace], dict[str, Figure]]
    about: str


SETS: dict[str, FigureSet] = {}


def figure_set(name: str, cost: str, needs: str = "") -> Callable[[Callable[[Workspace], dict[str, Figure]]],
                                                                   Callable[[Workspace], dict[str, Figure]]]:
    """Register a function measuring the figures ``name.*`` (its docstring says what it runs)."""
    def register(measure: Callable[[Workspace], dict[str, Figure]]) -> Callable[[Workspace], dict[str, Figure]]:
        SETS[name] = FigureSet(name, cost, needs, measure, (measure.__doc__ or "").strip().splitlines()[0])
        return measure
    return register


# --------------------------------------------------------------------------- running commands


class CommandFailed(RuntimeError):
    pass


@dataclass
class Workspace:
    """A temporary folder the commands run in, as a user's: ``demo/``, ``bench/``... relative paths.

    Runs are cached by their arguments, so sets that quote the same run share it."""

    root: Path
    pairs: Path | None = None
    shared: Path = REPO_ROOT.parent / "shared" / "data"
    reuse: bool = False  # a benchmark's JSON already in root is read, not measured again
    _runs: dict[tuple[str, ...], tuple[str, str]] = field(default_factory=dict)

    def env(self) -> dict[str, str]:
        path = os.pathsep.join([str(REPO_ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])
        return {**os.environ, "PYTHONPATH": path, "COLUMNS": "120"}

    def run(self, *args: str, python: bool = False) -> tuple[str, str]:
        """``osmseg ARGS`` (or ``python ARGS``) in the workspace: (stdout, stderr); raises when it fails.

        A command runs with ``--no-progress``: what it prints is what a terminal keeps once its
        progress bars are gone, not the progress lines a log gets."""
        key = ("python" if python else "osmseg", *args)
        if key not in self._runs:
            command = [sys.executable, *args] if python else [sys.executable, "-m", "osmseg", "--no-progress", *args]
            done = subprocess.run(command, cwd=self.root, env=self.env(), capture_output=True, text=True)
            if done.returncode != 0:
                raise CommandFailed(f"{' '.join(key)} exited {done.returncode}: {done.stderr.strip()[-2000:]}")
            self._runs[key] = (done.stdout, done.stderr)
        return self._runs[key]

    def demo_dataset(self) -> str:
        """The demo's dataset (``osmseg demo --out demo --no-train --no-localize``): ``demo/dataset``."""
        self.run(*DEMO_BUILD)
        return "demo/dataset"

    def bench(self, *args: str, command: str = "localize-bench") -> tuple[str, dict[str, Any]]:
        """``osmseg localize-bench ARGS`` (or ``localize-pairs``): what it printed (its summary on stderr,
        then the path of results.json on stdout) and results.json."""
        out, err = self.run(command, *args)
        folder = args[args.index("--out") + 1]
        return err + out, json.loads((self.root / folder / "results.json").read_text(encoding="utf-8"))

    def pairs_folder(self) -> str:
        """The annotated pairs, linked into the workspace under the name the docs use."""
        assert self.pairs is not None
        link = self.root / "landmark-graph-matching"
        if not link.exists():
            link.symlink_to(self.pairs.resolve(), target_is_directory=True)
        return "landmark-graph-matching/"


DEMO_BUILD = ("demo", "--out", "demo", "--no-train", "--no-localize", "-q")


def transcript(*runs: tuple[tuple[str, ...], str]) -> str:
    """A shell session as the docs print it: each ``$ osmseg ARGS`` and what it printed."""
    lines = []
    for args, output in runs:
        lines.append("$ osmseg " + " ".join(args))
        lines.extend(output.rstrip("\n").splitlines())
    return "\n```\n" + "\n".join(lines) + "\n```\n"


def available(fs: FigureSet, ws: Workspace) -> str:
    """Why ``fs`` cannot run here ("" when it can)."""
    if fs.needs == "torch":
        import importlib.util

        return "" if importlib.util.find_spec("torch") is not None else "PyTorch is not installed"
    if fs.needs == "shared data":
        return "" if ws.shared.exists() else f"{ws.shared} is absent"
    if fs.needs == "pairs":
        return "" if ws.pairs is not None and (ws.pairs / "aerial").is_dir() else \
            "no --pairs DIR (the authors' annotated pairs)"
    return ""


def measure(names: Iterable[str], ws: Workspace, say: Callable[[str], None] = print) -> dict[str, Figure]:
    """Run the sets ``names`` that can run here; every figure they give, by key."""
    import figure_sets  # noqa: F401  (registers the sets)

    figures: dict[str, Figure] = {}
    for name in names:
        fs = SETS[name]
        why = available(fs, ws)
        if why:
            say(f"{name}: skipped ({why}); its figures are left as they are")
            continue
        say(f"{name}: {fs.about}")
        got = fs.measure(ws)
        stray = [k for k in got if not k.startswith(name + ".")]
        if stray:
            raise KeyError(f"set {name} gave figures of another set: {stray}")
        figures.update(got)
    return figures


# --------------------------------------------------------------------------- the documents


def markers(text: str) -> list[tuple[str, str]]:
    """(key, current text) of every figure marker; malformed markers raise ValueError."""
    found = MARKER.findall(text)
    if len(OPENING.findall(text)) != len(found) or text.count(CLOSING) != len(found):
        raise ValueError("a figure marker is not closed, or nested, or its key is not [A-Za-z0-9_.-]")
    return found


def write_in(figures: dict[str, Figure], documents: Iterable[Path] = DOCUMENTS) -> dict[Path, str]:
    """Each document with every marker of ``figures`` rewritten (the others left alone)."""
    out = {}
    for path in documents:
        text = path.read_text(encoding="utf-8")
        markers(text)
        out[path] = MARKER.sub(lambda m: m.group(0) if m.group(1) not in figures else
                               f"<!-- fig {m.group(1)} -->{figures[m.group(1)].text}<!-- /fig -->", text)
    return out


def differences(figures: dict[str, Figure], documents: Iterable[Path] = DOCUMENTS) -> list[str]:
    """One line per figure a document states otherwise than ``figures`` (volatile parts left out),
    and per measured figure no document shows."""
    shown: set[str] = set()
    problems = []
    for path in documents:
        for key, text in markers(path.read_text(encoding="utf-8")):
            shown.add(key)
            if key in figures and figures[key].comparable(text) != figures[key].comparable():
                where = path.relative_to(REPO_ROOT) if path.is_relative_to(REPO_ROOT) else path
                problems.append(f"{where}: {key}: the doc says {text.strip()[:300]!r}, "
                                f"measured {figures[key].text.strip()[:300]!r}")
    problems += [f"{key}: measured, but no document shows it" for key in sorted(set(figures) - shown)]
    return problems


def main(argv: list[str] | None = None) -> int:
    import figure_sets  # noqa: F401

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--cheap", action="store_true", help="only the cheap sets (what the test reruns)")
    which.add_argument("--only", nargs="+", choices=sorted(SETS), metavar="SET", help=f"only these: {', '.join(SETS)}")
    parser.add_argument("--pairs", type=Path, help="the authors' annotated pairs (aerial/, ground/)")
    parser.add_argument("--check", action="store_true", help="write nothing; exit 1 when a figure differs")
    parser.add_argument("--keep", type=Path, help="run in this folder and keep it (default: a temporary one)")
    parser.add_argument("--reuse", action="store_true",
                        help="with --keep: read the JSON a benchmark left in that folder (its settings are in it) "
                             "instead of running it again; to write its figures anew after a change of wording")
    args = parser.parse_args(argv)
    names = args.only or [n for n, s in SETS.items() if s.cost == "cheap" or not args.cheap]
    with tempfile.TemporaryDirectory(prefix="osmseg-figures-") as tmp:
        root = args.keep or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        figures = measure(names, Workspace(root, args.pairs, reuse=args.reuse and args.keep is not None))
    if args.check:
        problems = differences(figures)
        print("\n".join(problems) or f"{len(figures)} figures, as the docs say")
        return 1 if problems else 0
    for path, text in write_in(figures).items():
        if text != path.read_text(encoding="utf-8"):
            path.write_text(text, encoding="utf-8")
            print(f"rewrote {path.relative_to(REPO_ROOT)}")
    missing = differences(figures)
    if missing:
        print("\n".join(missing))
        return 1
    return 0


if __name__ == "__main__":
    import figures  # this file again, as the module the figure sets register in

    sys.exit(figures.main())
