"""``osmseg localize``: where in the aerial image was the ground panorama taken?

Each side (``--aerial``, ``--ground``) is a label mask (PNG/TIFF of class ids), a landmark file
(``x y Class`` lines, ``.csv`` or ``.npy``), or an RGB image with ``--*-checkpoint`` to segment
it first. A mask's class table is ``--*-table``, else the ``manifest.json`` of the osmseg
dataset it belongs to (``DATASET/labels/NAME.png``), else the one the landmark dictionary names
(``mask_table``/``mask_classes`` in ``data_manifests/landmarks-*.toml``). A landmark file's
image size is ``--*-size``, else that of an image beside it with the same name (also drawn
under the pictures), else the extent of its landmarks (with a warning).

``--feature-threshold T`` removes the graph edges between landmarks whose encoder features
are closer than T (§5.3.2, :mod:`localization.features`) on each side that is an RGB image or
has its photo as ``--*-image``; result.json's ``feature_edges`` says how many went per side.

The top-k locations go to stdout (a table, or JSON with ``--json``); "unanswered" (no place
in the aerial image shows every class the ground sees) is a normal outcome: exit 0. Bad input
(an unreadable file, no landmarks, a window larger than the image, landmarks of a single
class on both sides) is a one-line error, exit 1 (2 for options).
"""

from __future__ import annotations

import json
import logging
import math
import re
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import click
import numpy as np

from osmseg.cli.common import report_errors
from osmseg.errors import ConfigError, DatasetError, ImageryError

logger = logging.getLogger(__name__)

LANDMARK_SUFFIXES = (".txt", ".csv", ".npy", ".lm")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff")


@dataclass(frozen=True)
class Side:
    """One image's landmarks, what to draw under them, and its ground resolution if known.

    ``paint`` draws a mask's colour picture when there is no RGB ``background``; it runs only
    when pictures are asked for (it needs matplotlib's colours). ``photo`` is the RGB image
    the landmarks were found in (segmented, or given by --*-image): the one landmark
    features (--feature-threshold) are computed from; None for a mask or landmark file alone.
    """

    landmarks: Any  # localization.landmarks.Landmarks
    background: np.ndarray | None
    resolution: float | None
    paint: Callable[[], np.ndarray] | None = None
    photo: np.ndarray | None = None

    def picture(self) -> np.ndarray | None:
        """The RGB image to draw under the landmarks, if any."""
        return self.background if self.background is not None or self.paint is None else self.paint()


@dataclass(frozen=True)
class SideOptions:
    """How to read one side (the command's ``--aerial-*`` or ``--ground-*`` options)."""

    name: str  # "aerial" or "ground": for messages
    classes: str
    table: str | None
    size: tuple[int, int] | None
    checkpoint: Path | None
    panorama: bool
    mode: str
    min_size: int
    grid_stride: int


# --------------------------------------------------------------------------- parsing options


def _size(value: str | None, option: str) -> tuple[int, int] | None:
    """``"750x750"`` -> (750, 750).

    >>> _size("1232x224", "--ground-size"), _size(None, "--ground-size")
    ((1232, 224), None)
    """
    if value is None:
        return None
    m = re.fullmatch(r"\s*(\d+)\s*[xX,]\s*(\d+)\s*", value)
    if not m or int(m.group(1)) < 1 or int(m.group(2)) < 1:
        raise ConfigError(f"{option} must be WIDTHxHEIGHT in pixels, e.g. 750x750; got {value!r}")
    return int(m.group(1)), int(m.group(2))


def _point(value: str | None) -> tuple[float, float] | None:
    """``"375,380"`` -> (375.0, 380.0).

    >>> _point("375,380.5")
    (375.0, 380.5)
    """
    if value is None:
        return None
    try:
        x, y = (float(v) for v in value.split(","))
    except ValueError:
        raise ConfigError(f"--truth must be X,Y in aerial pixels, e.g. 375,380; got {value!r}") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise ConfigError(f"--truth must be finite numbers, got {value!r}")
    return x, y


def _window(value: str) -> int | None:
    """``--window``: pixels, or None for "auto".

    >>> _window("auto"), _window("120")
    (None, 120)
    """
    if value.strip().lower() == "auto":
        return None
    try:
        w = int(value)
    except ValueError:
        raise ConfigError(f"--window must be a number of pixels or 'auto', got {value!r}") from None
    if w < 1:
        raise ConfigError(f"--window must be at least 1 pixel, got {w}")
    return w


def _windows(value: str) -> tuple[int, ...]:
    """``--windows``: pixel sizes, coarse to fine.

    >>> _windows("400,200,100")
    (400, 200, 100)
    """
    try:
        sizes = tuple(int(v) for v in value.split(","))
    except ValueError:
        raise ConfigError(f"--windows must be pixel sizes, coarse to fine, e.g. 400,200,100; got {value!r}") from None
    if not sizes or min(sizes) < 1:
        raise ConfigError(f"--windows must be positive pixel sizes, got {value!r}")
    return sizes


def _dictionary(name: str) -> Any:
    """A landmark class dictionary by name ("aerial13", "landmarks-aerial13", a .toml path)."""
    from localization.landmarks import load_landmark_classes

    return load_landmark_classes(name)


# --------------------------------------------------------------------------- reading inputs


def _read_image(path: Path) -> tuple[np.ndarray, float | None]:
    """Pixels ``(H, W)`` or ``(H, W, bands)`` of an image, and its ground resolution (m/px) if georeferenced."""
    if path.suffix.lower() in (".tif", ".tiff"):
        import rasterio
        from rasterio.errors import RasterioError

        try:
            with rasterio.open(path) as src:
                data = src.read()
                resolution = _resolution(src)
        except (RasterioError, OSError) as exc:
            raise ImageryError(f"{path}: cannot read the image ({exc})") from None
        return (data[0] if data.shape[0] == 1 else np.moveaxis(data, 0, -1)), resolution
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as img:
            img.load()
            if img.mode in ("RGBA", "LA", "CMYK", "YCbCr", "HSV", "LAB"):
                img = img.convert("RGB")  # colour: an image to segment or to draw under the landmarks
            elif img.mode == "1":
                img = img.convert("L")
            return np.asarray(img), None  # "L", "P" (palette indices), "I;16", "I": class ids
    except (UnidentifiedImageError, OSError) as exc:
        raise ImageryError(f"{path}: cannot read the image ({exc})") from None


def _resolution(src: Any) -> float | None:
    """Metres per pixel of an open rasterio dataset (Web Mercator scaled at its centre latitude)."""
    if src.crs is None or src.transform.is_identity:
        return None
    res = abs(src.transform.a)
    if src.crs.is_geographic:
        return None
    if src.crs.to_epsg() == 3857:
        from pyproj import Transformer

        x, y = src.xy(src.height // 2, src.width // 2)
        lat = Transformer.from_crs(3857, 4326, always_xy=True).transform(x, y)[1]
        return res * math.cos(math.radians(lat))
    unit = (src.crs.linear_units or "").lower()
    return res if unit in ("metre", "meter", "m") else None


def _manifest_for(mask: Path) -> tuple[dict[str, Any], dict[str, Any], Path] | None:
    """The class table and sample entry of ``mask`` in the manifest of the osmseg dataset listing it, and its root.

    Looks at ``DATASET/labels/NAME.png`` -> ``DATASET/manifest.json`` (and a manifest beside the
    mask); a manifest that does not list the mask is not its own and is ignored.
    """
    for root in (mask.parent.parent, mask.parent):
        path = root / "manifest.json"
        if not path.is_file():
            continue
        try:
            manifest = json.loads(path.read_text(encoding="utf-8"))
            table = {"classes": list(manifest["classes"]["classes"])}
            samples = list(manifest.get("samples", ()))
        except (OSError, ValueError, KeyError, TypeError):
            raise DatasetError(f"{path}: not a readable osmseg dataset manifest; give the mask's class table "
                               "with --aerial-table/--ground-table") from None
        rel = mask.resolve().relative_to(root.resolve()).as_posix()
        sample = next((s for s in samples if isinstance(s, dict) and rel in s.get("files", {})), None)
        if sample is not None:
            return table, sample, root
    return None


def _mask_side(path: Path, pixels: np.ndarray, resolution: float | None, opts: SideOptions, dictionary: Any,
               rgb: np.ndarray | None, table_dict: dict[str, Any] | None) -> Side:
    """Landmarks of a label mask, with the best background at hand (RGB image, class colours)."""
    from localization.landmarks import landmarks_from_mask
    from osmseg.classes import load_class_table

    background = rgb
    if opts.table is not None:
        table = load_class_table(opts.table)
        ids: Any = {c.id: c.name for c in (table.unlabeled, *table.classes)}
        colours = {c.id: c.color for c in (table.unlabeled, *table.classes)}
    elif table_dict is not None:
        ids = {int(c["id"]): str(c["name"]) for c in table_dict["classes"]}
        colours = {int(c["id"]): tuple(c["color"]) for c in table_dict["classes"] if "color" in c}
    else:
        found = _manifest_for(path)
        if found is not None:
            table_dict, sample, root = found
            ids = {int(c["id"]): str(c["name"]) for c in table_dict["classes"]}
            colours = {int(c["id"]): tuple(c["color"]) for c in table_dict["classes"] if "color" in c}
            resolution = resolution or sample.get("ground_resolution_m")
            image = root / "images" / path.name
            if background is None and image.is_file():
                background = _rgb(_read_image(image)[0])
        else:
            ids, colours = None, {}
    mask = pixels.astype(np.int64)
    lm = landmarks_from_mask(mask, ids, dictionary, mode=opts.mode, stride=opts.grid_stride,
                             min_size=opts.min_size, panorama=opts.panorama)
    paint: Callable[[], np.ndarray] | None = None
    if background is None and 0 <= int(mask.min()) and int(mask.max()) < 256:
        names = ids if ids is not None else dictionary.mask_ids()

        def paint_mask() -> np.ndarray:
            return _colourise(mask, colours, names, dictionary)
        paint = paint_mask
    return Side(lm, background, resolution, paint)


def _colourise(mask: np.ndarray, colours: dict[int, Any], ids: dict[int, str] | None, dictionary: Any) -> np.ndarray:
    """An RGB picture of a class mask: its table's colours, else pale landmark-class colours (others grey)."""
    lut = np.full((256, 3), 235, dtype=np.uint8)
    if colours:
        for cid, rgb_colour in colours.items():
            if 0 <= cid < 256:
                lut[cid] = rgb_colour
    elif ids:
        from matplotlib.colors import to_rgb

        from localization.pictures import class_colours

        palette = dict(zip(dictionary.names, class_colours(dictionary.names)))
        for cid, name in ids.items():
            target = dictionary.mapping.get(name)
            if target is not None and 0 <= cid < 256:  # pale, so the graph drawn over it stands out
                lut[cid] = [round(255 - 0.45 * (255 - 255 * v)) for v in to_rgb(palette[target])]
    return lut[mask]


def _rgb(pixels: np.ndarray) -> np.ndarray | None:
    """``pixels`` as an RGB image for drawing, or None if it is not one."""
    if pixels.ndim == 3 and pixels.shape[2] >= 3:
        rgb = pixels[:, :, :3]
        return rgb if rgb.dtype == np.uint8 else np.clip(rgb, 0, 255).astype(np.uint8)
    if pixels.ndim == 2 and pixels.dtype == np.uint8:
        return np.repeat(pixels[:, :, None], 3, axis=2)
    return None


def _segmented_side(path: Path, pixels: np.ndarray, resolution: float | None, opts: SideOptions,
                    dictionary: Any) -> Side:
    """Segment an RGB image with ``opts.checkpoint`` (needs PyTorch), then read its mask."""
    from osmseg.cli.common import require_torch

    require_torch()
    from training.checkpoint import model_from_checkpoint
    from training.infer import predict_array

    rgb = _rgb(pixels)
    if rgb is None:
        raise ConfigError(f"{path}: --{opts.name}-checkpoint needs an RGB image, got {pixels.shape}")
    model, spec = model_from_checkpoint(opts.checkpoint)  # type: ignore[arg-type]
    mask = predict_array(model, rgb, spec)
    return replace(_mask_side(path, mask, resolution, opts, dictionary, rgb, spec.class_table), photo=rgb)


def _landmark_file_side(path: Path, opts: SideOptions, dictionary: Any) -> Side:
    """Landmarks of an ``x y Class`` / CSV / .npy file, sized by --*-size, an image beside it, or their extent."""
    from localization.landmark_files import read_landmarks

    background, size = None, opts.size
    beside = next((path.with_suffix(s) for s in IMAGE_SUFFIXES if path.with_suffix(s).is_file()), None)
    resolution = None
    if beside is not None:
        pixels, resolution = _read_image(beside)
        background = _rgb(pixels)
        size = size or (pixels.shape[1], pixels.shape[0])
    if size is None:
        probe = read_landmarks(path, dictionary, 1 << 30, 1 << 30)
        if len(probe) == 0:
            size = (1, 1)
        else:
            size = (int(probe.xy[:, 0].max()) + 1, int(probe.xy[:, 1].max()) + 1)
        logger.warning("%s: no image size given (--%s-size) and no image beside it: using %dx%d, the landmarks' "
                       "extent%s", path, opts.name, size[0], size[1],
                       "; a panorama's width must be exact for its wrap-around" if opts.panorama else "")
    elif background is not None and (background.shape[1], background.shape[0]) != size:
        background = None  # an image of another size cannot be drawn under these landmarks
    return Side(read_landmarks(path, dictionary, size[0], size[1], panorama=opts.panorama), background, resolution)


def load_side(path: Path, opts: SideOptions) -> Side:
    """Read one side of the match from whatever ``path`` is (see the module docstring)."""
    dictionary = _dictionary(opts.classes)
    suffix = path.suffix.lower()
    if suffix in LANDMARK_SUFFIXES or suffix not in IMAGE_SUFFIXES:
        if opts.checkpoint is not None:
            raise ConfigError(f"--{opts.name}-checkpoint needs an image to segment, but {path.name} is a landmark file")
        return _landmark_file_side(path, opts, dictionary)
    pixels, resolution = _read_image(path)
    if opts.checkpoint is not None:
        return _segmented_side(path, pixels, resolution, opts, dictionary)
    if pixels.ndim != 2 or not np.issubdtype(pixels.dtype, np.integer):
        kind = f"{pixels.shape[2]}-band" if pixels.ndim == 3 else f"{pixels.dtype}"
        raise DatasetError(f"{path}: a {kind} image is not a label mask of class ids: give the mask, a landmark "
                           f"file, or --{opts.name}-checkpoint to segment it")
    return _mask_side(path, pixels, resolution, opts, dictionary, None, None)


def _with_photo(side: Side, path: Path | None, name: str) -> Side:
    """``side`` with the RGB photo of ``--NAME-image`` (for landmark features; drawn under the pictures)."""
    if path is None:
        return side
    rgb, lm = _rgb(_read_image(path)[0]), side.landmarks
    if rgb is None or rgb.shape[:2] != (lm.height, lm.width):
        got = "not an RGB image" if rgb is None else f"{rgb.shape[1]}x{rgb.shape[0]}"
        raise ConfigError(f"--{name}-image {path.name} is {got}; the {name} landmarks need the {lm.width}x{lm.height} "
                          f"RGB photo they were found in (or a matching --{name}-size)")
    return replace(side, background=rgb, photo=rgb)


# --------------------------------------------------------------------------- checks and output


def _check_inputs(aerial: Side, ground: Side, aerial_path: Path, ground_path: Path) -> None:
    """One-line errors for inputs no localization can use."""
    for side, path, name in ((aerial, aerial_path, "aerial"), (ground, ground_path, "ground")):
        lm = side.landmarks
        if len(lm) == 0:
            raise DatasetError(f"{path}: no landmarks of classes {', '.join(lm.classes)} found; check "
                               f"--{name}-classes and --{name}-table (or lower --min-size)")
    aerial_classes = {aerial.landmarks.classes[c] for c in np.unique(aerial.landmarks.cls)}
    ground_classes = {ground.landmarks.classes[c] for c in np.unique(ground.landmarks.cls)}
    if len(aerial_classes) == 1 and ground_classes <= aerial_classes:
        raise DatasetError(f"both images have landmarks of one class only ({aerial_classes.pop()}): every place would "
                           "match equally; use masks or landmark files with more classes")


def _table(result: Any) -> str:
    """The top-k as a fixed-width table."""
    lines = [f"{'rank':>4}  {'x':>8}  {'y':>8}  {'posterior':>10}  {'likelihood':>10}"]
    for rank, ((x, y, post), i) in enumerate(zip(result.top_k, result.order), start=1):
        lines.append(f"{rank:>4}  {x:>8.1f}  {y:>8.1f}  {post:>10.4f}  {float(result.likelihoods[i]):>10.4f}")
    return "\n".join(lines)


def _pictures(out_dir: Path, result: Any, aerial: Side, ground: Side, truth: tuple[float, float] | None,
              resolution: float | None, fast: bool, stride: int) -> list[Path]:
    """localization.png, aerial_graph.png and ground_graph.png in ``out_dir``."""
    try:
        from localization import pictures
    except ImportError:
        raise ConfigError("pictures need matplotlib: pip install matplotlib (or leave out --out)") from None
    from localization.graph import adjacency, cliques_fast, cliques_reference

    build = cliques_fast if fast else cliques_reference
    paths = [pictures.localization_png(out_dir / "localization.png", result, aerial.landmarks,
                                       image=aerial.picture(), truth=truth, resolution=resolution)]
    for name, side, w in (("aerial", aerial, result.window), ("ground", ground, result.query_window)):
        if w:
            graph = adjacency(build(side.landmarks, w, stride))
            title = f"{name}: {len(side.landmarks)} landmarks, window {w} px"
            paths.append(pictures.graph_png(out_dir / f"{name}_graph.png", side.landmarks, graph,
                                            image=side.picture(), title=title))
    return paths


@click.command("localize")
@click.option("--aerial", "aerial_path", required=True,
              type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="Aerial label mask (PNG/TIFF of class ids), landmark file (x y Class, .csv, .npy) or RGB image "
                   "with --aerial-checkpoint.")
@click.option("--ground", "ground_path", required=True,
              type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="Ground panorama: label mask, landmark file, or RGB image with --ground-checkpoint.")
@click.option("--aerial-classes", default="aerial13", show_default=True,
              help="Landmark class dictionary of the aerial side (data_manifests/landmarks-NAME.toml, or a path).")
@click.option("--ground-classes", default="camvid", show_default=True,
              help="Landmark class dictionary of the ground side.")
@click.option("--aerial-table", help="Class table of the aerial mask, e.g. classes13.toml [its dataset's manifest].")
@click.option("--ground-table", help="Class table of the ground mask [the dictionary's own].")
@click.option("--aerial-size", help="WIDTHxHEIGHT of the aerial landmark file's image [an image beside it].")
@click.option("--ground-size", help="WIDTHxHEIGHT of the ground landmark file's image, e.g. 1232x224.")
@click.option("--aerial-checkpoint", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="Segment the aerial RGB image with this checkpoint first (needs PyTorch).")
@click.option("--ground-checkpoint", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="Segment the ground RGB image with this checkpoint first (needs PyTorch).")
@click.option("--panorama/--no-panorama", default=True, show_default=True,
              help="The ground image is a 360-degree panorama (x wraps around); --no-panorama for an aerial crop.")
@click.option("--window", "window_text", default="auto", show_default=True,
              help="Aerial covisibility window in pixels, or auto: mean + 5 sd of nearest-neighbour distances.")
@click.option("--ground-window", type=click.IntRange(min=1),
              help="Ground window [a panorama's height; otherwise the aerial window].")
@click.option("--p", "p", type=click.FloatRange(0, 1, min_open=True), default=0.5, show_default=True,
              help="Candidate extension: add cliques sharing at least this fraction of a relevant clique's landmarks.")
@click.option("--top-k", type=click.IntRange(min=1), default=5, show_default=True)
@click.option("--stride", type=click.IntRange(min=1), default=1, show_default=True, help="Window stride in pixels.")
@click.option("--hierarchical", is_flag=True, help="Refine over --windows, multiplying probabilities (eq. 3.8).")
@click.option("--windows", "windows_text", default="400,200,100", show_default=True,
              help="Hierarchical windows, coarse to fine.")
@click.option("--mode", type=click.Choice(["centroid", "grid", "component"]), default="centroid", show_default=True,
              help="Landmarks of a mask: component centroids, grid points, or whole components.")
@click.option("--min-size", type=click.IntRange(min=0), default=50, show_default=True,
              help="Mask components smaller than this (pixels) are no landmarks.")
@click.option("--grid-stride", type=click.IntRange(min=1), default=50, show_default=True,
              help="Spacing of --mode grid.")
@click.option("--reference", is_flag=True, help="Build graphs with the paper's plain sliding window (slow; a check).")
@click.option("--truth", "truth_text", help="Ground-truth viewpoint X,Y in aerial pixels: reports the error.")
@click.option("--resolution", type=click.FloatRange(min=0, min_open=True),
              help="Metres per aerial pixel, for errors in metres [a GeoTIFF's, or the dataset manifest's].")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON instead of a table.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Folder for localization.png, aerial_graph.png, ground_graph.png and result.json.")
@click.option("--aerial-image", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="RGB photo of the aerial mask or landmark file: for --feature-threshold, and drawn under the graph.")
@click.option("--ground-image", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="RGB photo of the ground mask or landmark file.")
@click.option("--feature-threshold", type=click.FloatRange(min=0, min_open=True),
              help="Remove edges between landmarks whose encoder features are closer than this (§5.3.2) [off].")
@click.option("--feature-metric", type=click.Choice(["euclidean", "cosine"]), default="cosine", show_default=True)
@click.option("--feature-reduce", type=click.Choice(["none", "pca", "umap"]), default="pca", show_default=True,
              help="Reduce the features first (umap needs umap-learn). PCA centres them: with 2 landmarks their cosine distance is 2, so nothing is dropped.")
@click.option("--feature-components", type=click.IntRange(min=1), default=8, show_default=True,
              help="Dimensions --feature-reduce keeps.")
@click.option("--feature-checkpoint", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="Checkpoint whose encoder gives the features [the side's --aerial-checkpoint/--ground-checkpoint].")
@click.pass_context
@report_errors
def localize_command(ctx: click.Context, aerial_path: Path, ground_path: Path, aerial_classes: str,
                     ground_classes: str, aerial_table: str | None, ground_table: str | None, aerial_size: str | None,
                     ground_size: str | None, aerial_checkpoint: Path | None, ground_checkpoint: Path | None,
                     panorama: bool, window_text: str, ground_window: int | None, p: float, top_k: int, stride: int,
                     hierarchical: bool, windows_text: str, mode: str, min_size: int, grid_stride: int,
                     reference: bool, truth_text: str | None, resolution: float | None, as_json: bool,
                     out_dir: Path | None, aerial_image: Path | None, ground_image: Path | None,
                     feature_threshold: float | None, feature_metric: str, feature_reduce: str,
                     feature_components: int, feature_checkpoint: Path | None) -> None:
    """Find where the GROUND panorama was taken in the AERIAL image by matching landmark graphs."""
    from localization.features import FeatureEdges
    from localization.match import localize
    from localization.refine import localize_hierarchical

    verbosity = (ctx.obj or {}).get("verbosity", 0)
    window, windows, truth = _window(window_text), _windows(windows_text), _point(truth_text)
    common = {"mode": mode, "min_size": min_size, "grid_stride": grid_stride}
    aerial = load_side(aerial_path, SideOptions("aerial", aerial_classes, aerial_table,
                                                _size(aerial_size, "--aerial-size"), aerial_checkpoint, False,
                                                **common))
    ground = load_side(ground_path, SideOptions("ground", ground_classes, ground_table,
                                                _size(ground_size, "--ground-size"), ground_checkpoint, panorama,
                                                **common))
    _check_inputs(aerial, ground, aerial_path, ground_path)
    aerial, ground = _with_photo(aerial, aerial_image, "aerial"), _with_photo(ground, ground_image, "ground")
    a = aerial.landmarks
    if window is not None and not hierarchical and window >= max(a.width, a.height):
        raise ConfigError(f"--window {window} is not smaller than the aerial image ({a.width}x{a.height}): every "
                          f"landmark would be in one window; give less than {max(a.width, a.height)}, or auto")
    if truth is not None and not (0 <= truth[0] < a.width and 0 <= truth[1] < a.height):
        raise ConfigError(f"--truth {truth[0]:g},{truth[1]:g} is outside the aerial image ({a.width}x{a.height})")
    settings = {"query_window": ground_window, "p": p, "stride": stride, "top_k": top_k, "fast": not reference}
    edges, drops = None, {}
    if feature_threshold is not None:
        edges = FeatureEdges(feature_threshold, feature_metric, feature_reduce, feature_components)
        drops = edges.masks({"aerial": (aerial.photo, a, feature_checkpoint or aerial_checkpoint),
                             "ground": (ground.photo, ground.landmarks, feature_checkpoint or ground_checkpoint)})
        settings.update(aerial_drop=drops["aerial"], query_drop=drops["ground"])
    if hierarchical:
        result = localize_hierarchical(a, ground.landmarks, windows, **settings)
    else:
        result = localize(a, ground.landmarks, window=window, **settings)
        if window is None and not result.unanswered and result.window >= max(a.width, a.height):
            logger.warning("the automatic window (%d px) covers the whole aerial image, so there is one candidate: "
                           "give a smaller --window", result.window)
    if edges is not None:
        graphs = {"aerial": (a, result.window), "ground": (ground.landmarks, result.query_window)}
        result = replace(result, feature_edges=edges.summary(drops, graphs, fast=not reference, stride=stride))
    resolution = resolution or aerial.resolution
    error_px, error_m = result.error(truth, resolution)
    summary: dict[str, Any] = {"aerial": str(aerial_path), "ground": str(ground_path),
                               "aerial_landmarks": len(a), "ground_landmarks": len(ground.landmarks)}
    if truth is not None:
        summary["truth"] = {"x": truth[0], "y": truth[1], "error_px": error_px, "error_m": error_m}
    pictures: list[Path] = []
    if out_dir is not None:
        from osmseg.output.atomic import atomic_write_text

        pictures = _pictures(out_dir, result, aerial, ground, truth, resolution, not reference, stride)
        full = {**summary, **result.to_dict(all_candidates=True)}
        pictures.append(atomic_write_text(out_dir / "result.json", json.dumps(full, indent=2, sort_keys=True) + "\n"))
    if as_json:
        click.echo(json.dumps({**summary, **result.to_dict(all_candidates=False),
                               "files": [str(f) for f in pictures]}, indent=2, sort_keys=True))
    elif result.unanswered:
        click.echo(f"unanswered: {result.reason}")
    else:
        click.echo(_table(result))
    if verbosity >= 0 and not as_json:
        if not result.unanswered:
            ties = f", {result.ties} tied at the top (broken as documented)" if result.ties > 1 else ""
            used = (f"windows {', '.join(str(lv.window) for lv in result.levels)} px (hierarchical)" if hierarchical
                    else f"window {result.window} px{' (auto)' if window is None else ''}")
            click.echo(f"{used}, ground window {result.query_window} px, {result.n_cliques} cliques, "
                       f"{len(result.candidates)} candidates{ties}", err=True)
        if error_px is not None:
            click.echo(f"error of the best location: {error_px:.1f} px"
                       + (f" ({error_m:.1f} m)" if error_m is not None else ""), err=True)
        if pictures:
            click.echo(f"written: {', '.join(f.name for f in pictures)} in {out_dir}/", err=True)
