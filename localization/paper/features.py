"""Image features of landmarks from a segmentation network's encoder, for §5.3.2 edge removal.

The dissertation removes the graph edge between two landmarks whose image features are
closer than a threshold: two landmarks that look alike (two parts of one building) say
little about the place together. :func:`landmark_features` gives each landmark a trained
SegNet's *encoder* output at its position; :class:`FeatureEdges` turns those into the
``(K, K)`` mask :func:`~localization.paper.match.localize` takes as ``aerial_drop``/``query_drop``
(by :func:`~localization.paper.edges.feature_edge_mask`) and counts what it removed.

The image is **resized** to the nearest multiple of the stage's cell (32 px for the deepest
stage) and encoded in one pass, not tiled: the scale changes by at most half a cell per side
(2 % for a 750 px image), the cells then tile the image exactly (none is part padding), and
no tile seam cuts a receptive field. Coordinates follow the resize without arithmetic: they
are sampled relative to the image size, which the resize keeps. The price is memory growing
with the image (the first stage holds ``64 * width * H * W`` floats), fine for the 1-2 Mpx
images localized here. torch (the ``train`` extra) is imported only inside the functions
that run the network; without it they raise a one-line :class:`~osmseg.errors.ConfigError`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
from scipy import sparse

from localization.common.landmarks import Landmarks
from localization.paper.edges import feature_edge_mask
from localization.paper.graph import Cliques, adjacency
from osmseg.errors import ConfigError
from osmseg.images import as_rgb

__all__ = ["DEEPEST", "FeatureEdges", "dropped_edges", "fitted_size", "landmark_features"]

#: SegNet's encoder has five stages; stage ``s`` ends in a 2x2 pooling, so its cells are 2**s px.
DEEPEST = 5
REDUCTIONS, METRICS = ("none", "pca", "umap"), ("euclidean", "cosine")


def _torch() -> Any:
    """The torch module, or a one-line ConfigError saying how to install it."""
    try:
        import torch
    except ImportError:
        raise ConfigError("landmark features need PyTorch: pip install 'osmseg[train]' "
                          "(or leave out --feature-threshold)") from None
    return torch


def fitted_size(n: int, step: int) -> int:
    """``n`` rounded to the nearest multiple of ``step`` (halves up), at least ``step``.

    >>> fitted_size(750, 32), fitted_size(224, 32), fitted_size(10, 32), fitted_size(1232, 32), fitted_size(48, 32)
    (736, 224, 32, 1248, 64)
    """
    return max(step, (2 * n + step) // (2 * step) * step)


def _model(model: Any, device: str) -> tuple[Any, Any]:
    """``(network, spec)`` from a checkpoint path, or an already loaded ``(network, spec)`` pair."""
    if isinstance(model, (str, Path)):
        from training.models.checkpoint import model_from_checkpoint

        model = model_from_checkpoint(Path(model), device=device)
    net, spec = model
    if not hasattr(getattr(net, "encoder", None), "features"):
        raise ConfigError(f"{type(net).__name__} has no SegNet encoder (encoder.features): landmark features are the "
                          "paper's SegNet encoder's; give a checkpoint of an --arch segnet or segnet-skip run")
    return net, spec


def _encode(encoder: Any, x: Any, stage: int) -> Any:
    """The encoder's output after the pooling of ``stage`` (1..5): ``(N, C, H / 2**stage, W / 2**stage)``."""
    from torch import nn

    done = 0
    for layer in encoder.features:
        if isinstance(layer, nn.MaxPool2d):
            x = layer(x)[0]  # (pooled, indices)
            done += 1
            if done == stage:
                break
        else:
            x = layer(x)
    return x


def _component_cells(landmarks: Landmarks, h: int, w: int) -> sparse.csr_matrix:
    """``(K, h * w)``: the share of each landmark's pixels that falls in each feature cell.

    A pixel ``(x, y)`` is in cell ``(floor((y + 0.5) h / H), floor((x + 0.5) w / W))``: the
    cells tile the (resized) image exactly, so this is the cell the resize puts it in.
    """
    sizes = [len(p) for p in landmarks.pixels or ()]
    pix = np.concatenate(landmarks.pixels or ()).astype(np.float64)
    col = np.minimum(((pix[:, 0] + 0.5) * w / landmarks.width).astype(np.int64), w - 1)
    row = np.minimum(((pix[:, 1] + 0.5) * h / landmarks.height).astype(np.int64), h - 1)
    owner = np.repeat(np.arange(len(sizes)), sizes)
    weight = np.repeat(1.0 / np.asarray(sizes, dtype=np.float64), sizes)
    return sparse.csr_matrix((weight, (owner, row * w + col)), shape=(len(sizes), h * w))  # duplicates summed


def landmark_features(image_rgb: np.ndarray, landmarks: Landmarks, model: Any, *, stage: int = DEEPEST,
                      device: str = "cpu") -> np.ndarray:
    """``(K, C)`` encoder features of the landmarks of ``image_rgb``, one row per landmark.

    Args:
        image_rgb: ``(H, W, 3)`` uint8 (grey or RGBA are converted as inference does), the
            image the landmarks were found in: ``H, W`` must be the landmarks' height and width.
        landmarks: their positions; for component landmarks (``pixels`` not None) the feature
            is the mean of the cells their pixels fall in, weighted by how many fall in each.
        model: a checkpoint path, or a ``(SegNet, ModelSpec)`` pair (as
            :func:`~training.models.checkpoint.model_from_checkpoint` returns).
        stage: the encoder stage whose pooled output is sampled (5, the deepest: the encoder's
            output, cells of 32 px that see ~200 px). device: as inference (cpu, cuda, cuda:N).

    The image is resized to multiples of ``2**stage`` (see the module docstring), normalised
    with the checkpoint's mean and std exactly as inference does
    (:func:`training.inference.windows.normalise`), and encoded once. A point landmark at ``(x, y)``
    gets the bilinear sample of the feature map at the same relative position (cell centres
    at ``(j + 1/2) W / w - 1/2``; positions past the outer cell centres take the edge cell's).
    """
    torch = _torch()
    from training.devices import pick_device
    from training.inference.windows import normalise

    if not 1 <= stage <= DEEPEST:
        raise ConfigError(f"encoder stage must be 1..{DEEPEST}, got {stage}")
    pixels = as_rgb(np.asarray(image_rgb), "image")
    height, width = pixels.shape[:2]
    if (width, height) != (landmarks.width, landmarks.height):
        raise ConfigError(f"the image is {width}x{height} but the landmarks are of a {landmarks.width}x"
                          f"{landmarks.height} image; give the photo the landmarks were found in")
    dev = pick_device(device)
    net, spec = _model(model, device)
    net = net.to(dev).eval()
    step = 2 ** stage
    size = (fitted_size(width, step), fitted_size(height, step))
    if size != (width, height):
        from PIL import Image

        pixels = np.asarray(Image.fromarray(np.ascontiguousarray(pixels)).resize(size, Image.Resampling.BILINEAR))
    mean = torch.tensor(spec.mean, dtype=torch.float32, device=dev).view(1, 3, 1, 1)
    std = torch.tensor(spec.std, dtype=torch.float32, device=dev).view(1, 3, 1, 1)
    cuda = dev.type == "cuda"
    with torch.inference_mode(), torch.autocast(dev.type, enabled=cuda):
        x = normalise(np.array(pixels[None]), mean, std)  # a copy: torch wants writable arrays
        if cuda:
            x = x.contiguous(memory_format=torch.channels_last)
        fmap = _encode(net.encoder, x, stage).float()  # (1, C, h, w)
        if len(landmarks) == 0:
            return np.zeros((0, fmap.shape[1]))
        if landmarks.pixels is None:
            xy = torch.as_tensor(landmarks.xy, dtype=torch.float32, device=dev)
            scale = torch.tensor([width, height], dtype=torch.float32, device=dev)
            grid = ((2 * xy + 1) / scale - 1).view(1, 1, -1, 2)  # -1/+1 = the image's outer edges
            sampled = torch.nn.functional.grid_sample(fmap, grid, mode="bilinear", padding_mode="border",
                                                      align_corners=False)
            return cast("np.ndarray", sampled[0, :, 0, :].T.double().cpu().numpy())
    cells = fmap[0].flatten(1).T.double().cpu().numpy()  # (h * w, C)
    return np.asarray(_component_cells(landmarks, fmap.shape[2], fmap.shape[3]) @ cells)


@dataclass(frozen=True)
class FeatureEdges:
    """§5.3.2 settings: landmark pairs whose features are closer than ``threshold`` lose their edge.

    ``metric`` and ``reduce``/``components`` are those of
    :func:`~localization.paper.edges.feature_edge_mask` (``reduce="none"``: the raw features);
    ``stage`` is the encoder stage sampled (:func:`landmark_features`).

    >>> FeatureEdges(0.1, metric="cosine", reduce="pca").settings()
    {'threshold': 0.1, 'metric': 'cosine', 'reduce': 'pca', 'components': 8, 'stage': 5}
    """

    threshold: float
    metric: str = "cosine"
    reduce: str = "pca"
    components: int = 8
    stage: int = DEEPEST

    def __post_init__(self) -> None:
        ok = np.isfinite(self.threshold) and self.threshold > 0 and self.components >= 1 and 1 <= self.stage <= DEEPEST
        if not ok or self.metric not in METRICS or self.reduce not in REDUCTIONS:
            raise ConfigError(f"feature edges need a threshold > 0, metric in {METRICS}, reduce in {REDUCTIONS}, "
                              f"components >= 1 and stage 1..{DEEPEST}; got {self.settings()}")

    def settings(self) -> dict[str, Any]:
        """The settings as a JSON-able dict (what ``result.json`` records)."""
        return {"threshold": self.threshold, "metric": self.metric, "reduce": self.reduce,
                "components": self.components, "stage": self.stage}

    def drop(self, features: np.ndarray) -> np.ndarray:
        """``(K, K)`` bool: the landmark pairs whose features are closer than the threshold."""
        if len(features) < 2:  # no pair, and PCA of a single row has nothing to project
            return np.zeros((len(features), len(features)), dtype=bool)
        return feature_edge_mask(features, self.threshold, metric=self.metric,
                                 reduce=None if self.reduce == "none" else self.reduce, components=self.components)

    def mask(self, image_rgb: np.ndarray, landmarks: Landmarks, model: Any, device: str = "cpu") -> np.ndarray:
        """:meth:`drop` of the :func:`landmark_features` of ``landmarks`` in ``image_rgb``."""
        return self.drop(landmark_features(image_rgb, landmarks, model, stage=self.stage, device=device))

    def masks(self, sides: Mapping[str, tuple[np.ndarray | None, Landmarks, Any]],
              device: str = "cpu") -> dict[str, np.ndarray | None]:
        """Per side, the :meth:`mask` of ``(photo, landmarks, model)``; None for a side without a photo.

        A side given as a mask or a landmark file alone has no image to take features from: it
        keeps all its edges. At least one side must have a photo, and each photo a model.
        """
        if all(photo is None for photo, _, _ in sides.values()):
            raise ConfigError("--feature-threshold needs an RGB image: give --aerial-image or --ground-image (the photo "
                              "of the mask or landmark file), or an RGB --aerial/--ground with its --*-checkpoint")
        for name, (photo, _, model) in sides.items():
            if photo is not None and model is None:
                raise ConfigError(f"--feature-threshold needs an encoder for the {name} image's features: "
                                  "give --feature-checkpoint")
        return {name: None if photo is None else self.mask(photo, lm, model, device)
                for name, (photo, lm, model) in sides.items()}

    def summary(self, drops: Mapping[str, np.ndarray | None], graphs: Mapping[str, tuple[Landmarks, int]],
                cliques: Callable[[Landmarks, int], Cliques]) -> dict[str, Any]:
        """The :meth:`settings` and, per side, :func:`dropped_edges` (None: no features, every edge kept).

        ``graphs`` gives each side's landmarks and the window its graph was built with (the
        answer's; 0 when none was built: only the pairs are counted then); ``cliques`` builds a
        graph as the answer's were (:meth:`~localization.paper.config.PaperConfig.cliques`).
        """
        out = self.settings()
        for name, drop in drops.items():
            lm, window = graphs[name]
            out[name] = None if drop is None else dropped_edges(drop, cliques(lm, window) if window else None)
        return out


def dropped_edges(drop: np.ndarray, cliques: Cliques | None = None) -> dict[str, int]:
    """What a mask removes: the landmark ``pairs`` it holds; with ``cliques``, the graph's ``edges``
    and how many of them are ``dropped`` (a pair is an edge only when a window holds both).

    >>> drop = np.array([[0, 1, 1], [1, 0, 0], [1, 0, 0]], bool)
    >>> dropped_edges(drop, Cliques(np.array([[1, 1, 0], [0, 1, 1]], bool), np.zeros((2, 2)), 10))
    {'pairs': 2, 'edges': 2, 'dropped': 1}
    """
    upper = np.triu(np.asarray(drop, dtype=bool), k=1)
    out = {"pairs": int(upper.sum())}
    if cliques is not None:
        edges = np.triu(adjacency(cliques), k=1)
        out.update(edges=int(edges.sum()), dropped=int((edges & upper).sum()))
    return out
