"""``python -m zipon.cli``: the same as the ``zipon`` command."""

from zipon.cli import entry

entry()
