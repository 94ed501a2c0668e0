"""``python -m pipeline.cli``: the same as the ``zipon`` command."""

from pipeline.cli import entry

entry()
