"""Generate the data of the RGB localization pipeline test (tests/localize/test_loc_rgb.py).

A seeded town (classes13 ids, irregular streets, no grass: paved ground, so every ground pixel
the camera sees has a CamVid class) is turned into

* an aerial "photo": each class in its own colour with seeded noise, and its labels, cut into
  an osmseg-layout training set (``images/`` + ``labels/`` + ``classes.toml``);
* ground panoramas rendered at seeded viewpoints (:mod:`localization.bench.render`), relabelled to
  CamVid ids (``camvid.toml``: Sky 0, Building 1, Road 3, Pavement 4, Tree 5) and painted as
  photos the same way, in the CamVid layout (``train/``, ``trainannot/``, ``val/``, ``valannot/``).

Run ``python tests/data/rgbpipe/data.py OUT`` to write them; the test calls :func:`generate`.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from localization.bench.render import RenderConfig, render_panorama  # noqa: E402
from osmseg.classes import load_class_table  # noqa: E402

AERIAL = load_class_table("classes13.toml")
CAMVID = load_class_table("camvid.toml")
ID = {c.name: c.id for c in AERIAL.classes}
RES = 0.5            # m/px
SIZE = 320
#: aerial13 (+ sky) class -> CamVid id
TO_CAMVID = {"building": 1, "highway": 3, "footway": 4, "tree": 5, "sky": 0}
PANO = RenderConfig(width=616, height=112)   # half the CVUSA size: the ground model sees 1/4 of the pixels


def town(seed: int = 5) -> np.ndarray:
    """Streets 60-110 px apart with footways, buildings in the blocks, trees; paved ground between.

    Irregular streets: a regular grid makes every block look like the next.
    """
    rng = np.random.default_rng(seed)
    m = np.full((SIZE, SIZE), ID["footway"], np.uint8)
    cuts = {0: [], 1: []}
    for axis in (0, 1):
        at = int(rng.integers(20, 50))
        while at < SIZE - 10:
            cuts[axis].append(at)
            half = int(rng.integers(4, 7))
            if axis == 0:
                m[max(at - half, 0):at + half, :] = ID["highway"]
            else:
                m[:, max(at - half, 0):at + half] = ID["highway"]
            at += int(rng.integers(60, 110))
    for _ in range(300):
        w, h = rng.integers(10, 30, size=2)
        x, y = rng.integers(0, SIZE - 30, size=2)
        if (m[max(y - 3, 0):y + h + 3, max(x - 3, 0):x + w + 3] == ID["footway"]).all():
            m[y:y + h, x:x + w] = ID["building"]
    yy, xx = np.mgrid[:SIZE, :SIZE]
    for _ in range(20):
        x, y = rng.integers(8, SIZE - 8, size=2)
        if m[y, x] == ID["footway"]:
            m[((xx - x) ** 2 + (yy - y) ** 2 <= int(rng.integers(9, 25))) & (m == ID["footway"])] = ID["tree"]
    return m


def paint(labels: np.ndarray, colours: np.ndarray, seed: int) -> np.ndarray:
    """An RGB photo of a label image: each class's colour plus seeded noise (sd 8)."""
    rng = np.random.default_rng(seed)
    rgb = colours[labels].astype(np.float32) + rng.normal(0, 8, labels.shape + (3,))
    return np.clip(rgb, 0, 255).astype(np.uint8)


#: distinct photo colours per class id (not the table's colours: the model must not read ids off them)
AERIAL_COLOURS = np.zeros((256, 3), np.uint8)
for name, colour in (("building", (200, 80, 60)), ("highway", (70, 70, 80)), ("footway", (170, 170, 150)),
                     ("tree", (40, 120, 40))):
    AERIAL_COLOURS[ID[name]] = colour
GROUND_COLOURS = np.zeros((256, 3), np.uint8)
for cid, colour in ((0, (150, 190, 230)), (1, (180, 90, 70)), (3, (60, 60, 70)), (4, (160, 150, 140)),
                    (5, (50, 110, 40))):
    GROUND_COLOURS[cid] = colour


def camvid_labels(pano_labels: np.ndarray, table) -> np.ndarray:
    """A rendered panorama's labels (aerial13 + sky) in CamVid ids; anything else is void (11)."""
    lut = np.full(256, CAMVID.unlabeled.id, np.uint8)
    for name, cid in TO_CAMVID.items():
        lut[table.by_name[name].id] = cid
    return lut[pano_labels]


def viewpoints(mask: np.ndarray, n: int, seed: int) -> list[tuple[float, float]]:
    """``n`` seeded viewpoints on paved ground, 30 px from the border."""
    rng = np.random.default_rng(seed)
    ys, xs = np.nonzero(np.isin(mask[30:-30, 30:-30], [ID["footway"], ID["highway"]]))
    pick = rng.choice(len(xs), n, replace=False)
    return [(float(xs[i] + 30), float(ys[i] + 30)) for i in pick]


def generate(out: Path, seed: int = 5) -> dict[str, Path]:
    """Write the aerial training set, the CamVid-layout ground set and the test pair; return their paths."""
    out = Path(out)
    mask = town(seed)
    aerial = out / "aerial"
    for sub in ("images", "labels"):
        (aerial / sub).mkdir(parents=True, exist_ok=True)
    shutil.copy(ROOT / "data_manifests" / "classes13.toml", aerial / "classes.toml")
    photo = paint(mask, AERIAL_COLOURS, seed)
    k = 0
    for y in range(0, SIZE - 127, 32):
        for x in range(0, SIZE - 159, 40):
            Image.fromarray(photo[y:y + 128, x:x + 160]).save(aerial / "images" / f"a{k:02d}.png")
            Image.fromarray(mask[y:y + 128, x:x + 160]).save(aerial / "labels" / f"a{k:02d}.png")
            k += 1
    ground = out / "camvid"
    views = viewpoints(mask, 20, seed + 1)
    for i, xy in enumerate(views[:-1]):  # the last one is the test's query, never trained on
        split = "val" if i % 5 == 4 else "train"
        for sub in (split, f"{split}annot"):
            (ground / sub).mkdir(parents=True, exist_ok=True)
        pano = render_panorama(mask, AERIAL, RES, xy, PANO)
        labels = camvid_labels(pano.labels, pano.table)
        Image.fromarray(paint(labels, GROUND_COLOURS, 100 + i)).save(ground / split / f"g{i:02d}.png")
        Image.fromarray(labels).save(ground / f"{split}annot" / f"g{i:02d}.png")
    query_xy = views[-1]
    pano = render_panorama(mask, AERIAL, RES, query_xy, PANO)
    Image.fromarray(paint(camvid_labels(pano.labels, pano.table), GROUND_COLOURS, 999)).save(out / "query.png")
    Image.fromarray(photo).save(out / "aerial.png")
    (out / "truth.txt").write_text(f"{query_xy[0]},{query_xy[1]}\n")
    return {"aerial_set": aerial, "ground_set": ground, "aerial": out / "aerial.png", "query": out / "query.png",
            "truth": out / "truth.txt"}


if __name__ == "__main__":
    print(generate(Path(sys.argv[1])))
