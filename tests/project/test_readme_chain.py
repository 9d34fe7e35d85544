"""The README's real-data chain, read out of README.md and run as a user runs it: in order, as
written, in one folder, as separate processes with stderr sent to a file, then again into the
same folders. Skipped without ``../shared/data``.

The chain: the Kampala build example (real drone tiles and OSM footprints) -> ``osmseg train``
on it -> ``osmseg eval`` on its test split -> ``osmseg predict`` on Inria's Austin tile ->
``osmseg eval`` against Austin's own building labels. What a user would check, with readers
osmseg did not write: the samples are distinct (md5 of their files) and share no pixel
(shapely on the manifest's boxes), the checkpoint exists and its metrics beat a model that
calls everything background on the held-out samples, the predicted mask lies on the input's
grid (rasterio), and no command printed a traceback. ``test_the_chain_reads_only_what_it_makes``
checks, without running anything, that each command reads only what the ones before it made.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import shapely
from conftest import REPO_ROOT, SHARED_DATA

README = REPO_ROOT / "README.md"
#: the README's Kampala build example and its training block are found by these
BUILD_MARK = "kampala-oam/tiles"
CHAIN_MARK = "osmseg eval runs/kampala/model.pt data/kampala"


def sh_blocks() -> list[list[str]]:
    """The commands of every ``sh`` block of README.md (continuations joined, comments cut)."""
    text = README.read_text(encoding="utf-8")
    blocks = []
    for block in re.findall(r"```sh\n(.*?)```", text, flags=re.S):
        lines = [line.split(" #")[0].strip() for line in re.sub(r"\\\n\s*", " ", block).splitlines()]
        blocks.append([line for line in lines if line])
    return blocks


def chain() -> list[str]:
    """The Kampala build command, then the training block, as printed."""
    blocks = sh_blocks()
    build = [c for b in blocks for c in b if c.startswith("osmseg build") and BUILD_MARK in c]
    training = [b for b in blocks if any(CHAIN_MARK in c for c in b)]
    assert len(build) == 1 and len(training) == 1, (build, training)
    return [build[0], *training[0]]


def test_the_chain_reads_only_what_it_makes() -> None:
    commands = chain()
    assert [shlex.split(c)[1] for c in commands] == ["build", "train", "eval", "predict", "eval"]
    made = set()
    for command in commands:
        words = shlex.split(command)
        for word in words:
            root = word.split("/")[0]
            if root in ("data", "runs") and "/" in word and words[words.index(word) - 1] != "--out":
                assert "/".join(word.split("/")[:2]) in made, f"{command}: reads {word} before anything makes it"
        if "--out" in words:
            made.add("/".join(words[words.index("--out") + 1].split("/")[:2]).rstrip("/"))


def run_chain(folder: Path, commands: list[str], logs: Path, env: dict[str, str]) -> list[str]:
    """Run each command in ``folder`` as its own process, stderr to a file per command; their stderr."""
    said = []
    for index, command in enumerate(commands):
        args = [a.replace("/data/", f"{SHARED_DATA}/") for a in shlex.split(command)]
        log = logs / f"{index}-{args[1]}.err"
        with log.open("w") as err:
            done = subprocess.run([os.path.abspath(sys.executable), "-m", "osmseg", *args[1:]], cwd=folder, env=env,
                                  stdout=subprocess.PIPE, stderr=err, text=True, timeout=3600)
        text = log.read_text()
        assert done.returncode == 0, f"{command}\n{text[-3000:]}"
        assert "Traceback" not in text and "\r" not in text, f"{command}\n{text[-3000:]}"
        said.append(text)
    return said


def docs_blocks_on_real_data() -> list[tuple[str, list[str]]]:
    """The ``sh`` blocks of docs/*.md that read the real example data (``/data/...``): (doc, commands)."""
    found = []
    for doc in sorted((REPO_ROOT / "docs").glob("*.md")):
        for block in re.findall(r"```sh\n(.*?)```", doc.read_text(encoding="utf-8"), flags=re.S):
            if "/data/" not in block:
                continue
            lines = [re.split(r"\s#\s|^#", line)[0].strip() for line in re.sub(r"\\\n\s*", " ", block).splitlines()]
            found.append((doc.name, [line for line in lines if line]))
    return found


#: docs whose real-data examples take minutes (a region search): run by make test-slow
SLOW_DOCS = ("localization.md",)


@pytest.mark.parametrize("doc,commands", [
    pytest.param(doc, commands, id=f"{doc}-{i}", marks=[pytest.mark.slow] if doc in SLOW_DOCS else [])
    for i, (doc, commands) in enumerate(docs_blocks_on_real_data())])
def test_a_docs_example_on_real_data_runs_as_written(doc: str, commands: list[str], tmp_path: Path) -> None:
    """Each docs example that reads the real example data, every line in order (osmseg and the tools
    it shows, such as rasterio's ``rio``), as written: exit 0, no traceback, distinct samples."""
    if not SHARED_DATA.exists():
        pytest.skip(f"the example reads real data: {SHARED_DATA} is absent on this machine")
    env = {**os.environ, "OSMSEG_CACHE_DIR": str(tmp_path / "cache")}
    python = os.path.abspath(sys.executable)  # the commands run in another folder
    tools = Path(python).parent
    for command in commands:
        # run from a checkout's root as the docs say: its benchmarks/ scripts are at hand
        args = [a.replace("/data/", f"{SHARED_DATA}/") for a in shlex.split(command)]
        args = [str(REPO_ROOT / a) if a.startswith("benchmarks/") else a for a in args]
        program = [python, "-m", "osmseg"] if args[0] == "osmseg" else [str(tools / args[0])]
        done = subprocess.run([*program, *args[1:]], cwd=tmp_path, env=env, capture_output=True, text=True,
                              timeout=1800)
        assert done.returncode == 0, f"{doc}: {command}\n{done.stderr[-3000:]}"
        assert "Traceback" not in done.stderr, f"{doc}: {command}\n{done.stderr[-3000:]}"
        if args[:2] == ["osmseg", "build"]:
            out = tmp_path / args[args.index("--out") + 1]
            manifest = json.loads((out / "manifest.json").read_text())
            images = [out / next(f for f in s["files"] if f.startswith("images/")) for s in manifest["samples"]]
            assert images and len({md5(p) for p in images}) == len(images), f"{doc}: {command}: repeated samples"
        if args[:2] == ["osmseg", "localize-region"]:
            assert_found_where_drawn(tmp_path, args, doc)


def assert_found_where_drawn(folder: Path, args: list[str], doc: str) -> None:
    """A region search of a view that ``localize-bench --save-panoramas`` drew: its best answer in
    ``region.geojson`` lies within 5 m of where the bench says the camera stood (pyproj's geodesic)."""
    import pyproj

    ground = folder / args[args.index("--ground") + 1]
    results = json.loads((ground.parents[1] / "results.json").read_text())
    view = next(v for v in results["viewpoints"] if f"{v['index']:04d}_{v['scene']}.png" == ground.name)
    answers = json.loads((folder / args[args.index("--out") + 1] / "region.geojson").read_text())["features"]
    lon, lat = next(f["geometry"]["coordinates"] for f in answers if f["properties"].get("rank") == 1)
    _, _, metres = pyproj.Geod(ellps="WGS84").inv(lon, lat, *view["camera_lonlat"])
    assert metres < 5.0, f"{doc}: the answer is {metres:.1f} m from where the view was drawn"


def md5(path: Path) -> str:
    return hashlib.md5(path.read_bytes()).hexdigest()


@pytest.mark.slow
@pytest.mark.timeout(2400)  # a CPU training of 8 epochs, twice (the second resumes a finished run)
def test_the_readme_chain_runs_as_written_on_real_data(tmp_path: Path) -> None:
    if not SHARED_DATA.exists():
        pytest.skip(f"the chain reads real data: {SHARED_DATA} is absent on this machine")
    import rasterio

    commands = chain()
    logs = tmp_path / "logs"
    logs.mkdir()
    env = {**os.environ, "OSMSEG_CACHE_DIR": str(tmp_path / "cache")}
    work = tmp_path / "work"
    work.mkdir()

    run_chain(work, commands, logs, env)

    # the dataset: every sample its own tiles, no two sharing a pixel
    data = work / "data" / "kampala"
    manifest = json.loads((data / "manifest.json").read_text())
    names = [s["name"] for s in manifest["samples"]]
    assert len(names) == manifest["summary"]["requested"] == 8
    assert len({md5(data / "images" / f"{n}.png") for n in names}) == len(names)
    boxes = [shapely.box(*s["bounds_3857"]) for s in manifest["samples"]]
    assert all(a.intersection(b).area == 0 for i, a in enumerate(boxes) for b in boxes[i + 1:])

    # the model beats "everything is background" on samples it never saw
    metrics = json.loads((work / "runs" / "kampala" / "eval" / "metrics.json").read_text())
    building = metrics["per_class"]["building"]
    assert building["iou"] > 0.2, metrics
    background_share = 1 - building["support"] / sum(c["support"] for c in metrics["per_class"].values())
    assert metrics["pixel_accuracy"] > background_share, metrics

    # the prediction lies on the input's grid
    with rasterio.open(SHARED_DATA / "inria-austin" / "image.tif") as src, \
            rasterio.open(work / "masks" / "image.tif") as mask:
        assert mask.crs == src.crs and mask.shape == src.shape
        assert np.allclose(mask.transform, src.transform)
        ids = np.unique(mask.read(1))
    assert set(ids.tolist()) <= {c["id"] for c in manifest["classes"]["classes"]}
    austin = json.loads((work / "eval-austin" / "metrics.json").read_text())
    assert 0.0 <= austin["pixel_accuracy"] <= 1.0 and "building" in austin["per_class"]

    # again into the same folders: every command succeeds, the dataset and checkpoint stay as they are
    before = {p: md5(p) for p in [*sorted(data.rglob("*.png")), work / "runs" / "kampala" / "model.pt"]}
    run_chain(work, commands, logs, env)
    assert {p: md5(p) for p in before} == before
