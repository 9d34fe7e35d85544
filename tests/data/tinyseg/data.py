#!/usr/bin/env python3
"""Write ``tinyseg/``: a tiny, learnable segmentation dataset in the layout ``osmseg build`` writes.

Run it again to regenerate the files (deterministic from ``SEED``; no network)::

    python tests/data/tinyseg/data.py

Twelve 128x160 samples (``tinyseg_000`` .. ``tinyseg_011``), each ``images/NAME.png`` (RGB),
``labels/NAME.png`` (class ids, mode L), ``segmented/NAME.png`` (class colours), and a
``manifest.json`` (format version 1) that ``osmseg.output.manifest.read_manifest`` reads (synthetic
placeholders where a real build records places and providers) with the class table below.

Each scene: a grass background, one road band across the image (horizontal or vertical),
2-4 building rectangles, a water rectangle in about half of the scenes, and one rectangle
whose *label* is 0 (unlabeled, an "OSM gap") while the image still shows what is there.
Image pixels are the class colour of :data:`IMAGE_COLOURS` plus noise in steps of 8 (small
PNGs), so a network can learn the classes from colour alone: the set is for learnability
checks, loaders and end-to-end CLI tests, not for realism. With 64x80 patches each image
gives 4 patches (2x2, no leftover border).
"""

from __future__ import annotations

import hashlib
import io
import json
import shutil
from pathlib import Path

import numpy as np
from PIL import Image

HERE = Path(__file__).resolve().parent
SEED = 0
COUNT = 12
HEIGHT, WIDTH = 128, 160
PATCH = (64, 80)
NAME = "tinyseg"

#: (id, name, colour in segmented/ and the class table)
CLASSES = [
    (0, "unlabeled", (0, 0, 0)),
    (1, "building", (255, 255, 0)),
    (2, "highway", (50, 50, 255)),
    (3, "grass", (0, 255, 0)),
    (4, "water", (119, 242, 242)),
]
UNLABELED, BUILDING, HIGHWAY, GRASS, WATER = range(5)
#: What each class looks like in the aerial image (not its mask colour).
IMAGE_COLOURS = {BUILDING: (200, 120, 90), HIGHWAY: (90, 90, 100), GRASS: (70, 150, 60), WATER: (40, 90, 160)}


def class_table() -> dict:
    """The dataset's class table in ``ClassTable.to_dict()`` form."""
    return {"name": NAME, "classes": [{"id": i, "name": n, "color": list(c)} for i, n, c in CLASSES]}


def _rect(rng: np.random.Generator, min_size: int, max_size: int) -> tuple[slice, slice]:
    h, w = (int(v) for v in rng.integers(min_size, max_size + 1, size=2))
    top, left = int(rng.integers(0, HEIGHT - h + 1)), int(rng.integers(0, WIDTH - w + 1))
    return slice(top, top + h), slice(left, left + w)


def scene(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One (image RGB uint8, label uint8) pair drawn from ``rng``."""
    truth = np.full((HEIGHT, WIDTH), GRASS, dtype=np.uint8)
    if rng.random() < 0.5:
        truth[_rect(rng, 30, 60)] = WATER
    band = int(rng.integers(8, 15))
    if rng.random() < 0.5:
        top = int(rng.integers(0, HEIGHT - band))
        truth[top:top + band, :] = HIGHWAY
    else:
        left = int(rng.integers(0, WIDTH - band))
        truth[:, left:left + band] = HIGHWAY
    for _ in range(int(rng.integers(2, 5))):
        truth[_rect(rng, 12, 30)] = BUILDING
    image = np.zeros((HEIGHT, WIDTH, 3), dtype=np.int16)
    for cls, colour in IMAGE_COLOURS.items():
        image[truth == cls] = colour
    image += (rng.integers(-2, 3, size=image.shape) * 8).astype(np.int16)
    label = truth.copy()
    label[_rect(rng, 16, 32)] = UNLABELED
    return np.clip(image, 0, 255).astype(np.uint8), label


def png_bytes(array: np.ndarray, mode: str) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(array, mode=mode).save(buf, format="PNG", compress_level=9)
    return buf.getvalue()


def main(out: Path = HERE) -> None:
    rng = np.random.default_rng(SEED)
    palette = np.zeros((256, 3), dtype=np.uint8)
    for i, _, colour in CLASSES:
        palette[i] = colour
    for folder in ("images", "labels", "segmented"):
        shutil.rmtree(out / folder, ignore_errors=True)
        (out / folder).mkdir(parents=True)
    samples = []
    for k in range(COUNT):
        name = f"{NAME}_{k:03d}"
        image, label = scene(rng)
        files = {f"images/{name}.png": png_bytes(image, "RGB"), f"labels/{name}.png": png_bytes(label, "L"),
                 f"segmented/{name}.png": png_bytes(palette[label], "RGB")}
        for rel, data in files.items():
            (out / rel).write_bytes(data)
        counts = np.bincount(label.ravel(), minlength=len(CLASSES))
        samples.append({
            "name": name, "center": None, "bbox_wgs84": None, "bounds_3857": None, "zoom": None,
            "ground_resolution_m": None, "tiles": [], "imagery": {"provider": "synthetic"}, "osm": {"source": "synthetic"},
            "class_histogram": {n: int(counts[i]) for i, n, _ in CLASSES},
            "files": {rel: hashlib.sha256(data).hexdigest() for rel, data in sorted(files.items())},
        })
    manifest = {
        "format": "osmseg-dataset", "format_version": 1, "name": NAME,
        "tool": {"name": "osmseg", "version": "0.1.0"},
        "command": "python tests/data/tinyseg/data.py", "seed": SEED,
        "area": {"name": NAME, "kind": "custom", "lat": None, "lon": None, "radius_km": None, "bbox": None},
        "zoom": None, "grid_size": None, "image_format": "png", "classes": class_table(), "filters": {},
        "imagery": {"name": "synthetic", "note": "rectangles of class colours plus noise (tests/data/tinyseg/data.py)"},
        "osm": {"name": "synthetic"}, "samples": samples, "rejected": [],
        "summary": {"requested": COUNT, "accepted": COUNT, "rejected": 0, "attempts": COUNT, "max_attempts": COUNT,
                    "rejected_by_reason": {}, "complete": True},
    }
    (out / "manifest.json").write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
