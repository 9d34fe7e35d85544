"""The dataset manifest (``manifest.json``): what was built, from what, and the hash of every file,
as typed, versioned, frozen values; the one place that knows its keys.

* :mod:`~osmseg.output.manifest.dataset`: :class:`DatasetManifest` (the whole file, format
  versions 1 and 2 read, any other refused in one line) and its parts;
* :mod:`~osmseg.output.manifest.samples`: :class:`SampleRecord` (an accepted sample),
  :class:`RejectionRecord` (a rejected attempt), the tiles, centres and sources' provenance;
* :mod:`~osmseg.output.manifest.entries`: the records a build makes from what it did;
* :mod:`~osmseg.output.manifest.files`: :func:`read_manifest`, :func:`write_manifest` (a sample
  at a time, deterministic), :func:`verify`;
* :mod:`~osmseg.output.manifest.values`: the JSON values and their one-line checks.

Every reader, in every package, reads a manifest with :func:`read_manifest` and uses attributes
(``manifest.samples[0].bounds_3857``), never the JSON's keys. A record's ``to_json`` gives back
the object it was read from, so a built dataset's manifest read and written again is the same
bytes. The schema is in ``docs/dataset-format.md``. Imports: osmseg core below it (classes,
grid, errors, redact, output.atomic, output.writer, runtime.folderlock).
"""

from osmseg.output.manifest.dataset import (
    FORMAT,
    FORMAT_VERSION,
    READ_VERSIONS,
    REQUIRED_KEYS,
    TOP_LEVEL_SETTINGS,
    AreaRecord,
    DatasetManifest,
    DatasetSummary,
    ToolInfo,
    check_sample_names,
)
from osmseg.output.manifest.entries import (
    REASONS,
    Rejection,
    class_totals,
    command_line,
    config_entry,
    rejection_entry,
    sample_entry,
    summary_entry,
    tile_entry,
)
from osmseg.output.manifest.files import (
    MANIFEST_NAME,
    SAMPLE_DIRS,
    dataset_class_table,
    manifest_chunks,
    manifest_path,
    manifest_text,
    read_manifest,
    refuse_busy,
    verify,
    write_manifest,
)
from osmseg.output.manifest.samples import SAMPLE_KEYS, Point, Provenance, RejectionRecord, SampleRecord, TileRecord
from osmseg.output.manifest.values import Json, JsonObject

__all__ = [
    "FORMAT", "FORMAT_VERSION", "MANIFEST_NAME", "READ_VERSIONS", "REASONS", "REQUIRED_KEYS", "SAMPLE_DIRS",
    "SAMPLE_KEYS", "TOP_LEVEL_SETTINGS", "AreaRecord", "DatasetManifest", "DatasetSummary", "Json", "JsonObject",
    "Point", "Provenance", "Rejection", "RejectionRecord", "SampleRecord", "TileRecord", "ToolInfo",
    "check_sample_names", "class_totals", "command_line", "config_entry", "dataset_class_table", "manifest_chunks",
    "manifest_path", "manifest_text", "read_manifest", "refuse_busy", "rejection_entry", "sample_entry",
    "summary_entry", "tile_entry", "verify", "write_manifest",
]
