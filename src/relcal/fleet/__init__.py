"""Fleet work: a registry of calibrations, their history and drift, many sessions on Dask.

Above :mod:`relcal.calibration` and :mod:`relcal.reporting` in the layer order (it uses both);
nothing below imports it. ``registry`` stores one record per calibration (SQLAlchemy, schema
migrated by Alembic), ``drift`` compares two records of one robot, ``runner`` calibrates many
dataset folders as Dask tasks, and ``report`` draws the fleet page.
"""

ALPHA = 0.01  # the drift tests' default level (here, so that the command line reads it lightly)
