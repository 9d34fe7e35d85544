"""A photo as a user holds it: ``--photo FILE.jpg`` with its EXIF (localization/common/photo.py,
localization/cli/query.py).

The test photos' EXIF is written with piexif, a library osmseg does not use, and read by osmseg
through Pillow: focal length (35 mm equivalent, or on the sensor's focal plane), orientation,
compass heading and GPS fix. Through ``osmseg localize-region``: a 90° photo of the constructed
town, its field of view, compass and GPS from EXIF, found where it was taken with its heading
searched near its compass; and the refusals, each one line and exit 2.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import piexif
import pytest
from click.testing import CliRunner
from PIL import Image, ImageOps
from test_foreign_model import mapping, onnx_model
from test_loc_georender import LAT0, LON0, lonlat
from test_region_null import TABLE, towns  # noqa: F401  (towns: the fixture)

from localization.bench.georender import Camera, render
from localization.bench.georender_osm import scene_from_osm
from localization.bench.render import panorama_table
from localization.common.photo import photo_facts, upright_pixels
from localization.region.search import distance_m
from osmseg.cli.main import cli


def rational(value: float, scale: int = 10000) -> tuple[int, int]:
    return int(round(value * scale)), scale


def dms(value: float) -> tuple[tuple[int, int], ...]:
    value = abs(value)
    d = int(value)
    m = int((value - d) * 60)
    return (d, 1), (m, 1), rational((value - d - m / 60) * 3600, 1000)


def write_photo(path: Path, pixels: np.ndarray, *, orientation: int = 1, f35: int | None = None,
                focal_mm: float | None = None, sensor_mm: float | None = None, heading: float | None = None,
                magnetic: bool = False, lonlat_: tuple[float, float] | None = None, error_m: float | None = None) -> Path:
    """A JPEG of ``pixels`` whose EXIF says what is given, written by piexif."""
    zeroth = {piexif.ImageIFD.Orientation: orientation, piexif.ImageIFD.Make: b"osmseg test"}
    exif: dict = {piexif.ExifIFD.DateTimeOriginal: b"2026:12:06 10:00:00"}  # as every camera writes it
    if f35 is not None:
        exif[piexif.ExifIFD.FocalLengthIn35mmFilm] = f35
    if focal_mm is not None and sensor_mm is not None:  # the focal plane in pixels per centimetre
        exif[piexif.ExifIFD.FocalLength] = rational(focal_mm, 100)
        exif[piexif.ExifIFD.FocalPlaneXResolution] = rational(pixels.shape[1] / (sensor_mm / 10), 1000)
        exif[piexif.ExifIFD.FocalPlaneResolutionUnit] = 3
        exif[piexif.ExifIFD.PixelXDimension] = pixels.shape[1]
    gps: dict = {}
    if heading is not None:
        gps[piexif.GPSIFD.GPSImgDirectionRef] = b"M" if magnetic else b"T"
        gps[piexif.GPSIFD.GPSImgDirection] = rational(heading, 100)
    if lonlat_ is not None:
        lon, lat = lonlat_
        gps.update({piexif.GPSIFD.GPSLatitudeRef: b"N" if lat >= 0 else b"S", piexif.GPSIFD.GPSLatitude: dms(lat),
                    piexif.GPSIFD.GPSLongitudeRef: b"E" if lon >= 0 else b"W", piexif.GPSIFD.GPSLongitude: dms(lon)})
        if error_m is not None:
            gps[piexif.GPSIFD.GPSHPositioningError] = rational(error_m, 100)
    ifds = {"0th": zeroth, "Exif": exif, **({"GPS": gps} if gps else {})}  # no empty IFD
    Image.fromarray(pixels.astype(np.uint8)).save(path, quality=95, exif=piexif.dump(ifds))
    return path


def test_exif_gives_field_of_view_orientation_compass_and_gps(tmp_path: Path) -> None:
    pixels = np.zeros((3024 // 8, 4032 // 8, 3), np.uint8)
    pixels[:10, :20] = 255  # a corner to follow through the turn
    phone = photo_facts(write_photo(tmp_path / "phone.jpg", pixels, f35=26, heading=271.5, magnetic=True,
                                    lonlat_=(-122.2851, 37.8123), error_m=4.7))
    assert (phone.width, phone.height) == (504, 378) and phone.hfov_deg == pytest.approx(67.3, abs=0.05)
    assert (phone.heading_deg, phone.heading_ref) == (271.5, "magnetic north")
    assert phone.lonlat == pytest.approx((-122.2851, 37.8123), abs=1e-6) and phone.position_error_m == 4.7
    turned = write_photo(tmp_path / "portrait.jpg", pixels, orientation=6, f35=26)  # held upright
    facts = photo_facts(turned)
    across = math.hypot(36, 24) * 378 / 630  # the 35 mm frame's diagonal over the upright picture's aspect
    assert (facts.width, facts.height) == (378, 504)
    assert facts.hfov_deg == pytest.approx(math.degrees(2 * math.atan(across / (2 * 26))), abs=1e-6)
    with Image.open(turned) as im:  # Pillow's own turn of the stored pixels, beside ours
        theirs = np.asarray(ImageOps.exif_transpose(im))
        ours = upright_pixels(np.asarray(im), turned)
    assert theirs.shape == ours.shape == (504, 378, 3) and np.array_equal(theirs, ours)
    sensor = photo_facts(write_photo(tmp_path / "camera.jpg", pixels, focal_mm=4.0, sensor_mm=8.0))
    assert sensor.hfov_deg == pytest.approx(90.0, abs=0.01) and sensor.heading_deg is None and sensor.lonlat is None
    bare = photo_facts(write_photo(tmp_path / "bare.jpg", pixels))
    assert (bare.hfov_deg, bare.heading_deg, bare.lonlat) == (None, None, None)


def photo_of_town(osm: Path, folder: Path, at: tuple[float, float], facing: float, fov: float = 120.0,
                  **exif) -> tuple[Path, Path]:
    """A ``fov``-degree photo (224 rows) of ``osm`` at ``at`` facing ``facing`` degrees: its class-id
    mask, and a JPEG (the mask's colours) whose EXIF says what ``exif`` gives."""
    scene = scene_from_osm([osm], LON0, LAT0, TABLE, radius_m=200, seed=0)
    pano = panorama_table(TABLE)
    labels = render(scene.scene, Camera(*scene.to_local(*lonlat(*at)), eye_m=1.7, heading_deg=facing, hfov_deg=fov,
                                        width=int(round(1232 * fov / 360)), height=224), pano.by_name["sky"].id, TABLE.unlabeled.id)
    folder.mkdir(parents=True, exist_ok=True)
    Image.fromarray(labels.astype(np.uint8)).save(folder / "photo.labels.png")
    rgb = np.take(pano.palette(), labels, axis=0)
    return write_photo(folder / "photo.jpg", rgb, **exif), folder / "photo.labels.png"


def region_args(photo: Path, labels: Path | None, osm: Path, out: Path, *extra: str) -> list[str]:
    args = ["localize-region", "--photo", str(photo), "--ground-landmarks", "aerial13", "--ground-table",
            "classes13.toml", "--osm", str(osm), "--out", str(out), "--cache-dir", str(out.parent / "cache"), *extra]
    return args + (["--ground", str(labels)] if labels is not None else [])


def test_a_photo_is_found_with_its_exif_field_of_view_compass_and_gps(towns: tuple[Path, Path], tmp_path: Path) -> None:
    here, _ = towns
    at, heading = (10.0, -25.0), 80.0  # facing the park across the street
    truth = lonlat(*at)
    gps = lonlat(at[0] + 20.0, at[1] - 15.0)  # a phone's fix, 25 m off
    photo, labels = photo_of_town(here, tmp_path / "q", at, heading, focal_mm=2.31, sensor_mm=8.0,  # 120°
                                  heading=heading + 12.0, lonlat_=gps, error_m=25.0)
    result = CliRunner().invoke(cli, region_args(photo, labels, here, tmp_path / "out", "--radius-km", "0.14"))
    assert result.exit_code == 0, result.output
    said = result.stderr
    assert "photo: 411x224 px, field of view 120.0° (focal length 2.31 mm" in said and "compass heading 92.0°" in said
    assert "heading: searched within ±25° of 92°" in said, said
    doc = json.loads((tmp_path / "out" / "region.geojson").read_text())
    best = doc["features"][0]
    assert distance_m((best["geometry"]["coordinates"][0], best["geometry"]["coordinates"][1]), truth) < 5.0
    assert abs((best["properties"]["heading_deg"] - heading + 180) % 360 - 180) <= 5.0  # searched, not the compass's
    west, south, east, north = doc["properties"]["bbox"]
    assert west < gps[0] < east and south < gps[1] < north  # the region is the disc around the GPS fix
    # what the EXIF said is what the options say: the same search, the same answers
    fov = json.loads((tmp_path / "out" / "region.geojson").read_text())
    fix = photo_facts(photo).lonlat
    assert fix is not None and distance_m(fix, gps) < 0.05  # its DMS rationals (1/1000 s), read back
    typed = CliRunner().invoke(cli, ["localize-region", "--ground", str(labels), "--ground-landmarks", "aerial13",
                                     "--ground-table", "classes13.toml", "--osm", str(here), "--out",
                                     str(tmp_path / "typed"), "--cache-dir", str(tmp_path / "cache"),
                                     "--fov", f"{math.degrees(2 * math.atan(4 / 2.31)):.3f}", "--heading", "92",
                                     "--heading-within", "25", "--lon", repr(fix[0]), "--lat", repr(fix[1]),
                                     "--radius-km", "0.14"])
    assert typed.exit_code == 0, typed.output
    assert json.loads((tmp_path / "typed" / "region.geojson").read_text()) == fov


def test_a_photo_that_cannot_be_taken_as_it_is_says_what_to_give(towns: tuple[Path, Path], tmp_path: Path) -> None:
    here, _ = towns
    bare, labels = photo_of_town(here, tmp_path / "bare", (10.0, -25.0), 0.0)
    box = ["--bbox", ",".join(f"{v:.6f}" for v in (*lonlat(-140, -140), *lonlat(140, 140)))]
    cases = [
        (region_args(bare, labels, here, tmp_path / "o1", *box), "its EXIF has no focal length; give its field of view"),
        (region_args(bare, None, here, tmp_path / "o2", *box), "give its class-id mask as --ground FILE"),
        (region_args(bare, tmp_path / "wide.png", here, tmp_path / "o3", *box, "--fov", "90"), "is 300x100, but --photo"),
        (["localize-region", "--osm", str(here), *box], "give the ground view: --ground FILE"),
    ]
    Image.fromarray(np.zeros((100, 300), np.uint8)).save(tmp_path / "wide.png")
    located, _ = photo_of_town(here, tmp_path / "gps", (10.0, -25.0), 0.0, f35=18, lonlat_=lonlat(0, 0))
    cases.append((region_args(located, labels, here, tmp_path / "o4"), "give --radius-km KM to search around it"))
    cases.append((region_args(bare, labels, here, tmp_path / "o6", *box, "--fov", "90", "--heading-within", "20"),
                  "give it with --heading DEGREES"))
    cases.append((region_args(bare, labels, here, tmp_path / "o7", *box, "--fov", "90", "--heading", "unknown",
                              "--heading-within", "20"), "needs a heading to search near"))
    for args, message in cases:
        result = CliRunner().invoke(cli, args)
        assert result.exit_code == 2 and message in result.output, (args, result.output)
        assert len([line for line in result.output.splitlines() if line.startswith("Error")]) == 1
    # with --fov the bare photo is searched, its heading unknown
    ok = CliRunner().invoke(cli, region_args(bare, labels, here, tmp_path / "o5", *box, "--fov", "90"))
    assert ok.exit_code == 0 and "heading: searched (give --heading" in ok.stderr, ok.output


def test_a_photo_segmented_by_a_foreign_onnx_model_is_found_as_its_mask_is(towns: tuple[Path, Path],
                                                                         tmp_path: Path) -> None:
    """--photo with --ground-model (ONNX, made here: each pixel's nearest class colour, its channels
    in reverse order) and --ground-model-classes: the photo is segmented, then searched, and found
    where its own class-id mask is found."""
    here, _ = towns
    at, heading = (10.0, -25.0), 80.0
    photo, labels = photo_of_town(here, tmp_path / "q", at, heading, focal_mm=2.31, sensor_mm=8.0,
                                  heading=heading + 12.0)
    pano = panorama_table(TABLE)
    channels = tuple(c.name for c in reversed((pano.unlabeled, *pano.classes)))
    model = onnx_model(tmp_path / "colours.onnx", channels, pano)
    classes = mapping(tmp_path / "colours.toml", channels=channels)
    box = ["--bbox", ",".join(f"{v:.6f}" for v in (*lonlat(-140, -140), *lonlat(140, 140)))]
    runs = {}
    for name, ground in (("mask", ["--ground", str(labels)]),
                         ("model", ["--ground-model", str(model), "--ground-model-classes", str(classes)])):
        result = CliRunner().invoke(cli, [*region_args(photo, None, here, tmp_path / name, *box), *ground])
        assert result.exit_code == 0, result.output
        runs[name] = json.loads((tmp_path / name / "region.geojson").read_text())["features"][0]
    for run in runs.values():
        assert distance_m(tuple(run["geometry"]["coordinates"]), lonlat(*at)) < 5.0
    assert distance_m(tuple(runs["model"]["geometry"]["coordinates"]),
                      tuple(runs["mask"]["geometry"]["coordinates"])) < 2.0
    both = CliRunner().invoke(cli, [*region_args(photo, labels, here, tmp_path / "both", *box), "--ground-model",
                                    str(model), "--ground-checkpoint", str(model)])
    assert both.exit_code == 2 and "give one segmentation of the ground photo" in both.output, both.output
