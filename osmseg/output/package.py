"""``--zip``: pack a dataset folder into a deterministic zip archive.

The same folder always gives the same zip bytes: entries sorted by path, every entry dated
1980-01-01 00:00 (the zip epoch) with permissions 0644 and a Unix origin, fixed compression.
Hidden files and folders (any path part starting with ``.``: build state, caches, temp files)
are left out, and so is the archive itself when it is written inside the folder. Entries sit
under one top folder named like the dataset, so unzipping creates that folder.
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

from osmseg.errors import DatasetError
from osmseg.output.atomic import atomic_path

ZIP_DATE = (1980, 1, 1, 0, 0, 0)
#: Already-compressed formats are stored as they are; deflating them again only costs time.
STORED_SUFFIXES = frozenset({".png", ".jpg", ".jpeg", ".tif", ".tiff", ".zip", ".gz"})


def dataset_files(out_dir: Path, exclude: Path | None = None) -> list[str]:
    """Relative POSIX paths of the files to pack, sorted; hidden parts and ``exclude`` left out."""
    out_dir = Path(out_dir)
    skip = exclude.resolve() if exclude is not None else None
    found = []
    for dirpath, dirnames, filenames in os.walk(out_dir):
        dirnames[:] = [d for d in dirnames if not d.startswith(".")]
        for name in filenames:
            path = Path(dirpath) / name
            if name.startswith(".") or (skip is not None and path.resolve() == skip):
                continue
            found.append(path.relative_to(out_dir).as_posix())
    return sorted(found)


def make_zip(out_dir: Path, zip_path: Path, root: str | None = None) -> Path:
    """Write a deterministic zip of ``out_dir`` to ``zip_path`` atomically and return ``zip_path``.

    Args:
        out_dir: the dataset folder.
        zip_path: the archive to write (may be inside ``out_dir``; it is not packed into itself).
        root: top folder inside the archive; default ``out_dir``'s name.
    """
    out_dir, zip_path = Path(out_dir), Path(zip_path)
    if not out_dir.is_dir():
        raise DatasetError(f"{out_dir} is not a folder; give the dataset folder to zip")
    top = root if root is not None else out_dir.resolve().name
    names = dataset_files(out_dir, exclude=zip_path)
    with atomic_path(zip_path) as tmp:
        with zipfile.ZipFile(tmp, "w") as zf:
            for rel in names:
                info = zipfile.ZipInfo(f"{top}/{rel}" if top else rel, date_time=ZIP_DATE)
                info.create_system = 3  # Unix, so external_attr holds POSIX permissions
                info.external_attr = (0o100644 & 0xFFFF) << 16
                if Path(rel).suffix.lower() in STORED_SUFFIXES:
                    info.compress_type = zipfile.ZIP_STORED
                else:
                    info.compress_type = zipfile.ZIP_DEFLATED  # zlib's default level (6)
                info.file_size = (out_dir / rel).stat().st_size  # lets zipfile choose zip64 up front
                with open(out_dir / rel, "rb") as src, zf.open(info, "w") as dst:
                    while block := src.read(1 << 20):
                        dst.write(block)
    return zip_path
