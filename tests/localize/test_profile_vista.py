"""The vista cell (localization.profile.profiles): where a view's sky comes down to the horizon, nothing stands.

A constructed district holds the same street corner twice: the same road, houses and trees
within 60 m, so the method's ground rows cannot tell the copies apart. Only one copy is
ringed by houses 64-72 m away (the road passing through), where the view taken at the other
copy sees open sky down to the horizon. The vista reads that; without it the search is "not sure" between them.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
from click.testing import CliRunner
from PIL import Image
from test_loc_render import CLASSES, GRASS, RES, ROAD, SKY, TABLE, TREE, B

from localization.bench.render import RenderConfig, render_panorama
from localization.common.landmarks import landmarks_from_mask, panorama_table
from localization.common.views import OTHER, Camera, semantic_map
from localization.profile.method import profile_index, profile_query, run_profile
from localization.profile.profiles import MASK_MIN_CONFIDENCE, AerialMaskIndex, without_vista
from localization.profile.search import ProfileConfig
from osmseg.cli.main import cli

TILE = 400        # px (200 m) per copy of the corner
CENTRE = (200.0, 200.0)


def corner() -> np.ndarray:
    """A street corner: a north-south road, an east-west one ending at it, houses and trees within 50 m."""
    m = np.full((TILE, TILE), GRASS, np.uint8)
    m[:, 188:212] = ROAD                          # 12 m wide, north-south
    m[190:210, 100:188] = ROAD                    # a side street to the west
    for x, y, w, h in ((140, 140, 30, 30), (230, 120, 40, 50), (120, 230, 40, 30), (240, 240, 30, 40)):
        m[y:y + h, x:x + w] = B
    m[150:170, 250:262] = TREE
    return m


def district() -> np.ndarray:
    """Two copies of :func:`corner` side by side; the right one is ringed by houses 64-72 m from its centre."""
    left, right = corner(), corner()
    for lo, hi in ((56, 72), (328, 344)):         # a square ring of houses 64-72 m out, the road passing through
        right[lo:hi, 56:344] = B
        right[56:344, lo:hi] = B
    right[:, 188:212] = ROAD
    return np.concatenate([left, np.full((TILE, 200), GRASS, np.uint8), right], axis=1)


def view(mask: np.ndarray, xy: tuple[float, float], heading: float = 0.0):
    pano = render_panorama(mask, TABLE, RES, xy, RenderConfig(heading_deg=heading, far="sky"))
    return semantic_map(pano.labels, panorama_table(TABLE), CLASSES), Camera(1232, 224, camera_height_m=2.0)


def test_the_query_claims_open_sky_only_where_its_sky_meets_the_horizon() -> None:
    """East of the left corner's centre is open for 100 m, north and south lie along the road;
    the vista cell has mass there and none where a house stands in front, the same at every camera
    height tried, and a 90° photo's only within its field of view; dropping it gives the query
    built without a vista, exactly."""
    sem, camera = view(district(), CENTRE)
    q = profile_query(sem, camera, ProfileConfig(vista_weight=4))
    assert q.vista and q.radii_m[-1] == 75.0 and q.q.shape[1] == len(q.radii_m) + 1
    far = q.q[:, len(q.radii_m) - 1]                     # (C, A) in compass azimuths, heading 0
    other = q.classes.index(OTHER)
    assert far.sum() == far[other].sum() > 0             # the claim sits on "other" alone
    assert far[other, 18] == 4.0                          # due east (bin 18 of 72): open, the full weight
    assert far[other, 0] == 4.0 and far[other, 36] == 4.0  # along the road, north and south
    assert far[other, 63] == 0.0                          # north-west (315 degrees): the house at (140, 140)
    poses = profile_query(sem, camera, ProfileConfig(vista_weight=4, camera_heights=(1.5, 2.0, 2.5)))
    assert poses.vista and all(v.vista and np.array_equal(v.q[:, -2], q.q[:, -2]) for v in poses.variants)
    photo = Camera(308, 224, hfov_deg=90.0, camera_height_m=2.0)
    cols = slice(616 - 154, 616 + 154)                   # the panorama's middle 90 degrees, facing north
    narrow = dataclasses.replace(sem, labels=sem.labels[:, cols], standing=sem.standing[:, cols], sky=sem.sky[:, cols])
    p = profile_query(narrow, photo, ProfileConfig(vista_weight=4))
    seen = p.q[:, len(p.radii_m) - 1].sum(axis=0) > 0
    assert seen[0] and not seen[18] and not seen[36] and seen.sum() <= 19     # within the photo's 90 degrees only
    plain = profile_query(sem, camera, ProfileConfig(vista_weight=0))
    stripped = without_vista(q)
    assert not plain.vista and np.array_equal(stripped.q, plain.q) and np.array_equal(stripped.radii_m, plain.radii_m)


def test_the_aerial_side_reads_what_stands_first_within_the_vista() -> None:
    """At the right copy's centre the houses 64-72 m east stand in the vista cell, the road north
    reads "other" (every ground class merged); a ray that leaves the image between 60 and 75 m with nothing
    in its way predicts nothing there."""
    mask = district()
    index = AerialMaskIndex(semantic_map(mask, TABLE, CLASSES), RES)
    radii = np.array([10.0, 60.0, 75.0])
    right = (TILE + 200 + CENTRE[0], CENTRE[1])
    lab, valid = index.labels(np.array([right, (5.0, 200.0)]), radii, 72, vista=True)
    building, other = index.classes.index("building"), index.classes.index(OTHER)
    assert lab[0, 2, 18] == building and valid[0, 2, 18]      # east: the row of houses at 64 m
    assert lab[0, 1, 18] != building                          # ...which the 60 m radius does not reach
    lab, valid = index.labels(np.array([(130.0, 200.0)]), radii, 72, vista=True)   # 65 m from the west edge
    assert valid[0, 1, 54] and not valid[0, 2, 54]            # looking west: 60 m inside the image, 75 m not
    assert lab[0, 2, 0] == other and valid[0, 2, 0]          # north, along the road: nothing stands
    plain, _ = index.labels(np.array([right]), radii, 72)
    assert plain[0, 2, 0] == index.classes.index("road")      # without the vista: the ground class at 75 m


def test_a_look_alike_that_differs_only_beyond_60_m_is_told_apart_by_the_open_sky() -> None:
    """The view at the left corner: with the vista it is found within a metre and answered; without
    it both copies fit as well and the answer is "not sure", naming the other copy 300 m away.
    The same holds with the heading unknown."""
    mask = district()
    index = profile_index(semantic_map(mask, TABLE, CLASSES), RES)
    for heading_deg, seen_at in ((0.0, 0.0), (None, 37.0)):
        sem, camera = view(mask, CENTRE, seen_at)
        config = ProfileConfig(heading_deg=heading_deg, vista_weight=4)
        loc = run_profile(config, index, sem, camera)
        assert not loc.unanswered and loc.confidence >= MASK_MIN_CONFIDENCE, loc.reason
        assert math.hypot(loc.map_xy[0] - CENTRE[0], loc.map_xy[1] - CENTRE[1]) * RES <= 1.0
        if heading_deg is None:
            assert abs((loc.heading_deg - seen_at + 180) % 360 - 180) <= 5.0
        blind = run_profile(dataclasses.replace(config, vista_weight=0), index, sem, camera)
        assert blind.unanswered and blind.reason.startswith("not sure") and "300 m away" in blind.reason


def test_a_view_without_sky_and_aerial_points_get_no_vista(caplog) -> None:
    """A view whose table has no sky says nothing about the horizon, and a vista within the ground
    rows' range is none (each said in the log); landmark points cannot say that nothing stands, so
    the search drops the cell for them and answers as without it."""
    mask = district()
    sem, camera = view(mask, CENTRE)
    skyless = dataclasses.replace(sem, sky=None)
    with caplog.at_level("WARNING", logger="localization.profile.method"):
        assert not profile_query(skyless, camera, ProfileConfig(vista_weight=4)).vista
        assert not profile_query(sem, camera, ProfileConfig(vista_weight=4, max_range_m=80.0)).vista
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 2 and "no sky class" in said[0] and "within the farthest ground distance" in said[1], said
    assert SKY in np.unique(render_panorama(mask, TABLE, RES, CENTRE, RenderConfig(far="sky")).labels)
    points = profile_index(landmarks_from_mask(corner()[100:300, 100:300], TABLE, CLASSES, mode="grid", stride=20,
                                               min_size=20), RES)
    with_vista = run_profile(ProfileConfig(min_kappa=-1.0, vista_weight=4), points, sem, camera)
    without = run_profile(ProfileConfig(min_kappa=-1.0, vista_weight=0), points, sem, camera)
    assert with_vista.map_xy == without.map_xy and with_vista.kappa == without.kappa


def test_the_command_line_takes_the_vista_weight(tmp_path: Path) -> None:
    """``osmseg localize --vista-weight 4`` on the district and the view saved as files (its sky as
    the ground table's id 14): the left corner, answered; without it "not sure". A negative weight,
    or the vista with the paper method, is refused in one line (exit 2)."""
    mask = district()
    pano = render_panorama(mask, TABLE, RES, CENTRE, RenderConfig(far="sky"))
    Image.fromarray(mask).save(tmp_path / "district.png")
    Image.fromarray(pano.labels.astype(np.uint8)).save(tmp_path / "view.png")
    base = ["localize", "--aerial", str(tmp_path / "district.png"), "--aerial-table", "classes13.toml",
            "--aerial-resolution", str(RES), "--ground", str(tmp_path / "view.png"), "--ground-table", "classes13.toml",
            "--ground-landmarks", "aerial13", "--truth", f"{CENTRE[0]},{CENTRE[1]}", "--json"]
    res = CliRunner().invoke(cli, [*base, "--vista-weight", "4"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["truth"]["error_m"] <= 1.0 and out["confidence"] >= MASK_MIN_CONFIDENCE, out
    blind = json.loads(CliRunner().invoke(cli, base).stdout)
    assert blind["confidence"] < MASK_MIN_CONFIDENCE, blind
    bad = CliRunner().invoke(cli, [*base, "--vista-weight", "-1"])
    assert bad.exit_code == 2 and "--vista-weight" in bad.output
    bad = CliRunner().invoke(cli, [*base, "--vista-weight", "4", "--method", "paper"])
    assert bad.exit_code == 2 and "--method profile" in bad.output
