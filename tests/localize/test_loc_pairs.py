"""Annotated pairs (localization.bench.pairs): the paper's evaluation on landmark files, through the CLI.

The pairs are written here as the authors lay them out (aerial/NAME.txt, ground/NAME.txt,
``x y Class`` or ``x,y,Class`` lines in the paper's class names: their files use both). The scene has one place that shows every
class the panorama sees, so the answer is known.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from localization.bench.pairs import PairsConfig, load_pairs, run_pairs
from localization.cli.bench import localize_bench_command, localize_pairs_command
from localization.paper.match import localize
from osmseg.errors import DatasetError

AERIAL = (400, 400)
GROUND = (616, 112)
TRUTH = (305.0, 105.0)


def _aerial_lines() -> list[str]:
    """Buildings and roads everywhere on a 50 px lattice; trees and pavement only near TRUTH."""
    lines = []
    for i, x in enumerate(range(25, 400, 50)):
        for j, y in enumerate(range(25, 400, 50)):
            lines.append(f"{x} {y} {'Building' if (i + j) % 2 else 'Road'}")
    lines += ["300 100 Tree", "312 110 Pavement", "295 112 Tree"]
    return lines


def _ground_lines() -> list[str]:
    return ["100 60 Building", "140 80 Road", "300 70 Building", "330 90 Road", "480 50 Tree", "500 70 Pavement",
            "520 52 Tree"]


def write_pairs(root: Path, names: tuple[str, ...] = ("p1", "p2"), *, images: bool = True,
                truth: bool = True, sep: str = " ") -> Path:
    for side, lines, size in (("aerial", _aerial_lines(), AERIAL), ("ground", _ground_lines(), GROUND)):
        (root / side).mkdir(parents=True, exist_ok=True)
        for name in names:
            text = "\n".join(line.replace(" ", sep, 2) for line in lines) + "\n"
            (root / side / f"{name}.txt").write_text(text)
            if images:
                Image.new("RGB", size).save(root / side / f"{name}.jpg")
    if truth:
        (root / "truth.csv").write_text("name,x,y\n" + "".join(f"{n},{TRUTH[0]},{TRUTH[1]}\n" for n in names))
    return root


def test_what_is_left_out_of_the_pairs_is_said_in_agreeing_words(tmp_path: Path,
                                                                 caplog: pytest.LogCaptureFixture) -> None:
    """One lonely landmark file, one unknown name in truth.csv, one pair without its truth: each said
    in the singular (they said '1 landmark files have', '1 pairs that do not exist', '1 pairs have')."""
    root = write_pairs(tmp_path / "pairs", ("p1", "p2"))
    (root / "aerial" / "p3.txt").write_text((root / "aerial" / "p1.txt").read_text())
    (root / "truth.csv").write_text(f"name,x,y\np1,{TRUTH[0]},{TRUTH[1]}\nzz,{TRUTH[0]},{TRUTH[1]}\n")
    with caplog.at_level("WARNING"):
        assert [p.name for p in load_pairs(root)] == ["p1", "p2"]
    said = [r.getMessage() for r in caplog.records]
    assert any(m.startswith("1 landmark file has no partner on the other side and is skipped: p3") for m in said), said
    assert any(m.startswith("truth.csv names 1 pair that does not exist (zz)") for m in said), said
    assert "1 pair has no line in truth.csv: its truth is the aerial image's centre" in said, said


def test_pairs_are_read_with_sizes_from_images_and_truth_from_csv(tmp_path: Path) -> None:
    pairs = load_pairs(write_pairs(tmp_path / "pairs"))
    assert [p.name for p in pairs] == ["p1", "p2"]
    p = pairs[0]
    assert (p.aerial.width, p.aerial.height, p.ground.width, p.ground.height) == (*AERIAL, *GROUND)
    assert p.ground.panorama and not p.aerial.panorama and p.truth == TRUTH
    names = [p.aerial.classes[c] for c in p.aerial.cls]
    assert names.count("vegetation") == 2 and names.count("footway") == 1  # Tree, Pavement via the camvid dictionary
    # without truth.csv the viewpoint is the aerial centre (CVUSA), without images the sizes come from the config
    bare = write_pairs(tmp_path / "bare", ("q",), images=False, truth=False)
    [q] = load_pairs(bare, PairsConfig(aerial_size=AERIAL, ground_size=GROUND))
    assert q.truth == (199.5, 199.5)


def test_the_authors_comma_files_a_bom_in_truth_csv_and_upper_case_suffixes(tmp_path: Path) -> None:
    spaced = load_pairs(write_pairs(tmp_path / "spaced"))
    root = write_pairs(tmp_path / "commas", sep=",", truth=False)
    (root / "truth.csv").write_bytes("\ufeffName, X, Y\np1, 305, 105\np2,305,105\n".encode())
    (root / "ground" / "p2.txt").rename(root / "ground" / "p2.TXT")
    commas = load_pairs(root)
    assert [p.name for p in commas] == ["p1", "p2"]
    for a, b in zip(spaced, commas):
        assert np.array_equal(a.aerial.xy, b.aerial.xy) and np.array_equal(a.ground.cls, b.ground.cls)
        assert b.truth == TRUTH
    # a given size wins over the image beside the file (as in osmseg localize)
    [big] = load_pairs(write_pairs(tmp_path / "sized", ("s",)), PairsConfig(aerial_size=(800, 600)))
    assert (big.aerial.width, big.aerial.height) == (800, 600)


def test_run_pairs_finds_the_only_place_that_shows_every_class(tmp_path: Path) -> None:
    config = PairsConfig()
    results = run_pairs(load_pairs(write_pairs(tmp_path / "pairs"), config), config, tmp_path / "out")
    s = results["summary"]
    assert results["unit"] == "px" and list(s["recall_at"]) == ["25", "50", "100"]
    assert s["n"] == 2 and s["answered"] == 2
    for rec in results["viewpoints"]:
        half = rec["window_px"] / 2  # the MAP's window holds the truth
        assert abs(rec["map"][0] - TRUTH[0]) <= half and abs(rec["map"][1] - TRUTH[1]) <= half, rec
        assert rec["error"] == rec["error_px"] and rec["centre_guess"] == pytest.approx(np.hypot(305 - 199.5,
                                                                                                  105 - 199.5), abs=1e-3)
    assert s["recall_at"]["100"] == 1.0 and s["median_error"] < results["baselines"]["random_guess_mean"] / 3
    pair = load_pairs(tmp_path / "pairs")[0]  # a random candidate's expected error, recomputed
    loc = localize(pair.aerial, pair.ground)
    expected = np.hypot(loc.candidates[:, 0] - TRUTH[0], loc.candidates[:, 1] - TRUTH[1]).mean()
    assert results["viewpoints"][0]["candidate_guess"] == pytest.approx(expected, abs=1e-3)
    assert results["baselines"]["random_candidate_median"] == pytest.approx(expected, abs=1e-3)
    assert [len(results["by_num_classes"][k]["subsets"]) for k in "234"] == [6, 4, 1]
    on_disk = json.loads((tmp_path / "out" / "results.json").read_text())
    assert on_disk["summary"] == s and on_disk["kind"] == "annotated pairs"
    for png in ("errors.png", "classes.png"):
        with Image.open(tmp_path / "out" / png) as im:
            assert im.format == "PNG" and im.size[0] > 300


def test_cli_on_pairs_in_pixels_and_in_metres(tmp_path: Path) -> None:
    root = write_pairs(tmp_path / "pairs")
    runner = CliRunner()
    res = runner.invoke(localize_pairs_command, [str(root), "--out", str(tmp_path / "a"), "--no-plots",
                                                 "--methods", "paper"], obj={"verbosity": 0})
    assert res.exit_code == 0, res.output
    assert res.stdout.strip() == str(tmp_path / "a" / "results.json")
    assert "2 annotated pairs" in res.stderr and "@100 px" in res.stderr
    res = runner.invoke(localize_pairs_command, [str(root), "--out", str(tmp_path / "b"), "--no-plots",
                                                 "--aerial-resolution", "0.25", "--no-subsets", "--methods", "paper"],
                        obj={"verbosity": -1})
    assert res.exit_code == 0, res.output
    a = json.loads((tmp_path / "a" / "results.json").read_text())
    b = json.loads((tmp_path / "b" / "results.json").read_text())
    assert b["unit"] == "m" and list(b["by_num_classes"]) == ["4"]
    # the default compares the profile method (it needs the resolution) with the paper method
    res = runner.invoke(localize_pairs_command, [str(root), "--out", str(tmp_path / "c"), "--no-plots"],
                        obj={"verbosity": 0})
    assert res.exit_code == 2 and "--aerial-resolution" in res.stderr and "--methods paper" in res.stderr
    assert not (tmp_path / "c").exists()
    res = runner.invoke(localize_pairs_command, [str(root), "--out", str(tmp_path / "d"), "--no-plots",
                                                 "--aerial-resolution", "0.25", "--no-subsets"], obj={"verbosity": 0})
    assert res.exit_code == 0, res.output
    d = json.loads((tmp_path / "d" / "results.json").read_text())
    assert set(d["methods"]) == {"profile", "paper"} and d["settings"]["methods"] == ["profile", "paper"]
    # the summary is the profile method's alone: its errors and times, no paper candidates or subsets
    assert d["summary"]["median_error"] == d["methods"]["profile"]["median_error"]
    assert d["baselines"]["random_candidate_mean"] is None and list(d["by_num_classes"]) == ["4"]
    assert all(v["localize_s"] == v["methods"]["profile"]["localize_s"] for v in d["viewpoints"])
    res = runner.invoke(localize_pairs_command, [str(root), "--out", str(tmp_path / "e"), "--aerial-resolution", "0.25",
                                                 "--methods", "profile", "--window", "50"], obj={"verbosity": 0})
    assert res.exit_code == 2 and "--window applies to the paper method: add paper to --method" in res.stderr
    assert b["summary"]["mean_error"] == pytest.approx(0.25 * a["summary"]["mean_error"], abs=1e-3)


@pytest.mark.parametrize("case, words", [
    ("no sizes", "--aerial-size"),
    ("bad truth", "truth.csv:2"),
    ("nothing paired", "both aerial/ and ground/"),
    ("bad size", "WIDTHxHEIGHT"),
    ("outside", "outside the 400x400 image"),
    ("render option", "No such option '--viewpoints'"),
    ("truth outside", "is outside its 400x400 aerial image"),
])
def test_cli_bad_pairs_give_one_line(tmp_path: Path, case: str, words: str) -> None:
    root = tmp_path / "pairs"
    args: list[str] = []
    if case == "no sizes":
        write_pairs(root, images=False)
    elif case == "bad truth":
        write_pairs(root)
        (root / "truth.csv").write_text("name,x,y\np1,three,4\n")
    elif case == "nothing paired":
        write_pairs(root)
        for f in (root / "ground").glob("*.txt"):
            f.rename(f.with_name("other.txt"))
    elif case == "bad size":
        write_pairs(root, images=False)
        args = ["--aerial-size", "400by400"]
    elif case == "truth outside":
        write_pairs(root)
        (root / "truth.csv").write_text("name,x,y\np1,3000,-5\n")
    elif case == "render option":
        write_pairs(root)
        args = ["--viewpoints", "5", "--confusion", "0.1"]
    else:
        write_pairs(root)
        (root / "aerial" / "p1.txt").write_text("450 10 Building\n")
    res = CliRunner().invoke(localize_pairs_command, [str(root), "--out", str(tmp_path / "o"), "--methods", "paper",
                                                      *args], obj={"verbosity": 0})
    assert res.exit_code in (1, 2) and words in res.stderr, res.output
    errors = [line for line in res.stderr.splitlines() if line.startswith("Error:")]
    assert "Traceback" not in res.output and len(errors) == 1 and words in errors[0]
    assert not (tmp_path / "o" / "results.json").exists()


def test_load_pairs_rejects_a_folder_without_the_layout(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="aerial/ and ground/"):
        load_pairs(tmp_path)


def test_each_protocol_has_its_own_command_and_each_points_to_the_other(tmp_path: Path) -> None:
    """localize-bench renders views of a dataset or mask; localize-pairs scores annotated pairs.
    Given the other's folder, each says which command to run, in one line, and writes nothing."""
    root = write_pairs(tmp_path / "pairs")
    res = CliRunner().invoke(localize_bench_command, [str(root), "--out", str(tmp_path / "a"), "--methods", "paper"],
                             obj={"verbosity": 0})
    assert res.exit_code == 2 and f"osmseg localize-pairs {root} --out {tmp_path / 'a'}" in res.stderr, res.output
    plain = tmp_path / "plain"
    plain.mkdir()
    res = CliRunner().invoke(localize_pairs_command, [str(plain), "--out", str(tmp_path / "b")], obj={"verbosity": 0})
    assert res.exit_code == 2 and f"osmseg localize-bench {plain}" in res.stderr, res.output
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    res = CliRunner().invoke(localize_pairs_command, ["--help"])
    assert "--viewpoints" not in res.output and "--aerial-size" in res.output  # only its own options
