"""The ``osmseg`` command: a click group with one module per subcommand (as rasterio's ``rio``).

Only the CLI configures logging. Data (paths, JSON) goes to stdout; logs, progress and
summaries go to stderr. Exit status: 0 success, 1 failure, 2 usage error.
"""

from __future__ import annotations

import click

from osmseg import __version__
from osmseg.cli.build import build_command
from osmseg.cli.common import configure_logging, show_progress
from osmseg.cli.demo import demo_command
from osmseg.cli.eval import eval_command
from osmseg.cli.localize import localize_command
from osmseg.cli.localize_bench import localize_bench_command
from osmseg.cli.predict import predict_command
from osmseg.cli.train import train_command
from osmseg.cli.verify import verify_command


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, "--version", prog_name="osmseg")
@click.option("-v", "--verbose", count=True, help="More log output on stderr (-vv for debug).")
@click.option("-q", "--quiet", count=True, help="Less output on stderr: only errors, no progress bar.")
@click.option("--progress/--no-progress", default=None,
              help="Draw progress bars on stderr [only when stderr is a terminal, so logs stay clean].")
@click.pass_context
def cli(ctx: click.Context, verbose: int, quiet: int, progress: bool | None) -> None:
    """osmseg: aerial segmentation datasets from OpenStreetMap, and what to do with them."""
    verbosity = verbose - quiet
    configure_logging(verbosity)
    ctx.obj = {"verbosity": verbosity, "progress": show_progress(progress, verbosity)}


cli.add_command(build_command)
cli.add_command(demo_command)
cli.add_command(verify_command)
cli.add_command(train_command)
cli.add_command(predict_command)
cli.add_command(eval_command)
cli.add_command(localize_command)
cli.add_command(localize_bench_command)

if __name__ == "__main__":  # pragma: no cover
    cli()
