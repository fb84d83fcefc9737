"""Alembic environment of the calibration registry: run on the connection relcal hands over
(``config.attributes["connection"]``), never from an ini file."""

from alembic import context

connection = context.config.attributes["connection"]
context.configure(connection=connection, target_metadata=None, render_as_batch=True)
with context.begin_transaction():
    context.run_migrations()
