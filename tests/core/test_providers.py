"""Named imagery providers from xyzservices (``--imagery Esri.WorldImagery``).

Builds run through the real CLI and replay the vcrpy cassettes of tests/data/providers
(written by its data.py) with ``--replay``: no request leaves the machine.  Synthetic tiles
encode their position (red = 32 + 64 * (x % 3), green = 32 + 64 * (y % 3), blue = a diagonal
ramp), so the checks are "the pixels at tile (x, y)'s offset came from tile (x, y)".
Key hygiene is checked where a fixed https host allows it: through the real HTTP client and
on-disk cache with a replayed MapTiler tile, and for every key-needing catalogue entry on
the URLs osmseg sends, logs and records.
"""

from __future__ import annotations

import io
import json
import logging
from pathlib import Path

import mercantile
import numpy as np
import pytest
import xyzservices
import xyzservices.providers
from click.testing import CliRunner, Result
from conftest import TEST_DATA
from PIL import Image
from vcr.serialize import deserialize
from vcr.serializers import yamlserializer

from osmseg.cli.main import cli
from osmseg.errors import ConfigError
from osmseg.grid import TILE_SIZE, sample_grid
from osmseg.imagery import KEYLESS_DEFAULT, NamedProvider, make_provider
from osmseg.imagery.providers import (
    AERIAL_PROVIDERS,
    aerial_providers,
    catalogue,
    close_names,
    key_envs,
    tile_template,
    token_attributes,
)
from osmseg.imagery.xyz import fill_template
from osmseg.net.cassette import clean_url
from osmseg.net.http import HttpClient, HttpConfig
from osmseg.redact import redact

DATA = TEST_DATA / "providers"
ESRI_CASSETTE = DATA / "esri.yaml"
TINYCITY = TEST_DATA / "tinycity" / "tinycity.osm"
ZOOM = 18
CENTRE = mercantile.tile(24.94, 60.17, ZOOM)  # as in tests/data/providers/data.py
_B = mercantile.bounds(CENTRE)
LON, LAT = (_B.west + _B.east) / 2, (_B.south + _B.north) / 2
MAPTILER_KEY = "TEST-maptiler-key-6d1f0b"
ESRI_ATTRIBUTION = xyzservices.providers.Esri.WorldImagery["attribution"]


def recorded_tiles(cassette: Path) -> dict[tuple[int, int, int], bytes]:
    """JPEG bodies of the cassette's 200 tile answers by (z, x, y), read with vcrpy."""
    requests, responses = deserialize(cassette.read_text(), yamlserializer)
    tiles = {}
    for request, response in zip(requests, responses, strict=True):
        if response["status"]["code"] == 200:
            z, y, x = (int(p) for p in request.path.rsplit("/", 3)[1:])
            tiles[(z, x, y)] = response["body"]["string"]
    return tiles


def expected_colour(tile: mercantile.Tile, col: int, row: int) -> tuple[int, int, int]:
    return 32 + 64 * (tile.x % 3), 32 + 64 * (tile.y % 3), (col + row) // 2


def build(tmp_path: Path, imagery: str, *extra: str, env: dict[str, str | None] | None = None) -> Result:
    args = [
        "-q", "build", "--lat", str(LAT), "--lon", str(LON), "--radius-km", "0.005", "--samples", "1",
        "--seed", "1", "--imagery", imagery, "--osm", str(TINYCITY), "--out", str(tmp_path / "ds"),
        "--cache-dir", str(tmp_path / "cache"), "--replay", str(ESRI_CASSETTE), *extra,
    ]
    return CliRunner().invoke(cli, args, env=env)


def usage_error(result: Result) -> str:
    """The one ``Error:`` line of a usage error (exit 2, no traceback, no manifest)."""
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1, result.output
    return errors[0]


# -- through the CLI --------------------------------------------------------------------------


def test_build_with_esri_world_imagery_puts_every_tile_in_place(tmp_path: Path) -> None:
    result = build(tmp_path, "Esri.WorldImagery", "--min-classes", "1", "--max-unlabeled", "0.99")
    assert result.exit_code == 0, result.output
    out = tmp_path / "ds"
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["summary"]["accepted"] == 1
    imagery = manifest["imagery"]
    assert imagery["provider"] == "xyzservices" and imagery["name"] == "Esri.WorldImagery"
    assert imagery["template"] == (
        "https://server.arcgisonline.com/ArcGIS/rest/services/World_Imagery/MapServer/tile/{z}/{y}/{x}?blankTile=false"
    )
    assert imagery["attribution"] == ESRI_ATTRIBUTION and ESRI_ATTRIBUTION.startswith("Tiles (C) Esri")
    assert "terms before storing tiles" in imagery["terms"]
    attribution = (out / "ATTRIBUTION.md").read_text()
    assert "**Esri.WorldImagery**" in attribution and ESRI_ATTRIBUTION in attribution
    assert "check the provider's terms" in attribution

    recorded = recorded_tiles(ESRI_CASSETTE)
    sample = manifest["samples"][0]
    assert sample["imagery"]["name"] == "Esri.WorldImagery" and sample["imagery"]["no_imagery_tiles"] == []
    image = np.asarray(Image.open(out / "images" / f"{sample['name']}.png").convert("RGB"))
    assert image.shape == (5 * TILE_SIZE, 5 * TILE_SIZE, 3)
    for index, entry in enumerate(sample["tiles"]):
        tile = mercantile.Tile(entry["x"], entry["y"], entry["z"])
        row, col = divmod(index, 5)
        area = image[row * TILE_SIZE : (row + 1) * TILE_SIZE, col * TILE_SIZE : (col + 1) * TILE_SIZE]
        jpeg = np.asarray(Image.open(io.BytesIO(recorded[(tile.z, tile.x, tile.y)])).convert("RGB"))
        assert np.array_equal(area, jpeg), f"tile {tile} is not at row {row}, column {col}"
        for c, r in [(128, 128), (10, 200), (240, 16)]:  # and its pixels say they are that tile
            assert np.abs(area[r, c].astype(int) - expected_colour(tile, c, r)).max() <= 6, (tile, c, r)
    assert {(t["x"], t["y"]) for t in sample["tiles"]} == {(k[1], k[2]) for k in recorded}


def test_zoom_above_the_providers_max_zoom_is_a_usage_error(tmp_path: Path) -> None:
    result = build(tmp_path, "USGS.USImagery", "--zoom", "21", "--min-classes", "0", "--max-unlabeled", "1")
    line = usage_error(result)
    assert "--zoom 21 is above USGS.USImagery's highest zoom 20: use --zoom 20 or lower" in line
    assert not (tmp_path / "ds" / "manifest.json").exists()


def test_unknown_name_is_a_usage_error_with_close_names(tmp_path: Path) -> None:
    line = usage_error(build(tmp_path, "Esri.WorldImagry"))
    assert "unknown imagery 'Esri.WorldImagry'" in line and "close names: Esri.WorldImagery" in line
    assert "xyz:TEMPLATE" in line


def test_key_needing_provider_without_its_variable_is_a_usage_error(tmp_path: Path) -> None:
    line = usage_error(build(tmp_path, "MapTiler.Satellite", env={"MAPTILER_API_KEY": None}))
    assert "--imagery MapTiler.Satellite needs an API key: set MAPTILER_API_KEY" in line
    assert KEYLESS_DEFAULT in line


def test_no_imagery_and_no_bing_key_names_a_keyless_provider() -> None:
    with pytest.raises(ConfigError) as err:
        make_provider("bing", None, env={})
    message = str(err.value)
    assert "\n" not in message and "BING_MAPS_KEY" in message and "Basic keys no longer exist" in message
    assert f"--imagery {KEYLESS_DEFAULT}" in message
    with HttpClient(HttpConfig(retries=0)) as client:
        assert isinstance(make_provider(KEYLESS_DEFAULT, client, env={}), NamedProvider)


# -- keys -------------------------------------------------------------------------------------


def test_maptiler_key_is_sent_but_never_shown_logged_or_cached(tmp_path: Path, caplog) -> None:
    caplog.set_level(logging.DEBUG)
    env = {"MAPTILER_API_KEY": MAPTILER_KEY}
    grid = sample_grid(LON, LAT, ZOOM, size=1)
    config = HttpConfig(retries=0, cache_dir=tmp_path / "cache", cassette=DATA / "maptiler.yaml")
    with HttpClient(config) as client:
        sent: list[str] = []
        client._session.hooks["response"].append(lambda r, *a, **k: sent.append(r.request.url))
        provider = make_provider("maptiler satellite", client, env=env)
        imagery = provider.fetch(grid)
    # (requests-cache runs the session hooks a second time: the same URL twice)
    assert set(sent) == {f"https://api.maptiler.com/tiles/satellite-v2/18/{CENTRE.x}/{CENTRE.y}.jpg?key={MAPTILER_KEY}"}
    assert imagery.valid.all()
    assert np.abs(imagery.rgb[128, 128].astype(int) - expected_colour(CENTRE, 128, 128)).max() <= 6
    described = provider.describe()
    assert described["template"] == "https://api.maptiler.com/tiles/satellite-v2/{z}/{x}/{y}.jpg?key={env:MAPTILER_API_KEY}"
    assert described["key_env"] == ["MAPTILER_API_KEY"] and described["name"] == "MapTiler.Satellite"
    shown = " ".join([
        json.dumps(described), json.dumps(imagery.info), repr(provider), provider.display_template,
        provider.tile_location(CENTRE), redact(sent[0]), clean_url(sent[0]), caplog.text,
    ])
    assert MAPTILER_KEY not in shown
    on_disk = b"".join(p.read_bytes() for p in (tmp_path / "cache").rglob("*") if p.is_file())
    assert on_disk and MAPTILER_KEY.encode() not in on_disk


KEYED = sorted(
    name for name, p in catalogue().items() if p.requires_token() and p.get("crs") in (None, "EPSG:3857")
)


@pytest.mark.parametrize("name", KEYED)
def test_every_key_needing_entry_keeps_its_key_out_of_what_is_shown(name: str) -> None:
    """The key reaches the URL sent, never the template, the redacted URL or a cassette."""
    key = "TEST-k3y-" + name.replace(".", "-")
    env = {var: key for var in key_envs(catalogue()[name]).values()}
    assert env, name
    with HttpClient(HttpConfig(retries=0)) as client:
        provider = make_provider(name, client, env=env)
    assert isinstance(provider, NamedProvider)
    url = fill_template(provider.template, CENTRE, env)
    assert key in url
    for shown in (provider.display_template, json.dumps(provider.describe()), redact(url), clean_url(url)):
        assert key not in shown, (name, shown)


# -- zoom, bounds, missing tiles, odd entries -------------------------------------------------


def test_missing_esri_tile_is_no_imagery_not_an_error() -> None:
    missing = mercantile.Tile(CENTRE.x - 10, CENTRE.y, ZOOM)
    grid = sample_grid(*mercantile.ul(missing.x, missing.y, ZOOM), ZOOM, size=1)
    assert grid.tiles == (missing,)
    with HttpClient(HttpConfig(retries=0, cassette=ESRI_CASSETTE)) as client:
        imagery = make_provider("Esri.WorldImagery", client).fetch(grid)
    assert imagery.placeholder_tiles == 1 and not imagery.valid.any()
    assert imagery.info["no_imagery_tiles"] == [f"18/{missing.x}/{missing.y}"]


def test_tiles_outside_the_bounds_are_no_imagery_without_a_request() -> None:
    """PDOK (Netherlands) in Helsinki: a request would miss the cassette and raise."""
    grid = sample_grid(LON, LAT, ZOOM, size=3)
    with HttpClient(HttpConfig(retries=0, cassette=ESRI_CASSETTE)) as client:
        provider = make_provider("nlmaps.luchtfoto", client)
        imagery = provider.fetch(grid)
        with pytest.raises(ConfigError, match=r"^--zoom 5 is below nlmaps\.luchtfoto's lowest zoom 6: use --zoom 6"):
            provider.fetch(sample_grid(LON, LAT, 5, size=1))
    assert imagery.placeholder_tiles == 9 and not imagery.valid.any()
    assert provider.describe()["bounds_wgs84"] == [3.25, 50.5, 7.6, 54.0]


def test_template_translation_of_subdomains_scale_and_tms() -> None:
    entry = xyzservices.TileProvider(
        name="Example.Ortho", url="https://{s}.tiles.example/{variant}/{z}/{x}/{y}{r}.png",
        attribution="(C) Example", variant="ortho", subdomains="bcd", tms=True,
    )
    assert tile_template(entry, {}) == "https://b.tiles.example/ortho/{z}/{x}/{-y}.png"
    with HttpClient(HttpConfig(retries=0)) as client:
        provider = NamedProvider(entry, client, env={})
    assert provider.tile_location(mercantile.Tile(1, 0, 1)) == "https://b.tiles.example/ortho/1/1/1.png"
    assert provider.describe()["attribution"] == "(C) Example"
    assert provider.describe()["zoom_range"] == [0, None]
    entry4326 = xyzservices.TileProvider(name="Example.Geo", url="https://h/{z}/{x}/{y}.png", attribution="x", crs="EPSG:4326")
    with pytest.raises(ConfigError, match="serves tiles in EPSG:4326, not Web Mercator"):
        NamedProvider(entry4326, None, env={})


def test_names_are_case_and_punctuation_insensitive_and_maps_warn(caplog) -> None:
    with HttpClient(HttpConfig(retries=0)) as client:
        assert make_provider("esri worldimagery", client).describe()["name"] == "Esri.WorldImagery"
        assert "does not look like aerial imagery" not in caplog.text
        make_provider("OpenStreetMap.Mapnik", client)
    assert "OpenStreetMap.Mapnik does not look like aerial imagery" in caplog.text
    assert close_names("swissimage")[0] == "SwissFederalGeoportal.SWISSIMAGE"


def test_curated_aerial_providers_exist_and_resolve() -> None:
    assert [p.name for p in aerial_providers()] == [p.name for p in AERIAL_PROVIDERS]
    with HttpClient(HttpConfig(retries=0)) as client:
        for entry in aerial_providers():
            assert entry.terms and entry.coverage
            tile_provider = catalogue()[entry.name]
            env = {"MAPTILER_API_KEY": "TEST"} if token_attributes(tile_provider) else {}
            provider = make_provider(entry.name, client, env=env)
            assert isinstance(provider, NamedProvider) and provider.describe()["terms"] == entry.terms
            assert provider.attribution == tile_provider["attribution"]
    assert {p.name for p in aerial_providers() if p.open_licence} == {
        "USGS.USImagery", "GeoportailFrance.orthos", "nlmaps.luchtfoto", "BasemapAT.orthofoto",
        "SwissFederalGeoportal.SWISSIMAGE",
    }
