"""The dataset builder behind ``osmseg build``: its own package, so the core's shared rooms stand apart.

:mod:`~osmseg.builder.run` runs a build (:func:`~osmseg.builder.run.build`) from a
:class:`~osmseg.builder.config.BuildConfig`: it samples centres (:mod:`~osmseg.builder.sampling`),
builds each slot (:mod:`~osmseg.builder.slots`: fetch, rasterise, filter with
:mod:`~osmseg.builder.filters`, write) in this process or on workers
(:mod:`~osmseg.builder.workers`), records every slot's outcome (:mod:`~osmseg.builder.state`,
:mod:`~osmseg.builder.records`) so a build resumes, shards and does not depend on the number
of workers, and writes the dataset-level files (:mod:`~osmseg.builder.finalize`).

Imports: the osmseg core below it (grid, classes, places, osm, imagery, net, output,
processes, ...). Only the command line (:mod:`osmseg.cli`) and the demo (:mod:`osmseg.demo`)
import it (``lint-imports``): training and localization read what it wrote, and localization's
``osmseg demo`` command runs a build only through :func:`osmseg.cli.build.run_build`.
"""
