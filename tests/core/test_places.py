"""City presets, areas and the sample grid: what a user sees when choosing where to sample."""

from __future__ import annotations

import math

import mercantile
import numpy as np
import pytest

from osmseg.errors import ConfigError, UnknownPlaceError
from osmseg.grid import ground_resolution, sample_grid
from osmseg.places import Area, find_preset, load_presets, parse_bbox

URBAN = ["Berlin", "Boston", "Chicago", "London", "Manhattan", "Paris", "Rome", "San Francisco", "São Paulo"]
RURAL = ["Carver", "Lincoln", "Palmer", "Waynesville", "Zolfo Springs"]


def test_presets_hold_every_dissertation_area_and_three_added_rural_ones() -> None:
    presets = load_presets()
    for name in URBAN + RURAL:
        assert name in presets
    rural = [p for p in presets.values() if p.kind == "rural"]
    assert len(rural) == 8
    assert sum(p.source == "osmseg" for p in rural) == 3


@pytest.mark.parametrize("typed", ["sao paulo", "SÃO PAULO", "  são   paulo ", "Sao-Paulo"])
def test_city_names_match_regardless_of_case_and_accents(typed: str) -> None:
    assert find_preset(typed).name == "São Paulo"


def test_unknown_city_lists_the_presets() -> None:
    with pytest.raises(UnknownPlaceError) as err:
        find_preset("Atlantis")
    message = str(err.value)
    assert "Atlantis" in message and "Berlin" in message and "Zolfo Springs" in message
    assert "\n" not in message
    assert isinstance(err.value, KeyError) and isinstance(err.value, ConfigError)


def test_preset_coordinates_are_in_the_right_places() -> None:
    p = load_presets()
    assert 52 < p["Berlin"].lat < 53 and 13 < p["Berlin"].lon < 14
    assert p["São Paulo"].lat < 0 and p["São Paulo"].lon < 0
    assert 27 < p["Zolfo Springs"].lat < 28


def test_disc_centres_are_seeded_and_within_the_radius() -> None:
    area = Area(name="x", lat=52.52, lon=13.405, radius_km=3.0)
    a = area.random_centres(np.random.default_rng(7), 200)
    b = area.random_centres(np.random.default_rng(7), 200)
    assert a == b
    for lon, lat in a:
        dy = (lat - 52.52) * 111.195
        dx = (lon - 13.405) * 111.195 * math.cos(math.radians(52.52))
        assert math.hypot(dx, dy) <= 3.0 + 0.01
    # uniform over the disc: about a quarter of the points fall inside half the radius
    inner = sum(math.hypot((lon - 13.405) * 67.7, (lat - 52.52) * 111.2) < 1.5 for lon, lat in a)
    assert 25 < inner < 80


def test_bbox_centres_stay_inside_the_box() -> None:
    box = parse_bbox("13.3,52.4,13.5,52.6")
    pts = Area(name="b", lat=52.5, lon=13.4, bbox=box).random_centres(np.random.default_rng(1), 100)
    assert all(box.west <= lon <= box.east and box.south <= lat <= box.north for lon, lat in pts)


@pytest.mark.parametrize("bad", ["1,2,3", "a,b,c,d", "10,50,9,51", "0,-89,1,-88"])
def test_bad_bbox_is_a_one_line_config_error(bad: str) -> None:
    with pytest.raises(ConfigError) as err:
        parse_bbox(bad)
    assert "\n" not in str(err.value) and "--bbox" in str(err.value)


@pytest.mark.parametrize("bad,meant", [("13.5,52.4,13.3,52.6", "13.3,52.4,13.5,52.6"),    # east first
                                       ("13.3,52.6,13.5,52.4", "13.3,52.4,13.5,52.6"),    # north second
                                       ("-33.9,151.2,-33.8,151.3", "151.2,-33.9,151.3,-33.8"),  # lat, lon
                                       ("-33.8,151.3,-33.9,151.2", "151.2,-33.9,151.3,-33.8"),  # and backwards
                                       ("151.20935,-33.87,151.20912,-33.86",                     # digits kept
                                        "151.20912,-33.87,151.20935,-33.86")])
def test_a_bbox_given_in_the_wrong_order_is_answered_with_the_right_one(bad: str, meant: str) -> None:
    with pytest.raises(ConfigError) as err:
        parse_bbox(bad)
    assert f"did you mean --bbox {meant}" in str(err.value)
    parse_bbox(meant)   # and what it suggests is a box


@pytest.mark.parametrize("bad", ["13.5,52.4,13.3,89", "0,-89,1,-88", "179.5,-17,-179.5,-16"])
def test_a_bbox_no_reordering_mends_gets_no_guess(bad: str) -> None:
    with pytest.raises(ConfigError) as err:
        parse_bbox(bad)
    assert "did you mean" not in str(err.value) and "\n" not in str(err.value)


def test_grid_is_5x5_tiles_around_the_centre_and_georeferenced() -> None:
    g = sample_grid(13.405, 52.52, 18)
    centre = mercantile.tile(13.405, 52.52, 18)
    assert g.tiles[12] == centre and g.tiles[0] == mercantile.Tile(centre.x - 2, centre.y - 2, 18)
    # the centre point falls inside the middle tile's pixels
    col, row = ~g.transform @ mercantile.xy(13.405, 52.52)
    assert 512 <= col < 768 and 512 <= row < 768
    # pixel size equals Web Mercator tile resolution, ground size shrinks with cos(lat)
    assert g.transform.a == pytest.approx(g.pixel_size) and g.transform.e == pytest.approx(-g.pixel_size)
    assert g.ground_resolution == pytest.approx(ground_resolution(52.52, 18))
    assert g.bbox.west < 13.405 < g.bbox.east and g.bbox.south < 52.52 < g.bbox.north


def test_grid_is_shifted_inward_at_the_antimeridian_and_refuses_even_sizes() -> None:
    g = sample_grid(179.9999, 0.0, 3)
    assert {t.x for t in g.tiles} == {3, 4, 5, 6, 7}
    assert mercantile.tile(179.9999, 0.0, 3) in g.tiles
    assert g.bbox.west < g.bbox.east
    with pytest.raises(ValueError):
        sample_grid(0, 0, 10, size=4)
