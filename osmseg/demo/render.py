"""Render a plausible aerial image from a label mask (for demos, fixtures and benchmarks).

Real aerial imagery from Bing, Esri or Mapbox may not be redistributed, so the project's
recorded fixtures carry imagery *rendered from OSM labels*: each class gets a material colour
(roof, asphalt, grass, canopy, water ...), low-frequency brightness variation, per-pixel
noise, soft edges and building shadows. It is not meant to fool anyone; it gives pictures
whose content lines up with the labels exactly, which is what the demo and tests need.

>>> import numpy as np
>>> labels = np.zeros((64, 64), dtype=np.uint8); labels[16:48, 16:48] = 1
>>> img = render_aerial(labels, seed=0)
>>> img.shape, img.dtype
((64, 64, 3), dtype('uint8'))
>>> bool(img[32, 32].mean() > img[60, 60].mean() - 60)
True
"""

from __future__ import annotations

import numpy as np
from PIL import Image, ImageFilter

#: Material colours by 13-class name; unlabeled ground is a warm urban grey.
MATERIALS: dict[str, tuple[int, int, int]] = {
    "unlabeled": (150, 142, 128),
    "building": (176, 160, 150),
    "highway": (78, 78, 84),
    "grass": (112, 152, 72),
    "natural": (58, 92, 46),
    "construction": (160, 132, 104),
    "industrial": (138, 134, 140),
    "beach": (222, 206, 160),
    "water": (44, 76, 104),
    "footway": (186, 178, 166),
    "parking": (112, 112, 116),
    "park": (96, 140, 66),
    "dirt road": (156, 124, 88),
    "tree": (46, 96, 44),
}

#: Class ids of the 13-class table (data_manifests/classes13.toml).
IDS13 = {
    "unlabeled": 0, "building": 1, "highway": 2, "grass": 3, "natural": 4, "construction": 5,
    "industrial": 6, "beach": 7, "water": 8, "footway": 9, "parking": 10, "park": 11,
    "dirt road": 12, "tree": 13,
}


def _smooth_noise(shape: tuple[int, int], rng: np.random.Generator, scale: int) -> np.ndarray:
    """Low-frequency noise in [-1, 1]: random values on a coarse grid, bilinearly upsampled."""
    h, w = shape
    coarse = rng.uniform(-1, 1, size=(h // scale + 2, w // scale + 2)).astype(np.float32)
    img = Image.fromarray(coarse, mode="F").resize((w + 2 * scale, h + 2 * scale), Image.Resampling.BILINEAR)
    return np.asarray(img)[scale : scale + h, scale : scale + w]


def render_aerial(labels: np.ndarray, seed: int = 0) -> np.ndarray:
    """An ``(H, W, 3)`` uint8 image whose materials follow the 13-class ``labels``.

    Deterministic for a given ``labels`` and ``seed``.
    """
    rng = np.random.default_rng(seed)
    h, w = labels.shape
    lut = np.zeros((256, 3), dtype=np.float32)
    for name, rgb in MATERIALS.items():
        lut[IDS13[name]] = rgb
    img = lut[labels]
    # roofs vary from block to block, vegetation and water less so
    variation = _smooth_noise((h, w), rng, 24)[..., None]
    amount = np.where(labels == IDS13["building"], 38.0, 14.0)[..., None]
    img = img + variation * amount
    # canopy texture: darker blobs inside trees and natural areas
    leafy = np.isin(labels, [IDS13["tree"], IDS13["natural"], IDS13["park"]])[..., None]
    img = img + leafy * _smooth_noise((h, w), rng, 3)[..., None] * 18.0
    # shadows: building mask shifted towards the south-east darkens what it falls on
    building = labels == IDS13["building"]
    shadow = np.zeros_like(building)
    shadow[4:, 3:] = building[:-4, :-3]
    img = np.where((shadow & ~building)[..., None], img * 0.55, img)
    img = img + rng.normal(0.0, 6.0, size=img.shape)
    out = Image.fromarray(np.clip(img, 0, 255).astype(np.uint8), mode="RGB")
    return np.asarray(out.filter(ImageFilter.GaussianBlur(radius=0.8)))
