"""Pictures of a dataset: a contact sheet of samples and a class-distribution bar chart.

``overview.png`` shows up to ``max_samples`` samples as rows of image | colour mask |
50 % overlay, with a legend of class colours and names, so a user sees at a glance whether
masks line up with the imagery. The builder keeps each shown sample's thumbnails while it
writes the sample (:func:`write_thumbnails`), so the sheet is drawn without decoding 1280 px
images again; without them it is made from the files, with the same pixels. ``class_histogram.png`` shows each class's share of all
pixels as bars in the class colours. Both are drawn with Pillow only, with fixed sizes and
Pillow's built-in font, and written like every other output file (atomic, deterministic).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from itertools import islice
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from osmseg.classes import ClassTable
from osmseg.errors import DatasetError
from osmseg.images import read_rgb
from osmseg.output.atomic import atomic_write_bytes
from osmseg.output.manifest import SampleRecord
from osmseg.output.writer import PHOTO_COMPRESS_LEVEL, encode_png

OVERVIEW_NAME = "overview.png"
#: The sheet shows the first this many samples (in slot order), each as a ``THUMB`` px square.
OVERVIEW_SAMPLES = 8
THUMB = 256
HISTOGRAM_NAME = "class_histogram.png"
MARGIN = 8
LINE = 14  # text line height of the default font, in pixels
SWATCH = 12
WHITE = (255, 255, 255)
INK = (30, 30, 30)
EDGE = (128, 128, 128)


def _font() -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    return ImageFont.load_default()


def _file(out_dir: Path, sample: SampleRecord, folder: str) -> Path:
    """The sample's file under ``folder/`` as listed in its manifest entry."""
    rel = sample.file_in(folder)
    if rel is None:
        raise DatasetError(f"sample {sample.name} lists no file under {folder}/; rebuild it")
    path = out_dir / rel
    if not path.is_file():
        raise DatasetError(f"{path} is missing; rebuild the dataset (the manifest lists it)")
    return path


def _legend(draw: ImageDraw.ImageDraw, table: ClassTable, x0: int, y0: int, width: int) -> int:
    """Draw class swatches and names in columns from (x0, y0); returns the y below the legend."""
    font = _font()
    entries = [(c.name, c.color) for c in sorted((table.unlabeled, *table.classes), key=lambda c: c.id)]
    col_w = SWATCH + 6 + max(int(draw.textlength(name, font=font)) for name, _ in entries) + 12
    per_row = max(1, (width - x0) // col_w)
    for i, (name, color) in enumerate(entries):
        row, col = divmod(i, per_row)
        x, y = x0 + col * col_w, y0 + row * (LINE + 4)
        draw.rectangle([x, y + 1, x + SWATCH, y + 1 + SWATCH], fill=tuple(color), outline=EDGE)
        draw.text((x + SWATCH + 6, y), name, fill=INK, font=font)
    rows = -(-len(entries) // per_row)
    return y0 + rows * (LINE + 4)


def legend_height(table: ClassTable, width: int) -> int:
    """Pixel height of the legend block drawn by :func:`overview_image` for an image ``width`` wide."""
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    return _legend(probe, table, MARGIN, 0, width - MARGIN) + MARGIN


def thumbnails(image: np.ndarray, labels: np.ndarray, thumb: int = THUMB) -> tuple[Image.Image, Image.Image]:
    """A sample's image (box-filtered) and class ids (nearest) shrunk to ``thumb`` x ``thumb``:
    what the overview sheet shows of it."""
    return (Image.fromarray(np.ascontiguousarray(image)).resize((thumb, thumb), Image.Resampling.BOX),
            Image.fromarray(np.ascontiguousarray(labels)).resize((thumb, thumb), Image.Resampling.NEAREST))


def write_thumbnails(folder: Path, name: str, image: np.ndarray, labels: np.ndarray) -> None:
    """Keep sample ``name``'s thumbnails in ``folder`` (the build state) while its files are written,
    so that the overview sheet is later drawn without decoding the sample's image again.

    ``image`` must be the pixels a reader of the written image gets (for a JPEG, the decoded
    file): the sheet is then the same whether it is drawn from thumbnails or from the files.
    """
    small_image, small_labels = thumbnails(image, labels)
    atomic_write_bytes(Path(folder) / f"{name}.image.png", encode_png(np.asarray(small_image), level=1))
    atomic_write_bytes(Path(folder) / f"{name}.labels.png", encode_png(np.asarray(small_labels), level=1))


def _sample_thumbnails(out_dir: Path, sample: SampleRecord, folder: Path | None,
                       thumb: int) -> tuple[Image.Image, Image.Image]:
    """The thumbnails of a sample: kept ones from ``folder`` when there, else made from its files."""
    name = sample.name
    if folder is not None and thumb == THUMB:
        kept = (Path(folder) / f"{name}.image.png", Path(folder) / f"{name}.labels.png")
        if all(p.is_file() for p in kept):
            try:
                with Image.open(kept[0]) as small_image, Image.open(kept[1]) as small_labels:
                    small_image.load()
                    small_labels.load()
                    if small_image.size == small_labels.size == (thumb, thumb):
                        return small_image.convert("RGB"), small_labels.convert("L")
            except OSError:  # a damaged thumbnail: the files are the truth
                pass
    with Image.open(_file(out_dir, sample, "labels")) as im:
        labels = np.asarray(im)
    return thumbnails(read_rgb(_file(out_dir, sample, "images")), labels, thumb)


def overview_image(
    out_dir: Path, samples: Sequence[SampleRecord], table: ClassTable, *, max_samples: int = OVERVIEW_SAMPLES,
    thumb: int = THUMB, kept: Path | None = None,
) -> Image.Image:
    """The contact sheet of the first ``max_samples`` samples (manifest entries) as a Pillow image.

    ``kept``: a folder of thumbnails written by :func:`write_thumbnails`; samples without one
    there are read from their files (same pictures, more time).
    """
    out_dir = Path(out_dir)
    shown = list(islice(samples, max_samples))  # samples may be read from disk as iterated: no more
    width = 3 * thumb + 4 * MARGIN
    row_h = LINE + thumb + MARGIN
    top = MARGIN + LINE + 4
    height = top + len(shown) * row_h + LINE + 4 + legend_height(table, width)
    sheet = Image.new("RGB", (width, height), WHITE)
    draw = ImageDraw.Draw(sheet)
    font = _font()
    for col, title in enumerate(("image", "labels", "overlay 50%")):
        draw.text((MARGIN + col * (thumb + MARGIN), MARGIN), title, fill=INK, font=font)
    if len(samples) > len(shown):  # say that the sheet is not the whole dataset
        note = f"first {len(shown)} of {len(samples)} samples"
        draw.text((width - MARGIN - int(draw.textlength(note, font=font)), MARGIN), note, fill=INK, font=font)
    for row, sample in enumerate(shown):
        image, small_labels = _sample_thumbnails(out_dir, sample, kept, thumb)
        mask = Image.fromarray(table.colorize(np.asarray(small_labels)))
        overlay = Image.blend(image, mask, 0.5)
        y = top + row * row_h
        draw.text((MARGIN, y), sample.name, fill=INK, font=font)
        for col, picture in enumerate((image, mask, overlay)):
            sheet.paste(picture, (MARGIN + col * (thumb + MARGIN), y + LINE))
    legend_top = top + len(shown) * row_h
    draw.text((MARGIN, legend_top), f"classes ({table.name})", fill=INK, font=font)
    _legend(draw, table, MARGIN, legend_top + LINE + 4, width - MARGIN)
    return sheet


def write_overview(
    out_dir: Path, samples: Sequence[SampleRecord], table: ClassTable, *, max_samples: int = OVERVIEW_SAMPLES,
    thumb: int = THUMB, kept: Path | None = None,
) -> Path:
    """Write ``OUT/overview.png`` (see :func:`overview_image`) atomically and return its path.

    ``samples`` are the manifest's sample records (:class:`osmseg.output.manifest.SampleRecord`);
    their files must already be in ``out_dir``. ``kept``: a folder of thumbnails (see
    :func:`write_thumbnails`).
    """
    sheet = overview_image(out_dir, samples, table, max_samples=max_samples, thumb=thumb, kept=kept)
    # mostly photos: the photos' fast level (level 6 took a quarter of a second)
    return atomic_write_bytes(Path(out_dir) / OVERVIEW_NAME, encode_png(np.asarray(sheet), PHOTO_COMPRESS_LEVEL))


def histogram_image(totals: Mapping[str, int], table: ClassTable, *, bar_width: int = 360) -> Image.Image:
    """Horizontal bar chart of each class's share of ``totals`` (class name -> pixels), in class colours."""
    font = _font()
    classes = sorted((table.unlabeled, *table.classes), key=lambda c: c.id)
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    label_w = max(int(probe.textlength(c.name, font=font)) for c in classes) + 10
    all_pixels = sum(totals.get(c.name, 0) for c in classes)
    shares = [totals.get(c.name, 0) / all_pixels if all_pixels else 0.0 for c in classes]
    longest = max(shares) or 1.0
    row = LINE + 6
    width = MARGIN + label_w + bar_width + 70
    height = MARGIN + LINE + 8 + len(classes) * row + MARGIN
    chart = Image.new("RGB", (width, height), WHITE)
    draw = ImageDraw.Draw(chart)
    draw.text((MARGIN, MARGIN), f"share of pixels per class ({table.name}, {all_pixels:,} px)", fill=INK, font=font)
    for i, (c, share) in enumerate(zip(classes, shares)):
        y = MARGIN + LINE + 8 + i * row
        draw.text((MARGIN, y), c.name, fill=INK, font=font)
        x0 = MARGIN + label_w
        length = round(bar_width * share / longest)
        draw.rectangle([x0, y + 1, x0 + max(length, 1), y + LINE - 1], fill=tuple(c.color), outline=EDGE)
        draw.text((x0 + length + 6, y), f"{100 * share:.1f}%", fill=INK, font=font)
    return chart


def write_class_histogram(out_dir: Path, totals: Mapping[str, int], table: ClassTable) -> Path:
    """Write ``OUT/class_histogram.png`` atomically and return its path.

    ``totals`` is pixels per class name, e.g. :func:`osmseg.output.manifest.class_totals`.
    """
    chart = histogram_image(totals, table)
    return atomic_write_bytes(Path(out_dir) / HISTOGRAM_NAME, encode_png(np.asarray(chart)))
