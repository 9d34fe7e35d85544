"""The dataset builder behind ``osmseg build``: its own package, so the core's shared rooms stand apart.

:mod:`~osmseg.build.builder` runs a build (:func:`~osmseg.build.builder.build`) from a
:class:`~osmseg.build.config.BuildConfig`: it samples centres (:mod:`~osmseg.build.sampling`),
builds each slot (:mod:`~osmseg.build.slots`: fetch, rasterise, filter with
:mod:`~osmseg.build.filters`, write) in this process or on workers
(:mod:`~osmseg.build.workers`), records every slot's outcome (:mod:`~osmseg.build.state`,
:mod:`~osmseg.build.records`) so a build resumes, shards and does not depend on the number
of workers, and writes the dataset-level files (:mod:`~osmseg.build.finalize`).

Imports: the osmseg core below it (grid, classes, places, osm, imagery, net, output,
processes, ...). Only the command line (:mod:`osmseg.cli`) and the demo (:mod:`osmseg.demo`)
import it (``lint-imports``): training and localization read what it wrote, and localization's
``osmseg demo`` command runs a build only through :func:`osmseg.cli.build.run_build`.
"""
