"""A region's block is searched in its core alone, its rays reading the whole block (localization/region/search.py).

The profile method's ``within`` box: only the coarse positions inside it are searched, while what
the rays read around a position is the whole image's. On the district of two look-alike street
corners (tests/localize/test_profile_vista.py), the view at the left corner is "not sure" over the
whole district; searched within either copy's box it is found at that copy's centre, and no
candidate lies outside the box (and the one coarse cell a refinement may step). A block's box is
its core, all but its outer ring of tiles, and a coarse cell around it.
"""

from __future__ import annotations

import math

import mercantile
import numpy as np
from test_loc_render import CLASSES, RES, TABLE
from test_profile_vista import CENTRE, TILE, district, view

from localization.common.views import semantic_map
from localization.profile.method import profile_index, run_profile
from localization.profile.search import ProfileConfig
from localization.region.search import RegionConfig, _core_box, region_blocks
from osmseg.grid import pixel_lonlat


def test_a_search_within_a_box_finds_the_copy_in_it_and_nothing_outside() -> None:
    mask = district()
    index = profile_index(semantic_map(mask, TABLE, CLASSES), RES)
    sem, camera = view(mask, CENTRE)
    config = ProfileConfig(heading_deg=0.0)
    whole = run_profile(config, index, sem, camera)
    assert whole.unanswered and whole.reason.startswith("not sure"), whole.reason  # two copies fit alike
    step = index.grid_m / RES
    right = CENTRE[0] + TILE + 200                                   # the other copy, 300 m east
    for centre_x in (CENTRE[0], right):
        box = (centre_x - 180, 20.0, centre_x + 180, TILE - 20.0)
        loc = run_profile(config, index, sem, camera, within=box)
        assert not loc.unanswered, loc.reason
        assert math.hypot(loc.map_xy[0] - centre_x, loc.map_xy[1] - CENTRE[1]) * RES <= 1.0
        xy = np.array([(x, y) for x, y, _ in loc.top_k])
        assert (xy[:, 0] >= box[0] - step).all() and (xy[:, 0] <= box[2] + step).all(), xy
        assert (xy[:, 1] >= box[1] - step).all() and (xy[:, 1] <= box[3] + step).all(), xy
    none = run_profile(config, index, sem, camera, within=(5000.0, 5000.0, 5100.0, 5100.0))
    assert none.unanswered and "no position" in none.reason


def test_a_blocks_box_is_its_core_and_a_cell_around_it() -> None:
    """Kotka's blocks (5 x 5 tiles): the box without its margin holds exactly the pixels whose tile is
    a core tile, as the block's candidates are kept (``_in_core``'s test: the tile of the pixel's place)."""
    grid, core = region_blocks(RegionConfig((26.94, 60.53, 26.95, 60.535), zoom=18))[0]
    assert len(core) == 9 and grid.size == 5
    x0, y0, x1, y1 = _core_box(grid, 0.0)
    b = grid.xy_bounds
    for px in (255.0, 255.4, 256.0, 600.0, 1023.0, 1023.4, 1024.0):
        lon, lat = pixel_lonlat((b.left, b.bottom, b.right, b.top), (grid.height, grid.width), (px, 600.0))
        tile = mercantile.tile(lon, lat, grid.zoom)
        assert ((tile.x, tile.y) in core) == (x0 <= px <= x1), px
    assert _core_box(grid, 14.0) == (x0 - 14.0, y0 - 14.0, x1 + 14.0, y1 + 14.0)
