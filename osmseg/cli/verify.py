"""``osmseg verify``: check a dataset against its manifest, and masks against their images."""

from __future__ import annotations

import json
from pathlib import Path

import click

from osmseg.cli.common import output_options, report_errors
from osmseg.cli.options import declare
from osmseg.output import read_manifest, verify
from osmseg.quality import dataset_alignment
from osmseg.units import plural

ALIGNMENT = declare("--alignment", dest="align_class", metavar="CLASS",
                    help="Also estimate, per sample, the pixel offset between CLASS outlines and image edges.")


@click.command("verify")
@output_options
@click.argument("dataset", type=click.Path(exists=True, file_okay=False, path_type=Path))
@ALIGNMENT()
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
    report: dict[str, object] = {"dataset": str(dataset), "samples": len(manifest.samples), "problems": problems}
    if align_class is not None:
        offsets = dataset_alignment(dataset, align_class, skip={p.split(":")[0] for p in problems})
        report["alignment"] = {"class": align_class, "offsets": offsets}
    click.echo(json.dumps(report, indent=2))
    if problems:
        raise click.ClickException(f"{plural(len(problems), 'problem')} in {dataset}: first: {problems[0]}")
