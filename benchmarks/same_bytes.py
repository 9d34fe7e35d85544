"""Do two versions of osmseg write the same bytes? ``osmseg demo`` (build, localize-bench, training,
evaluation) run by the working tree and by another commit, compared file by file.

Run: ``.venv/bin/python benchmarks/same_bytes.py [--ref HEAD] [--epochs 2] [--keep DIR]``.

The other commit is checked out as a ``git worktree`` in a temporary folder. Each tree runs
``python -m osmseg -q demo --out OUT --epochs N`` in a fresh process, from its own folder and with
its own code first on the import path (checked: each run says which files it imported), into
the same OUT path (moved aside after), so the paths the outputs record are the same. Then every
file under the two folders is compared: the same bytes, or the same content once the figures
that measure time are set aside (JSON keys ending in ``_s`` or ``seconds`` and ``timing``; CSV
columns so named; the same in a PyTorch checkpoint, whose tensors are compared by their bytes).
The build's own state folder (``.osmseg-build``: its HTTP cache and resume records) is not an
output. A refactor that keeps behaviour keeps all of them: the script prints each file that
differs, and exits 1 if any does.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import io
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import tomllib

ROOT = Path(__file__).resolve().parents[1]
#: keys of a JSON document that measure time, not behaviour
TIME_KEYS = ("timing",)
TIME_SUFFIXES = ("_s", "seconds")
#: the builder's own state folder in a dataset (HTTP cache, resume records): not an output
STATE = ".osmseg-build"


def timeless(value: Any) -> Any:
    """``value`` (a JSON document) without the keys that measure time.

    >>> timeless({"error": 1.5, "localize_s": 0.2, "timing": {"total_s": 3}, "rows": [{"seconds": 2, "n": 1}]})
    {'error': 1.5, 'rows': [{'n': 1}]}
    """
    if isinstance(value, dict):
        return {k: timeless(v) for k, v in value.items()
                if k not in TIME_KEYS and not k.endswith(TIME_SUFFIXES)}
    if isinstance(value, list):
        return [timeless(v) for v in value]
    return value


def timeless_csv(data: bytes) -> list[list[str]]:
    """A CSV file's rows without the columns whose header names a time.

    >>> timeless_csv(b"epoch,loss,seconds\\n1,0.5,12.3\\n")
    [['epoch', 'loss'], ['1', '0.5']]
    """
    rows = list(csv.reader(io.StringIO(data.decode("utf-8"))))
    keep = [i for i, name in enumerate(rows[0] if rows else []) if name not in TIME_KEYS
            and not name.endswith(TIME_SUFFIXES)]
    return [[row[i] for i in keep if i < len(row)] for row in rows]


def tensors_as_digests(value: Any) -> Any:
    """A loaded checkpoint with each tensor as its dtype, shape and the SHA-256 of its bytes."""
    import torch

    if isinstance(value, torch.Tensor):
        t = value.detach().cpu().contiguous()
        return [str(t.dtype), list(t.shape), hashlib.sha256(t.reshape(-1).view(torch.uint8).numpy().tobytes()).hexdigest()
                if t.numel() else ""]
    if isinstance(value, dict):
        return {str(k): tensors_as_digests(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [tensors_as_digests(v) for v in value]
    return value


def same(a: Path, b: Path) -> bool:
    """Whether files ``a`` and ``b`` hold the same bytes, or the same content apart from its times."""
    left, right = a.read_bytes(), b.read_bytes()
    if left == right:
        return True
    try:
        if a.suffix == ".json":
            return bool(timeless(json.loads(left)) == timeless(json.loads(right)))
        if a.suffix == ".csv":
            return timeless_csv(left) == timeless_csv(right)
        if a.suffix == ".pt":
            import torch

            first, second = (torch.load(p, map_location="cpu", weights_only=False) for p in (a, b))
            return bool(timeless(tensors_as_digests(first)) == timeless(tensors_as_digests(second)))
    except (ValueError, UnicodeDecodeError):
        return False
    return False


def tree_metadata(tree: Path, into: Path) -> Path:
    """A folder holding an ``osmseg`` dist-info with ``tree``'s own version and entry points.

    The installed metadata names the command modules of the checkout it was installed from;
    once a command moves (``localization.cli`` became a package), the other tree's commands
    would not load. Put first on ``PYTHONPATH``, this dist-info is the one ``importlib.metadata``
    finds (it keeps the first distribution of a name on the path).
    """
    project = tomllib.loads((tree / "pyproject.toml").read_text())["project"]
    info = into / f"osmseg-{project['version']}.dist-info"
    info.mkdir(parents=True, exist_ok=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: osmseg\nVersion: {project['version']}\n")
    groups = {"console_scripts": project.get("scripts", {}), **project.get("entry-points", {})}
    (info / "entry_points.txt").write_text("".join(
        f"[{group}]\n" + "".join(f"{name} = {target}\n" for name, target in entries.items()) + "\n"
        for group, entries in groups.items()))
    return into


def run_demo(tree: Path, out: Path, epochs: int) -> str:
    """``osmseg demo`` with ``tree``'s code and entry points into ``out``; returns the folder its ``osmseg`` came from."""
    meta = tree_metadata(tree, out.parent / f"meta-{abs(hash(str(tree)))}")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(meta), str(tree)])}
    probe = subprocess.run([sys.executable, "-c", "import osmseg, training, localization as l; "
                            "print(l.__file__)"], cwd=tree, env=env, check=True, capture_output=True, text=True)
    used = Path(probe.stdout.strip()).parents[1]
    if used.resolve() != tree.resolve():
        raise SystemExit(f"the run for {tree} imported {used}: the editable install shadows PYTHONPATH")
    subprocess.run([sys.executable, "-m", "osmseg", "-q", "demo", "--out", str(out), "--epochs", str(epochs)],
                   cwd=tree, env=env, check=True)
    shutil.rmtree(meta, ignore_errors=True)
    return str(used)


def compare(a: Path, b: Path) -> tuple[int, list[str]]:
    """``(files compared, the relative paths that differ or exist on one side only)``."""
    left, right = ({p.relative_to(root) for p in root.rglob("*") if p.is_file() and STATE not in p.parts}
                   for root in (a, b))
    differ = sorted(str(p) + (" (only in the other commit's)" if p not in left else " (only in this tree's)")
                    for p in left ^ right)
    differ += sorted(str(p) for p in left & right if not same(a / p, b / p))
    return len(left | right), differ


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ref", default="HEAD", help="the commit to compare the working tree with")
    ap.add_argument("--epochs", type=int, default=2, help="the demo's training epochs")
    ap.add_argument("--keep", type=Path, help="keep both output folders here (else a temporary folder)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="same-bytes-") as tmp:
        work = args.keep or Path(tmp)
        other = Path(tmp) / "tree"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "--quiet", str(other), args.ref],
                       check=True)
        try:
            for name, tree, aside in (("this tree", ROOT, "this"), (args.ref, other, "ref")):
                shutil.rmtree(work / aside, ignore_errors=True)
                print(f"{name}: osmseg demo ({run_demo(tree, work / 'out', args.epochs)})", flush=True)
                (work / "out").rename(work / aside)   # both runs write to the same path
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(other)], check=False)
        n, differ = compare(work / "this", work / "ref")
    print(f"{n} files, {len(differ)} differ from {args.ref}'s" + (":" if differ else ""))
    for rel in differ:
        print(f"  {rel}")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
