"""Writing a dataset: sample files, manifest, datasheet, attribution, pictures and zip.

The builder calls, per accepted sample, :func:`write_sample` then :func:`sample_entry`;
per rejected attempt :func:`rejection_entry`; and at the end :func:`write_manifest`,
:func:`write_datasheet`, :func:`write_attribution`, :func:`write_overview`,
:func:`write_class_histogram`, :func:`write_stac` (a STAC catalog of the dataset) and, with
``--zip``, :func:`make_zip`. The folder layout and the manifest schema are documented in
``docs/dataset-format.md``. Readers of a dataset use :func:`read_manifest` (validated) and
:func:`verify`. Imports: osmseg core below it (classes, grid, errors, images); never the
builder, the CLI, training or localization.
"""

from osmseg.output.atomic import atomic_write_bytes, atomic_write_text, sha256_file
from osmseg.output.attribution import write_attribution
from osmseg.output.datasheet import write_datasheet
from osmseg.output.manifest import (
    class_totals,
    command_line,
    read_manifest,
    rejection_entry,
    sample_entry,
    summary_entry,
    verify,
    write_manifest,
)
from osmseg.output.overview import write_class_histogram, write_overview
from osmseg.output.package import make_zip
from osmseg.output.stac import write_stac
from osmseg.output.writer import sample_paths, write_sample

__all__ = [
    "atomic_write_bytes",
    "atomic_write_text",
    "class_totals",
    "command_line",
    "make_zip",
    "read_manifest",
    "rejection_entry",
    "sample_entry",
    "sample_paths",
    "sha256_file",
    "summary_entry",
    "verify",
    "write_attribution",
    "write_class_histogram",
    "write_datasheet",
    "write_manifest",
    "write_overview",
    "write_sample",
    "write_stac",
]
