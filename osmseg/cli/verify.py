"""``osmseg verify``: check a dataset against its manifest, and masks against their images."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import click
import numpy as np
from PIL import Image

from osmseg.cli.common import report_errors
from osmseg.errors import ConfigError
from osmseg.output import read_manifest, verify
from osmseg.images import read_rgb
from osmseg.quality import edge_alignment


@click.command("verify")
@click.argument("dataset", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--alignment", "align_class", metavar="CLASS",
              help="Also estimate, per sample, the pixel offset between CLASS outlines and image edges.")
@click.pass_context
@report_errors
def verify_command(ctx: click.Context, dataset: Path, align_class: str | None) -> None:
    """Check every file of DATASET against the sha256 in its manifest.json.

    With --alignment building, also print per sample the shift (dx, dy) that would put the
    building outlines on the strongest image edges: (0, 0) means mask and imagery line up;
    a consistent offset means the imagery is misregistered against OSM.
    Prints JSON to stdout; exits 1 when a file is missing, modified or unlisted.
    """
    manifest = read_manifest(dataset)
    problems = verify(dataset)
    report: dict[str, object] = {"dataset": str(dataset), "samples": len(manifest["samples"]), "problems": problems}
    if align_class is not None:
        ids = {c["name"]: c["id"] for c in manifest["classes"]["classes"]}
        if align_class not in ids:
            raise ConfigError(f"--alignment {align_class!r}: not a class of this dataset; use one of {', '.join(ids)}")
        offsets: dict[str, dict[str, Any]] = {}
        broken = {p.split(":")[0] for p in problems}
        for sample in manifest["samples"]:
            files = sample["files"]
            image = next((k for k in files if k.startswith("images/")), None)
            label = next((k for k in files if k.startswith("labels/")), None)
            if image is None or label is None or image in broken or label in broken:
                continue  # already reported as a problem
            rgb = read_rgb(dataset / image)
            mask = np.asarray(Image.open(dataset / label)) == ids[align_class]
            if not mask.any():  # nothing to align: say so instead of a (0, 0) that reads as "lined up"
                offsets[sample["name"]] = {"dx": None, "dy": None, "outline_pixels": 0,
                                           "note": f"no {align_class} pixels in this sample"}
                continue
            fit = edge_alignment(rgb, mask)
            offsets[sample["name"]] = {"dx": fit.best[0], "dy": fit.best[1], "edge_at_zero": round(fit.at_zero, 1),
                                       "edge_far": round(fit.far, 1), "outline_pixels": fit.outline_pixels}
        report["alignment"] = {"class": align_class, "offsets": offsets}
    click.echo(json.dumps(report, indent=2))
    if problems:
        raise click.ClickException(f"{len(problems)} problems in {dataset}: first: {problems[0]}")
