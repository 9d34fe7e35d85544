"""``osmseg build`` with its HTTP cache on a disk that fills up, on a real (tmpfs) file system.

The cache folder is a small tmpfs mounted in a private mount namespace (``unshare``; as root,
or as any user where user namespaces are allowed), filled nearly to the brim by a filler file.
The build must stop with one ``Error:`` line naming the cache and what to do, exit 1, keep
what it finished; once space is freed (the filler removed) the same command finishes the
build, byte-identical to a build that never saw a full disk. The build replays the demo's
recorded traffic, so no server is needed.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO_ROOT

CASSETTE = REPO_ROOT / "osmseg" / "demo" / "helsinki.yaml.gz"


def can_mount_tmpfs(tmp_path: Path) -> list[str] | None:
    """The command prefix that runs a shell in a private mount namespace, or None."""
    if shutil.which("unshare") is None:
        return None
    prefix = ["unshare", "-m"] if os.geteuid() == 0 else ["unshare", "-Urm"]
    probe = tmp_path / "probe"
    probe.mkdir()
    ok = subprocess.run([*prefix, "sh", "-c", f"mount -t tmpfs -o size=64k tmpfs {probe}"],
                        capture_output=True).returncode == 0
    return prefix if ok else None


def build_twice_on_a_full_disk(prefix: list[str], tmp_path: Path, build: list[str], out: Path, size: str, fill: str,
                               env: dict[str, str] | None = None) -> tuple[str, str, str, str]:
    """Run ``build`` (``--out out``, cache on a tmpfs of ``size`` filled with ``fill`` bytes), free the
    space, run it again; the first run's stderr and exit status, then the second's."""
    disk = tmp_path / "disk"
    disk.mkdir()
    command = " ".join(f"'{a}'" for a in [*build, "--out", str(out), "--cache-dir", str(disk / "cache")])
    script = f"""
        mount -t tmpfs -o size={size} tmpfs {disk}
        head -c {fill} /dev/zero > {disk}/filler
        {command} 2> {tmp_path}/first.err; echo $? > {tmp_path}/first.code
        ls -A {out} > {tmp_path}/first.ls
        rm {disk}/filler                               # the user frees space
        {command} 2> {tmp_path}/second.err; echo $? > {tmp_path}/second.code
    """
    subprocess.run([*prefix, "sh", "-c", script], env=env, check=True, timeout=600)
    return tuple((tmp_path / name).read_text() for name in  # type: ignore[return-value]
                 ("first.err", "first.code", "second.err", "second.code"))


def tree_bytes(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and ".osmseg-build" not in p.parts}


def test_a_full_cache_disk_stops_in_one_line_and_the_rerun_after_freeing_space_finishes(tmp_path: Path) -> None:
    prefix = can_mount_tmpfs(tmp_path)
    if prefix is None:
        pytest.skip("cannot mount a tmpfs here (needs root or user namespaces)")
    build = [sys.executable, "-m", "osmseg", "-q", "build", "--city", "Helsinki", "--samples", "4", "--seed", "0", "--no-overlap",
             "--imagery", "bing", "--osm", "api", "--replay", str(CASSETTE)]
    env = dict(os.environ, BING_MAPS_KEY="demo-key-not-secret")
    clean = tmp_path / "clean"
    done = subprocess.run([*build, "--out", str(clean), "--cache-dir", str(tmp_path / "clean-cache")], env=env,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr

    out = tmp_path / "ds"
    # 13000k of 16m leaves ~3 MB: the cache needs ~10.5 MB
    first, code, second, second_code = build_twice_on_a_full_disk(prefix, tmp_path, build, out, "16m", "13000k", env)
    assert code.strip() == "1", first
    lines = first.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error:"), first
    assert "Traceback" not in first and "cache" in lines[0] and ("full" in lines[0] or "space" in lines[0])
    assert "run the same command again" in lines[0]
    assert "manifest.json" not in (tmp_path / "first.ls").read_text().split()  # not finished, nothing faked

    assert second_code.strip() == "0", second
    assert tree_bytes(out) == tree_bytes(clean)
    assert json.loads((out / "manifest.json").read_text())["summary"]["accepted"] == 4


def test_a_full_disk_while_cutting_a_local_osm_file_is_one_line_and_the_rerun_finishes(
        tmp_path: Path, imagery_tif: Path) -> None:
    """Cutting the samples' boxes out of a local OSM file onto a full disk: osmium cannot survive a
    write that fails (the process would abort), so the room is checked first and the build stops
    with the one-line disk-full error; with space freed, the same command finishes."""
    from conftest import TINYCITY, TINYCITY_CENTRE

    prefix = can_mount_tmpfs(tmp_path)
    if prefix is None:
        pytest.skip("cannot mount a tmpfs here (needs root or user namespaces)")
    lon, lat = TINYCITY_CENTRE
    build = [sys.executable, "-m", "osmseg", "-q", "build", "--lat", str(lat), "--lon", str(lon), "--radius-km", "0.08",
             "--samples", "2", "--seed", "1", "--imagery", f"geotiff:{imagery_tif}", "--osm", str(TINYCITY)]
    clean = tmp_path / "clean"
    done = subprocess.run([*build, "--out", str(clean), "--cache-dir", str(tmp_path / "clean-cache")],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr

    out = tmp_path / "ds"
    # 2040k of 2m leaves ~8 KB: less than the region file itself
    first, code, second, second_code = build_twice_on_a_full_disk(prefix, tmp_path, build, out, "2m", "2040k")
    assert code.strip() == "1", first
    lines = first.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error:") and "disk is full" in lines[0], first
    assert second_code.strip() == "0", second
    assert tree_bytes(out) == tree_bytes(clean)
