"""A per-pixel baseline for building segmentation, and the scores every method is given.

What a network must beat to have learnt shapes rather than colours: a logistic regression
(scikit-learn, the ``bench`` extra) on each pixel's own colour and its neighbourhood, nine
features: R, G, B, and the mean and standard deviation of each channel over the 7x7 window
around it (box filters, ``scipy.ndimage.uniform_filter``). Features are standardised with
the training pixels' mean and spread. It is fitted on a seeded random subsample of the
labelled training pixels, either unweighted or with ``class_weight="balanced"`` (each class
weighted by the inverse of its share, as median-frequency weights do for a network).

:func:`building_scores` is the one scoring function of ``bench_real_heldout.py``: building
IoU and pixel accuracy of a boolean prediction against a boolean truth over the valid
pixels, counted with numpy, for the network's masks and the baseline's alike.

>>> truth = np.array([[1, 1, 0, 0]], bool)
>>> building_scores(np.array([[1, 0, 1, 0]], bool), truth, np.ones_like(truth))
{'building_iou': 0.3333, 'pixel_accuracy': 0.5, 'pixels': 4}
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import uniform_filter
from sklearn.linear_model import LogisticRegression
from sklearn.pipeline import Pipeline, make_pipeline
from sklearn.preprocessing import StandardScaler

WINDOW = 7
FEATURES = ("R", "G", "B", *(f"{s} {c} {WINDOW}x{WINDOW}" for s in ("mean", "std") for c in "RGB"))


def pixel_features(rgb: np.ndarray, window: int = WINDOW) -> np.ndarray:
    """``(H, W, 9)`` float32: each pixel's RGB (0..1), and per channel the mean and standard
    deviation over the ``window`` x ``window`` box around it (borders reflected).

    >>> f = pixel_features(np.full((5, 5, 3), 255, np.uint8))
    >>> f.shape, float(f[2, 2, 0]), float(f[2, 2, 3]), float(f[2, 2, 6])
    ((5, 5, 9), 1.0, 1.0, 0.0)
    """
    x = np.asarray(rgb, dtype=np.float32)[:, :, :3] / 255.0
    size = (window, window, 1)
    mean = uniform_filter(x, size=size, mode="reflect")
    square = uniform_filter(x * x, size=size, mode="reflect")
    std = np.sqrt(np.clip(square - mean * mean, 0.0, None))
    return np.concatenate([x, mean, std], axis=2)


@dataclass(frozen=True)
class Fitted:
    """A fitted baseline and what it was fitted on."""

    model: Pipeline
    balanced: bool
    samples: int
    seed: int
    positive_share: float  # building share of the fitted pixels

    def predict(self, rgb: np.ndarray, rows: int = 256) -> np.ndarray:
        """Boolean building mask of an image, ``rows`` image rows at a time (bounded memory)."""
        features = pixel_features(rgb)
        out = np.zeros(features.shape[:2], dtype=bool)
        for top in range(0, features.shape[0], rows):
            block = features[top:top + rows]
            out[top:top + rows] = self.model.predict(block.reshape(-1, block.shape[2])).reshape(block.shape[:2])
        return out


def fit_baseline(images: Sequence[np.ndarray], positives: Sequence[np.ndarray], valid: Sequence[np.ndarray],
                 samples: int, seed: int, balanced: bool) -> Fitted:
    """Logistic regression on ``samples`` pixels drawn (uniformly, seeded) from the ``valid``
    pixels of ``images``, labelled True where ``positives`` is."""
    feats, truth = [], []
    for rgb, pos, ok in zip(images, positives, valid, strict=True):
        f = pixel_features(rgb)
        feats.append(f[ok])
        truth.append(pos[ok])
    x, y = np.concatenate(feats), np.concatenate(truth)
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(x), size=min(samples, len(x)), replace=False)
    x, y = x[pick], y[pick]
    if y.all() or not y.any():
        raise ValueError("the training pixels hold one class only: nothing for the baseline to tell apart")
    model = make_pipeline(StandardScaler(), LogisticRegression(
        class_weight="balanced" if balanced else None, max_iter=1000, random_state=seed))
    model.fit(x, y)
    return Fitted(model=model, balanced=balanced, samples=len(y), seed=seed, positive_share=round(float(y.mean()), 4))


def resample(rgb: np.ndarray, scale: float) -> np.ndarray:
    """An image ``scale`` times as many pixels across (bilinear up, area-averaged down)."""
    h, w = rgb.shape[:2]
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    return cv2.resize(rgb, size, interpolation=cv2.INTER_LINEAR if scale >= 1 else cv2.INTER_AREA)


def back_to_grid(mask: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A boolean mask brought onto a ``shape`` grid with nearest neighbour (as ``osmseg
    predict --resolution`` brings its classes back onto the input's grid)."""
    return cv2.resize(mask.astype(np.uint8), (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST).astype(bool)


def building_scores(pred: np.ndarray, truth: np.ndarray, valid: np.ndarray) -> dict[str, float | int]:
    """Building IoU and pixel accuracy (building vs the rest) over the ``valid`` pixels."""
    p, t = pred[valid], truth[valid]
    union = int(np.count_nonzero(p | t))
    iou = np.count_nonzero(p & t) / union if union else float("nan")
    accuracy = np.count_nonzero(p == t) / p.size if p.size else float("nan")
    return {"building_iou": round(float(iou), 4), "pixel_accuracy": round(float(accuracy), 4), "pixels": int(p.size)}
