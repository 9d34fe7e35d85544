"""Imagery providers: Bing, XYZ (HTTP and file://), GeoTIFF, and the --imagery spec parser.

HTTP tests replay the vcrpy cassettes in tests/data/imagery (made by its data.py) through the real
HttpClient's replay adapter (osmseg.net.cassette, as ``osmseg build --replay``): no request leaves
the machine.  Tests of faults and the on-disk cache use the scripted server on 127.0.0.1
(tests/servers.py).  Synthetic tiles
encode their position (red = 32 + 64 * (x % 3), green = 32 + 64 * (y % 3), blue = a diagonal
ramp), so every check is "the pixel at tile i's offset came from tile i".
"""

from __future__ import annotations

import io
import json
import logging
import multiprocessing
import re
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import mercantile
import numpy as np
import pytest
import rasterio
from conftest import TEST_DATA, shared_path
from PIL import Image
from pyproj import Transformer
from rasterio.transform import from_origin
from scipy import ndimage
from servers import Reply

from osmseg.errors import AuthError, ConfigError, ImageryError, RetriesExhausted
from osmseg.grid import TILE_SIZE, SampleGrid, sample_grid
from osmseg.imagery import (
    BingProvider,
    GeoTiffProvider,
    XYZProvider,
    make_provider,
)
from osmseg.imagery.bing import AUTH_MESSAGE
from osmseg.imagery.mosaic import assemble
from osmseg.net.http import ABSENT_ASKS, HttpClient, HttpConfig

DATA = TEST_DATA / "imagery"
LON, LAT, ZOOM = 13.4050, 52.5200, 18  # as in tests/data/imagery/data.py
BING_KEY = "TEST-bing-key-7f3a9c"
MAPBOX_TOKEN = "pk.TEST-mapbox-token-51e2"
MAPBOX = (
    "https://api.mapbox.com/v4/mapbox.satellite/{z}/{x}/{y}.png?access_token={env:MAPBOX_TOKEN}"
)


@contextmanager
def replay(name: str) -> Iterator[HttpClient]:
    """A client answering from cassette ``name`` as ``osmseg build --replay`` does (keys filtered out)."""
    with HttpClient(HttpConfig(retries=0, timeout=5, cassette=DATA / name)) as http:
        yield http


@pytest.fixture
def grid() -> SampleGrid:
    return sample_grid(LON, LAT, ZOOM, size=3)


@pytest.fixture
def client():
    with HttpClient(HttpConfig(retries=0, timeout=5)) as http:
        yield http


def expected_colour(tile: mercantile.Tile, col: int, row: int) -> tuple[int, int, int]:
    """The synthetic colour at (col, row) inside ``tile`` (see data.py)."""
    return 32 + 64 * (tile.x % 3), 32 + 64 * (tile.y % 3), (col + row) // 2


def assert_tile_in_place(rgb: np.ndarray, grid: SampleGrid, index: int, tol: int) -> None:
    """Pixels at tile ``index``'s offset carry that tile's colour code and in-tile ramp."""
    left, top = grid.tile_offset(index)
    for col, row in [(128, 128), (10, 200), (240, 16)]:
        got = rgb[top + row, left + col].astype(int)
        want = expected_colour(grid.tiles[index], col, row)
        assert np.abs(got - want).max() <= tol, (index, col, row, got, want)


def tile_area(array: np.ndarray, grid: SampleGrid, index: int) -> np.ndarray:
    left, top = grid.tile_offset(index)
    return array[top : top + TILE_SIZE, left : left + TILE_SIZE]


# -- Bing -------------------------------------------------------------------------------------


def test_bing_tiles_land_at_their_offsets_and_placeholder_is_invalid(grid, client):
    with replay("bing.yaml") as client:
        provider = BingProvider(client, BING_KEY, workers=1)
        imagery = provider.fetch(grid)
        provider.describe()
        provider.fetch(grid)
        metadata = [n for url, n in client._adapter.plays.items() if "Imagery/Metadata" in url]
        assert metadata == [1]  # the metadata call is made once per provider
    assert imagery.rgb.shape == (768, 768, 3) and imagery.valid.shape == (768, 768)
    for index in range(8):
        assert_tile_in_place(imagery.rgb, grid, index, tol=6)  # JPEG
        assert tile_area(imagery.valid, grid, index).all()
    # the south-east tile answered "X-VE-Tile-Info: no-tile"
    assert imagery.placeholder_tiles == 1
    assert imagery.info["no_imagery_tiles"] == ["18/140834/85972"]
    assert not tile_area(imagery.valid, grid, 8).any()
    assert not tile_area(imagery.rgb, grid, 8).any()


def test_bing_describe_records_attribution_and_never_the_key(grid, client, caplog):
    caplog.set_level(logging.DEBUG)
    with replay("bing.yaml") as client:
        provider = make_provider("bing", client, env={"BING_MAPS_KEY": BING_KEY})
        provider.workers = 1
        imagery = provider.fetch(grid)
        described = provider.describe()
    assert (
        described["image_url"]
        == "https://ecn.{subdomain}.tiles.virtualearth.net/tiles/a{quadkey}.jpeg?g=14560"
    )
    assert (
        described["brand_logo_uri"] == "https://dev.virtualearth.net/Branding/logo_powered_by.png"
    )
    assert described["copyright"].startswith("Copyright © 2025 Microsoft")
    assert provider.attribution == described["copyright"]
    # suppliers whose coverage meets Berlin at z18 (not the New York-only or z<=8 ones)
    assert imagery.info["suppliers"] == ["© 2025 Microsoft Corporation", "© 2025 Maxar"]
    shown = " ".join([str(described), str(imagery.info), repr(provider), caplog.text])
    assert "metadata/aerial" in caplog.text.lower()  # the metadata URL was logged, redacted
    assert BING_KEY not in shown


def test_bing_refused_key_is_an_auth_error_without_the_key(grid, client):
    with replay("bing-refused.yaml") as client:
        provider = BingProvider(client, BING_KEY)
        with pytest.raises(AuthError) as refused:
            provider.fetch(grid)
    assert str(refused.value) == AUTH_MESSAGE
    assert refused.value.status == 401
    assert BING_KEY not in str(refused.value) and "\n" not in str(refused.value)


def test_bing_zoom_outside_metadata_range_is_a_config_error(client):
    with replay("bing.yaml") as client:
        provider = BingProvider(client, BING_KEY)
        with pytest.raises(ConfigError, match="zoom 22 is outside Bing Aerial's range 1-21"):
            provider.fetch(sample_grid(LON, LAT, 22, size=1))


def test_bing_needs_a_key(client):
    with pytest.raises(ConfigError, match=re.escape("--imagery bing needs BING_MAPS_KEY")) as err:
        make_provider("bing", client, env={})
    assert "no longer exist" in str(err.value) and "Esri.WorldImagery" in str(err.value)
    assert isinstance(make_provider("bing", client, env={"BING_MAPS_KEY": BING_KEY}), BingProvider)


def synthetic_tile(tile: mercantile.Tile, fmt: str) -> bytes:
    """The data.py tile content, encoded in the test (for the live local server)."""
    row, col = np.mgrid[0:256, 0:256]
    rgb = np.zeros((256, 256, 3), np.uint8)
    rgb[..., 0], rgb[..., 1] = 32 + 64 * (tile.x % 3), 32 + 64 * (tile.y % 3)
    rgb[..., 2] = (col + row) // 2
    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, fmt)
    return buf.getvalue()


def test_bing_against_a_local_server_with_faults(http_server, grid):
    """Threaded tile fetches through the real client: retries, truncation and no-tile 404s."""
    image_url = http_server.url("/{subdomain}/a{quadkey}.jpeg?g=1&n=z&mkt={culture}")
    meta = {
        "authenticationResultCode": "ValidCredentials",
        "copyright": "Copyright © Microsoft",
        "resourceSets": [
            {
                "resources": [
                    {
                        "imageUrl": image_url,
                        "imageUrlSubdomains": ["t0", "t1"],
                        "zoomMin": 1,
                        "zoomMax": 21,
                    }
                ]
            }
        ],
        "statusCode": 200,
    }
    http_server.script(
        "/REST/v1/Imagery/Metadata/Aerial",
        Reply(200, json.dumps(meta), {"Content-Type": "application/json"}),
    )
    for index, tile in enumerate(grid.tiles):
        quadkey = mercantile.quadkey(tile)
        path = f"/t{int(quadkey, 4) % 2}/a{quadkey}.jpeg"
        jpeg = Reply(200, synthetic_tile(tile, "JPEG"), {"Content-Type": "image/jpeg"})
        if index == 4:
            http_server.script(path, Reply(503, headers={"Retry-After": "0"}), jpeg)
        elif index == 0:
            http_server.script(path, Reply(200, jpeg.data, jpeg.headers, truncate=100), jpeg)
        elif index == 8:  # with n=z Bing answers "no imagery" as a 404 carrying the header
            http_server.script(path, Reply(404, b"", {"X-VE-Tile-Info": "no-tile"}))
        else:
            http_server.script(path, jpeg)
    metadata_url = http_server.url("/REST/v1/Imagery/Metadata/{imagery_set}")
    with HttpClient(HttpConfig(retries=2, backoff=0.01, timeout=5)) as http:
        imagery = BingProvider(http, BING_KEY, metadata_url=metadata_url).fetch(grid)
    for index in range(8):
        assert_tile_in_place(imagery.rgb, grid, index, tol=6)
    assert imagery.placeholder_tiles == 1 and not tile_area(imagery.valid, grid, 8).any()
    assert http_server.count("/REST/v1/Imagery/Metadata/Aerial") == 1
    assert all(
        f"key={BING_KEY}" in s.query
        for s in http_server.requests("/REST/v1/Imagery/Metadata/Aerial")
    )
    tile_requests = [s for s in http_server.requests() if s.path.endswith(".jpeg")]
    # 9 tiles + one retry after 503 + one after the cut body; "no imagery" is asked ABSENT_ASKS times in all
    assert len(tile_requests) == 11 + ABSENT_ASKS - 1
    assert all("key=" not in s.query and "mkt=en-US" in s.query for s in tile_requests)


def test_xyz_against_a_local_server_with_faults(http_server, grid):
    for index, tile in enumerate(grid.tiles):
        path = f"/t/{tile.z}/{tile.x}/{tile.y}.png"
        png = Reply(200, synthetic_tile(tile, "PNG"), {"Content-Type": "image/png"})
        if index == 3:
            http_server.script(path, Reply(429, headers={"Retry-After": "0"}), png)
        elif index == 5:
            http_server.script(path, Reply(204))
        else:
            http_server.script(path, png)
    template = http_server.url("/t/{z}/{x}/{y}.png?access_token={env:TILE_TOKEN}")
    with HttpClient(HttpConfig(retries=2, backoff=0.01, timeout=5)) as http:
        imagery = XYZProvider(template, http, env={"TILE_TOKEN": "TEST-live-token"}).fetch(grid)
    for index in (0, 1, 2, 3, 4, 6, 7, 8):
        assert_tile_in_place(imagery.rgb, grid, index, tol=0)
    assert imagery.placeholder_tiles == 1 and not tile_area(imagery.valid, grid, 5).any()
    assert http_server.count() == 10 + ABSENT_ASKS - 1  # the 204 ("no tile") is a verdict, asked again
    assert all(s.query == "access_token=TEST-live-token" for s in http_server.requests())


def test_bing_refusal_is_not_cached(http_server, grid, tmp_path):
    """After a refused key is fixed, the HTTP cache must not replay the refusal."""
    image_url = http_server.url("/tiles/a{quadkey}.jpeg")
    meta = {
        "authenticationResultCode": "ValidCredentials",
        "resourceSets": [{"resources": [{"imageUrl": image_url, "zoomMin": 1, "zoomMax": 21}]}],
    }
    refused = {"authenticationResultCode": "InvalidCredentials", "statusCode": 401}

    def metadata(seen):
        if f"key={BING_KEY}" in seen.query:
            return Reply(200, json.dumps(meta), {"Content-Type": "application/json"})
        return Reply(401, json.dumps(refused), {"Content-Type": "application/json"})

    http_server.route("/REST/v1/Imagery/Metadata/Aerial", metadata)
    for tile in grid.tiles:
        jpeg = synthetic_tile(tile, "JPEG")
        http_server.script(f"/tiles/a{mercantile.quadkey(tile)}.jpeg", Reply(200, jpeg))
    metadata_url = http_server.url("/REST/v1/Imagery/Metadata/{imagery_set}")
    with HttpClient(HttpConfig(cache_dir=tmp_path, retries=0)) as http:
        with pytest.raises(AuthError, match="Bing Maps refused the key"):
            BingProvider(http, "TEST-wrong-key", metadata_url=metadata_url).fetch(grid)
        imagery = BingProvider(http, BING_KEY, metadata_url=metadata_url).fetch(grid)
    assert imagery.valid.all()
    assert BING_KEY.encode() not in (tmp_path / "http.sqlite").read_bytes()


def test_xyz_offline_rebuild_from_the_cache(http_server, grid, tmp_path):
    """A second, offline fetch gives the same pixels, the 404 tile included, with no request."""
    for index, tile in enumerate(grid.tiles):
        if index != 6:  # unscripted paths answer 404
            png = synthetic_tile(tile, "PNG")
            http_server.script(f"/t/{tile.z}/{tile.x}/{tile.y}.png", Reply(200, png))
    template = http_server.url("/t/{z}/{x}/{y}.png?access_token={env:TILE_TOKEN}")
    env = {"TILE_TOKEN": "TEST-live-token"}
    with HttpClient(HttpConfig(cache_dir=tmp_path, retries=0)) as http:
        online = XYZProvider(template, http, env=env).fetch(grid)
    assert http_server.count() == 9 + ABSENT_ASKS - 1  # the 404 ("no tile") is a verdict, asked again
    with HttpClient(HttpConfig(cache_dir=tmp_path, offline=True)) as http:
        offline = XYZProvider(template, http, env=env).fetch(grid)
    assert http_server.count() == 9 + ABSENT_ASKS - 1
    assert np.array_equal(online.rgb, offline.rgb) and np.array_equal(online.valid, offline.valid)
    assert offline.placeholder_tiles == 1
    assert b"TEST-live-token" not in (tmp_path / "http.sqlite").read_bytes()


def test_a_one_colour_tile_an_older_cache_kept_as_imagery_is_asked_again(http_server, grid, tmp_path):
    """An older osmseg cached a tile of one colour like any tile: a build against that cache asks the
    server again (which has imagery there now) instead of condemning the sample from the cache;
    offline, the cache is all there is and its answer stands."""
    tile = grid.tiles[4]
    path = f"/t/{tile.z}/{tile.x}/{tile.y}.png"
    white = io.BytesIO()
    Image.new("RGB", (256, 256), (255, 255, 255)).save(white, "PNG")
    http_server.script(path, Reply(200, white.getvalue()), Reply(200, synthetic_tile(tile, "PNG")))
    url = http_server.url(path)
    with HttpClient(HttpConfig(cache_dir=tmp_path, retries=0, backoff=0.01)) as http:
        http.get(url)  # what the older osmseg did with any 200 that decoded: keep it
    with HttpClient(HttpConfig(cache_dir=tmp_path, offline=True)) as http:
        assert XYZProvider(http_server.url("/t/{z}/{x}/{y}.png"), http).fetch_tile(tile).uniform
    with HttpClient(HttpConfig(cache_dir=tmp_path, retries=0, backoff=0.01)) as http:
        pixels = XYZProvider(http_server.url("/t/{z}/{x}/{y}.png"), http).fetch_tile(tile)
    assert http_server.count(path) == 2 and not pixels.placeholder and pixels.valid.all()
    with HttpClient(HttpConfig(cache_dir=tmp_path, offline=True)) as http:  # the imagery replaced it
        assert XYZProvider(http_server.url("/t/{z}/{x}/{y}.png"), http).fetch_tile(tile).valid.all()


# -- XYZ over HTTP ----------------------------------------------------------------------------


def test_xyz_http_tiles_land_at_their_offsets(grid, client, caplog):
    caplog.set_level(logging.DEBUG)
    with replay("xyz.yaml") as client:
        provider = XYZProvider(MAPBOX, client, env={"MAPBOX_TOKEN": MAPBOX_TOKEN}, workers=1)
        imagery = provider.fetch(grid)
    for index in (1, 2, 3, 4, 5, 7, 8):
        assert_tile_in_place(imagery.rgb, grid, index, tol=0)  # PNG is lossless
        assert tile_area(imagery.valid, grid, index).all()
    # north-west tile: left half transparent
    nw = tile_area(imagery.valid, grid, 0)
    assert not nw[:, :128].any() and nw[:, 128:].all()
    assert tuple(imagery.rgb[128, 200]) == expected_colour(grid.tiles[0], 200, 128)
    # south-west tile: HTTP 404 -> no imagery, not an error
    assert imagery.placeholder_tiles == 1
    assert imagery.info["no_imagery_tiles"] == ["18/140832/85972"]
    assert not tile_area(imagery.valid, grid, 6).any()
    # the manifest shows the template with the env placeholder, never the token
    assert provider.describe()["template"] == MAPBOX
    assert provider.describe()["attribution"] == "© Mapbox © Maxar"
    assert MAPBOX_TOKEN not in " ".join(
        [str(provider.describe()), str(imagery.info), repr(provider), caplog.text]
    )


def test_xyz_corrupt_tile_is_retried_then_an_error_naming_the_tile(client):
    """An HTML page answered as a tile: fetched again like a 5xx; when it stays broken, one line."""
    corrupt = sample_grid(*mercantile.ul(140827, 85970, ZOOM), ZOOM, size=1)
    assert corrupt.tiles[0] == mercantile.Tile(140827, 85970, ZOOM)
    with replay("xyz.yaml") as client:
        provider = XYZProvider(MAPBOX, client, env={"MAPBOX_TOKEN": MAPBOX_TOKEN})
        with pytest.raises(
            RetriesExhausted, match=r"unusable answers in a row, the last: tile 18/140827/85970 .* is not a readable image"
        ) as bad:
            provider.fetch(corrupt)
    assert "\n" not in str(bad.value) and MAPBOX_TOKEN not in str(bad.value)


def test_xyz_refused_key_is_an_auth_error_without_the_key(client):
    refused = sample_grid(*mercantile.ul(140822, 85970, ZOOM), ZOOM, size=1)
    template = "https://tiles.example.org/{z}/{x}/{y}.png?api_key={env:TILE_KEY}"
    with replay("xyz.yaml") as client:
        provider = XYZProvider(template, client, env={"TILE_KEY": "TEST-tile-key-99"})
        with pytest.raises(AuthError) as exc:
            provider.fetch(refused)
    assert exc.value.status == 401
    assert "TEST-tile-key-99" not in str(exc.value) and "HTTP 401" in str(exc.value)


@pytest.mark.parametrize(
    ("template", "message"),
    [
        ("https://h.example/{z}/{x}/{s}.png", r"unknown placeholder \{s\}"),
        ("https://h.example/{z}/{x}.png", r"needs \{z\}, \{x\} and \{y\}"),
        ("ftp://h.example/{z}/{x}/{y}.png", "must start with https://"),
        ("https://h.example/{z}/{x}/{y}.png?access_token={env:NOT_SET_HERE}", "set it"),
        ("https://h.example/{env:TOKEN}/{z}/{x}/{y}.png", "only in a key query parameter"),
        ("https://h.example/{z}/{x}/{y}.png?style={env:TOKEN}", "only in a key query parameter"),
    ],
)
def test_xyz_bad_templates_are_config_errors(template, message):
    with pytest.raises(ConfigError, match=message):
        XYZProvider(template, client=None, env={"TOKEN": "t"})


def test_xyz_http_template_needs_a_client():
    with pytest.raises(ConfigError, match="needs an HTTP client"):
        XYZProvider("https://h.example/{z}/{x}/{y}.png", client=None, env={})


# -- XYZ from a local folder ------------------------------------------------------------------


def test_xyz_file_tiles_land_at_their_offsets(grid):
    template = f"xyz:file://{DATA}/tiles/{{z}}/{{x}}/{{y}}.png"
    provider = make_provider(template, None)
    # tile 4 of the folder is a 512 px tile among 256 px ones: never stretched silently
    with pytest.raises(ConfigError, match=r"18/\d+/\d+ .* is 512x512 px where this provider's tiles are 256x256 px: "
                                           r"if the provider's tiles are 512 px, declare it with --tile-size 512"):
        provider.fetch(grid)  # default thread pool
    retina = make_provider(template, None, tile_size=512)
    parts = [(retina if index == 4 else provider).fetch_tile(tile) for index, tile in enumerate(grid.tiles)]
    rgb, valid, placeholders = assemble(grid, parts)
    for index in (1, 2, 3, 5, 7, 8):
        assert_tile_in_place(rgb, grid, index, tol=0)
        assert tile_area(valid, grid, index).all()
    assert_tile_in_place(rgb, grid, 4, tol=2)  # 512 px tile, declared, resampled to 256
    assert not tile_area(valid, grid, 0)[:, :128].any()  # transparent half
    assert placeholders == 1 and not tile_area(valid, grid, 6).any()  # missing file


def test_xyz_file_truncated_tile_is_an_imagery_error():
    corrupt = sample_grid(*mercantile.ul(140827, 85970, ZOOM), ZOOM, size=1)
    provider = XYZProvider(f"file://{DATA}/tiles/{{z}}/{{x}}/{{y}}.png")
    with pytest.raises(
        ImageryError, match=r"tile 18/140827/85970 .*85970\.png.* is not a readable image"
    ):
        provider.fetch(corrupt)


def test_xyz_file_tms_rows(tmp_path, grid):
    """``{-y}`` counts rows from the south: a TMS folder gives the same image."""
    for tile in grid.tiles:
        source = DATA / "tiles" / str(tile.z) / str(tile.x) / f"{tile.y}.png"
        if source.exists():
            target = tmp_path / str(tile.z) / str(tile.x) / f"{2**tile.z - 1 - tile.y}.png"
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(source.read_bytes())
    xyz = XYZProvider(f"file://{DATA}/tiles/{{z}}/{{x}}/{{y}}.png")
    tms = XYZProvider(f"file://{tmp_path}/{{z}}/{{x}}/{{-y}}.png")
    for index, tile in enumerate(grid.tiles):
        if index == 4:  # the folder's 512 px tile: refused by both alike (test above)
            continue
        a, b = xyz.fetch_tile(tile), tms.fetch_tile(tile)
        assert a.placeholder == b.placeholder and (a.rgb is None) == (b.rgb is None), index
        if a.rgb is not None and b.rgb is not None:
            assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.valid, b.valid), index


# -- GeoTIFF ----------------------------------------------------------------------------------


def grid_pixel_centres(
    grid: SampleGrid, cols: np.ndarray, rows: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """EPSG:3857 coordinates of grid pixel centres."""
    t = grid.transform
    return t.c + (cols + 0.5) * t.a, t.f + (rows + 0.5) * t.e


def source_positions(path: Path, grid: SampleGrid, cols: np.ndarray, rows: np.ndarray):
    """Fractional (col, row) in the source raster of grid pixel centres, via pyproj."""
    with rasterio.open(path) as src:
        to_src = Transformer.from_crs("EPSG:3857", src.crs, always_xy=True)
        x, y = to_src.transform(*grid_pixel_centres(grid, cols, rows))
        inverse = ~src.transform
        scol, srow = inverse @ (np.asarray(x), np.asarray(y))
    return np.asarray(scol), np.asarray(srow)


def test_geotiff_utm_lines_up_with_pyproj(grid):
    """utm-rgb.tif's red/green are 2 x source column/row: each pixel says where it came from."""
    imagery = GeoTiffProvider(DATA / "utm-rgb.tif").fetch(grid)
    rows, cols = np.nonzero(imagery.valid)
    scol, srow = source_positions(DATA / "utm-rgb.tif", grid, cols, rows)
    inside = (scol > 1) & (scol < 99) & (srow > 1) & (srow < 99)  # away from the edge ramp-off
    assert inside.mean() > 0.9
    # pixel centres sit at col + 0.5; bilinear interpolation of a linear ramp is exact
    got_r = imagery.rgb[rows, cols, 0][inside].astype(float)
    got_g = imagery.rgb[rows, cols, 1][inside].astype(float)
    assert np.abs(got_r - 2 * (scol[inside] - 0.5)).max() < 1.6
    assert np.abs(got_g - 2 * (srow[inside] - 0.5)).max() < 1.6
    assert (imagery.rgb[rows, cols, 2] == 200).all()
    # outside the 200 m footprint: invalid and black; the footprint covers ~ (200 / 279 m)^2
    assert not imagery.rgb[~imagery.valid].any()
    assert 0.4 < imagery.valid.mean() < 0.6
    assert imagery.info["crs"] == "EPSG:32633"


def test_geotiff_grey_with_nodata(grid):
    imagery = GeoTiffProvider(DATA / "wgs84-grey-nodata.tif").fetch(grid)
    assert imagery.valid.any() and not imagery.valid.all()
    values = imagery.rgb[imagery.valid]
    assert (values == 150).all()  # grey replicated to R = G = B; nodata 0 never blended in
    # the nodata third (west) is invalid: no valid pixel west of the nodata edge
    x, _ = grid_pixel_centres(grid, np.nonzero(imagery.valid)[1], np.nonzero(imagery.valid)[0])
    west_edge = mercantile.xy(LON - 0.0015 + 20 * 0.00005, LAT)[0]
    assert x.min() > west_edge - grid.pixel_size


def test_geotiff_alpha_band_masks_and_nir_is_not_alpha(grid):
    rgba = GeoTiffProvider(DATA / "rgba.tif").fetch(grid)
    rows, _ = np.nonzero(rgba.valid)
    assert (rgba.rgb[rgba.valid] == (10, 120, 230)).all()
    _, y = mercantile.xy(LON, LAT)
    _, ys = grid_pixel_centres(grid, np.zeros_like(rows), rows)
    assert ys.max() < y + grid.pixel_size  # only the south half (alpha 255) is valid
    rgbn = GeoTiffProvider(DATA / "rgbn.tif").fetch(grid)
    assert rgbn.valid.sum() > 0.9 * (80 / grid.pixel_size) ** 2  # NIR = 0 did not mask it
    assert (rgbn.rgb[rgbn.valid] == (90, 140, 60)).all()


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("not-a-raster.tif", "is not a raster GDAL can read"),
        ("no-crs.tif", "has no CRS"),
        ("float32.tif", "is float32: imagery is read as 8- or 16-bit unsigned values"),
    ],
)
def test_geotiff_bad_inputs_are_one_line_imagery_errors(name, message, tmp_path):
    if name == "float32.tif":  # a stretch only its owner can choose (16-bit reads: tests/core/test_bad_inputs.py)
        with rasterio.open(DATA / "uint16.tif") as src:
            profile = dict(src.profile, dtype="float32")
        with rasterio.open(tmp_path / name, "w", **profile) as dst:
            dst.write(np.zeros((3, 8, 8), np.float32))
    with pytest.raises(ImageryError, match=message) as bad:
        GeoTiffProvider((tmp_path if name == "float32.tif" else DATA) / name)
    assert "\n" not in str(bad.value)


def test_geotiff_missing_path_is_a_usage_error():
    with pytest.raises(ConfigError, match="does not exist") as bad:
        GeoTiffProvider(DATA / "no-such-file.tif")
    assert "\n" not in str(bad.value)


def fetch_in_child(provider: GeoTiffProvider, grid: SampleGrid, results) -> None:
    """Runs in a child process: the provider's pixels, sent back to the parent."""
    imagery = provider.fetch(grid)
    results.put((imagery.rgb, imagery.valid))


@pytest.mark.parametrize("method", ["fork", "spawn"])
def test_geotiff_provider_in_a_worker_process_gives_the_same_pixels(grid, method):
    """A build's worker gets the provider forked (its open file inherited) or pickled (spawned):
    same pixels there, and the parent's provider still reads after the worker is gone."""
    if method not in multiprocessing.get_all_start_methods():
        pytest.skip(f"no {method} start method here")
    provider = GeoTiffProvider(DATA / "utm-rgb.tif")
    before = provider.fetch(grid)  # the parent's file is open now
    context = multiprocessing.get_context(method)
    results = context.Queue()
    child = context.Process(target=fetch_in_child, args=(provider, grid, results))
    child.start()
    rgb, valid = results.get(timeout=120)
    child.join(timeout=60)
    assert child.exitcode == 0
    assert valid.any() and np.array_equal(valid, before.valid) and np.array_equal(rgb, before.rgb)
    after = provider.fetch(grid)
    assert np.array_equal(after.valid, before.valid) and np.array_equal(after.rgb, before.rgb)


def write_plain_tif(path: Path, colour: tuple[int, int, int], size: int) -> None:
    """A 100 m EPSG:3857 raster of one colour around (LON, LAT)."""
    x, y = mercantile.xy(LON, LAT)
    with rasterio.open(path, "w", driver="GTiff", width=size, height=size, count=3, dtype="uint8",
                       crs="EPSG:3857", transform=from_origin(x - 50, y + 50, 100 / size, 100 / size)) as dst:
        dst.write(np.broadcast_to(np.array(colour, np.uint8)[:, None, None], (3, size, size)))


def test_geotiff_replaced_while_the_provider_lives_is_read_again(grid, tmp_path):
    """The provider keeps the file open; a GeoTIFF exported again (renamed over, or rewritten in
    place) is what the next fetch reads, never a mix with the old file."""
    path = tmp_path / "ortho.tif"
    write_plain_tif(path, (200, 10, 10), 40)
    provider = GeoTiffProvider(path)
    first = provider.fetch(grid)
    write_plain_tif(tmp_path / "new.tif", (10, 200, 10), 50)
    (tmp_path / "new.tif").replace(path)
    second = provider.fetch(grid)
    write_plain_tif(path, (10, 10, 200), 80)  # same file, new content and size
    third = provider.fetch(grid)
    for imagery, colour in [(first, (200, 10, 10)), (second, (10, 200, 10)), (third, (10, 10, 200))]:
        assert imagery.valid.sum() > 20_000  # the 100 m square
        assert (imagery.rgb[imagery.valid] == colour).all()
    assert provider.describe()["size"] == [80, 80]


def test_geotiff_truncated_file_is_a_one_line_imagery_error(grid, tmp_path):
    """A download cut short opens (its header is whole) but fails on the pixels: one line saying so."""
    x, y = mercantile.xy(LON, LAT)
    data = np.random.default_rng(0).integers(0, 256, (3, 512, 512), dtype=np.uint8)
    whole = tmp_path / "whole.tif"
    with rasterio.open(whole, "w", driver="GTiff", width=512, height=512, count=3, dtype="uint8", crs="EPSG:3857",
                       transform=from_origin(x - 100, y + 100, 0.4, 0.4), tiled=True, compress="deflate") as dst:
        dst.write(data)
    cut = tmp_path / "cut.tif"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    provider = GeoTiffProvider(cut)
    with pytest.raises(ImageryError, match=r"cannot read .*cut\.tif .* looks truncated or corrupt") as bad:
        provider.fetch(grid)
    assert "\n" not in str(bad.value)


# -- the --imagery spec -----------------------------------------------------------------------


def test_make_provider_specs():
    assert isinstance(make_provider(f"geotiff:{DATA / 'rgba.tif'}", None), GeoTiffProvider)
    assert isinstance(make_provider(str(DATA / "rgba.tif"), None), GeoTiffProvider)
    assert isinstance(
        make_provider(f"xyz:file://{DATA}/tiles/{{z}}/{{x}}/{{y}}.png", None), XYZProvider
    )
    with pytest.raises(ConfigError, match="unknown imagery 'google': use bing"):
        make_provider("google", None)
    with pytest.raises(ConfigError, match="needs a template"):
        make_provider("xyz:", None)


# -- real data (../shared/data) ---------------------------------------------------------------


def test_kampala_tiles_through_file_template():
    """A 5x5 z21 mosaic from real OpenAerialMap tiles equals the raw tiles at their offsets."""
    tiles = shared_path("kampala-oam", "tiles")
    west, south, east, north = mercantile.bounds(1238453, 1046531, 21)
    grid = sample_grid((west + east) / 2, (south + north) / 2, 21)
    assert {t.x for t in grid.tiles} <= set(range(1238448, 1238460))
    assert {t.y for t in grid.tiles} <= set(range(1046528, 1046536))
    imagery = make_provider(f"xyz:file://{tiles}/OAM-{{x}}-{{y}}-{{z}}.png", None).fetch(grid)
    assert imagery.rgb.shape == (1280, 1280, 3) and imagery.placeholder_tiles == 0
    assert imagery.valid.mean() > 0.5 and imagery.rgb[imagery.valid].std() > 20  # real content
    for index, tile in enumerate(grid.tiles):
        raw = np.asarray(Image.open(tiles / f"OAM-{tile.x}-{tile.y}-{tile.z}.png").convert("RGBA"))
        opaque = raw[:, :, 3] >= 128
        assert np.array_equal(tile_area(imagery.valid, grid, index), opaque)
        assert np.array_equal(tile_area(imagery.rgb, grid, index)[opaque], raw[:, :, :3][opaque])


def bilinear(array: np.ndarray, scol: np.ndarray, srow: np.ndarray) -> np.ndarray:
    """``array`` (bands, H, W) sampled at fractional pixel positions, pixel centres at +0.5."""
    c, r = scol - 0.5, srow - 0.5
    c0, r0 = np.floor(c).astype(int), np.floor(r).astype(int)
    fc, fr = c - c0, r - r0
    a = array.astype(float)
    top = a[:, r0, c0] * (1 - fc) + a[:, r0, c0 + 1] * fc
    bottom = a[:, r0 + 1, c0] * (1 - fc) + a[:, r0 + 1, c0 + 1] * fc
    return (top * (1 - fr) + bottom * fr).T


@pytest.mark.parametrize(
    ("parts", "zoom"),
    [
        (("oam-rgb", "manila.tif"), 21),  # EPSG:3395 World Mercator
        (("inria-austin", "image.tif"), 20),  # EPSG:26914 UTM 14N
        (("zurich-ortho", "image.tif"), 20),  # EPSG:2056 Swiss LV95
    ],
)
def test_real_geotiff_warps_onto_the_grid(parts, zoom):
    """Warped real imagery matches the source sampled where pyproj says each grid pixel lies."""
    path = shared_path(*parts)
    with rasterio.open(path) as src:
        source = src.read()
        cx, cy = (src.bounds.left + src.bounds.right) / 2, (src.bounds.bottom + src.bounds.top) / 2
        lon, lat = Transformer.from_crs(src.crs, "EPSG:4326", always_xy=True).transform(cx, cy)
    grid = sample_grid(lon, lat, zoom)
    imagery = GeoTiffProvider(path).fetch(grid)
    assert imagery.valid.mean() > 0.9
    rng = np.random.default_rng(0)
    rows, cols = rng.integers(0, grid.height, 400), rng.integers(0, grid.width, 400)
    scol, srow = source_positions(path, grid, cols, rows)
    got = imagery.rgb[rows, cols].astype(float)
    error = np.abs(got - bilinear(source, scol, srow)).mean(axis=1)
    assert error.max() < 1.0  # equal up to rounding to uint8
    # the same check one source pixel off fails: the comparison can see a misalignment
    shifted = np.abs(got - bilinear(source, scol + 1, srow)).mean(axis=1)
    assert np.median(shifted) > 1.5


def _write_tif(path: Path, rgb: np.ndarray, crs: str, transform) -> Path:  # type: ignore[no-untyped-def]
    with rasterio.open(path, "w", driver="GTiff", width=rgb.shape[2], height=rgb.shape[1], count=3, dtype="uint8",
                       crs=crs, transform=transform, tiled=True, compress="deflate") as dst:
        dst.write(rgb)
    return path


def test_geotiff_zoomed_out_averages_fine_detail_instead_of_aliasing(tmp_path: Path) -> None:
    """A drone orthophoto 8x finer than the sample's pixels, covering the middle of the sample (in a
    rotated CRS, ETRS-TM35FIN against Web Mercator): the bilinear kernel is widened by the true
    8:1 factor, so source pixel noise (std 74) averages down to ~6. The warper's own estimate,
    made from the raster's size against the grid's, filters less (~10 here)."""
    lon, lat, zoom = 24.94, 60.17, 17
    grid = sample_grid(lon, lat, zoom, size=3)
    x, y = Transformer.from_crs("EPSG:4326", "EPSG:3067", always_xy=True).transform(lon, lat)
    res = grid.ground_resolution / 8
    size = grid.width  # an eighth of the grid's extent
    noise = np.random.default_rng(1).integers(0, 256, (size, size), dtype=np.uint8)
    path = _write_tif(tmp_path / "noise.tif", np.stack([noise] * 3), "EPSG:3067",
                      from_origin(x - size / 2 * res, y + size / 2 * res, res, res))
    image = GeoTiffProvider(path).fetch(grid)
    assert 0.01 < image.valid.mean() < 0.02
    inner = image.valid.copy()
    for _ in range(3):  # away from the footprint's edge, where alpha fades
        inner[1:-1, 1:-1] &= inner[:-2, 1:-1] & inner[2:, 1:-1] & inner[1:-1, :-2] & inner[1:-1, 2:]
    grey = image.rgb[..., 0][inner].astype(float)
    assert abs(grey.mean() - 127.5) < 5 and grey.std() < 8, (grey.mean(), grey.std())


def test_geotiff_warp_matches_gdal_warping_the_whole_raster(tmp_path: Path) -> None:
    """The window read under a sample plus OpenCV's interpolation at PROJ's coordinates gives GDAL's
    pixels: ``rasterio.warp.reproject`` (bilinear) of the whole raster, on a noise image (the
    hardest case: any misplacement shows), in a rotated CRS, at three zooms, also where the
    sample runs off the raster. Equal up to rounding and OpenCV's 1/32-pixel placement; the
    validity mask differs only on the footprint's edge."""
    from rasterio.enums import Resampling
    from rasterio.warp import reproject

    lon, lat = 24.94, 60.17
    x, y = Transformer.from_crs("EPSG:4326", "EPSG:3067", always_xy=True).transform(lon, lat)
    rng = np.random.default_rng(5)
    rgb = rng.integers(0, 256, (3, 900, 900), dtype=np.uint8)
    res = 0.9
    path = _write_tif(tmp_path / "noise.tif", rgb, "EPSG:3067", from_origin(x - 450 * res, y + 450 * res, res, res))
    provider = GeoTiffProvider(path)
    for zoom, size, lon_off in ((18, 1, 0.001), (17, 3, 0.001), (19, 3, 0.001), (17, 3, 0.007)):
        grid = sample_grid(lon + lon_off, lat - 0.0005, zoom, size=size)
        got = provider.fetch(grid)
        with rasterio.open(path) as src:
            whole = np.concatenate([src.read(), np.full((1, 900, 900), 255, np.uint8)])
            out = np.zeros((4, grid.height, grid.width), np.uint8)
            reproject(whole, out, src_transform=src.transform, src_crs=src.crs, dst_transform=grid.transform,
                      dst_crs="EPSG:3857", resampling=Resampling.bilinear, src_alpha=4, dst_alpha=4)
        valid = out[3] >= 128
        assert valid.mean() > 0.2, zoom
        edge = valid ^ ndimage.binary_erosion(valid, iterations=2)
        assert not (got.valid ^ valid)[~edge].any(), zoom  # the footprints agree off their edge
        both = got.valid & valid & ~edge
        diff = np.abs(got.rgb[both].astype(int) - out[:3].transpose(1, 2, 0)[both])
        assert diff.mean() < 0.5 and diff.max() <= 4, (zoom, diff.mean(), diff.max())
        # one output pixel off is plainly different: the comparison sees a misplacement
        shifted = np.abs(got.rgb[:, 1:][both[:, 1:]].astype(int) - out[:3].transpose(1, 2, 0)[:, :-1][both[:, 1:]])
        assert shifted.mean() > 10 * diff.mean() + 5, zoom
