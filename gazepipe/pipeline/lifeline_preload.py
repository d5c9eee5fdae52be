"""Imported as a preload module (the process executor's forkserver, the workers of a local Dask cluster): the
importing process dies with its parent (:func:`gazepipe.pipeline.lifeline.die_with_parent`). Nothing else
imports it."""

from gazepipe.pipeline.lifeline import die_with_parent

die_with_parent()
